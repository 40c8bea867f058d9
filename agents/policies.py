"""Network structures for observations laid out as a list of candidates.

Several envs observe *candidates* (MultiHop's distance-ranked estimates, RendezvousMapping's landmarks):
``K`` blocks of ``F`` features each, then ``G`` features of the robot itself, and act on them one by one
(a select bit per candidate, or a choice among them). A plain MLP over the flat vector has to learn that
output k depends on block k, separately for every k. ``CandidatePolicy`` scores every candidate with the
same small network (permutation-equivariant, as in pointer/attention policies), so what it learns about one
candidate applies to all, and the same network serves any K.

An env declares its layout with ``observation_layout()`` → ``{"candidates": K, "features": F,
"globals": G, "extra_actions": E}``; ``E`` more logits (e.g. "hold") come from the robot's own features. An env
whose select bits choose *at most* ``c`` candidates (MultiHop's slot: the env sends the first ``m − 1`` selected)
adds ``"choose": c``; the ``candidate_subset`` policy then draws that subset as the decision it is
(:class:`SubsetDistribution`) rather than as K independent coins.
"""

from __future__ import annotations

import itertools
import math
from typing import Any, cast

import torch
from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
from stable_baselines3.common.distributions import Distribution
from stable_baselines3.common.policies import ActorCriticPolicy
from torch import nn


def _mlp(sizes: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        layers += [nn.Linear(a, b), nn.Tanh()]
    return nn.Sequential(*layers)


class CandidateExtractor(nn.Module):
    """Actor: one logit per candidate from a shared scorer of (candidate features, own features), plus
    ``extra_actions`` logits from the own features. Critic: own features and the mean of the candidates'
    embeddings."""

    def __init__(
        self,
        candidates: int,
        features: int,
        globals: int,
        extra_actions: int = 0,
        hidden: int = 64,
        context: bool = False,
    ):
        super().__init__()
        self.k, self.f, self.g, self.e = candidates, features, globals, extra_actions
        self.latent_dim_pi = candidates + extra_actions
        self.latent_dim_vf = hidden
        # context: each candidate is also scored against the whole list (the mean and the max of an embedding of
        # every candidate, a Deep Sets summary), so a score can say "among the best few", which a choice of the
        # top m − 1 (MultiHop's slot) needs; without it a candidate is judged alone
        self.context = _mlp([features + globals, hidden]) if context else None
        extra_inputs = 2 * hidden if context else 0
        self.scorer = nn.Sequential(_mlp([features + globals + extra_inputs, hidden, hidden]), nn.Linear(hidden, 1))
        self.extra = nn.Sequential(_mlp([globals, hidden]), nn.Linear(hidden, extra_actions)) if extra_actions else None
        self.value_candidates = _mlp([features + globals, hidden])
        self.value_own = _mlp([globals, hidden])
        self.value_head = _mlp([2 * hidden, hidden])

    def _split(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(candidates ``(B, K, F)``, own features ``(B, G)``) of flat observations."""
        cand = obs[:, : self.k * self.f].reshape(-1, self.k, self.f)
        own = obs[:, self.k * self.f : self.k * self.f + self.g]
        return cand, own

    def _paired_mlp(self, mlp: nn.Sequential, cand: torch.Tensor, own: torch.Tensor, summary=None) -> torch.Tensor:
        """``mlp`` (a :func:`_mlp`) on each candidate's (features, own features[, the list's summary]), ``(B, K, ·)``.
        Its first layer is split as W·[x, o, s] + b = W_x·x + (W_o·o + W_s·s + b): the own features and the summary
        are the same for all K candidates of a row, so their part is computed once per row rather than K times and
        the (B, K, F + G + 2·hidden) concatenation is never built (for MultiHop's 35 candidates the summary's part
        was 2 × 64 of the scorer's 137 inputs, most of an update's arithmetic; splitting halves the actor's
        time). The weights are the unsplit ``nn.Linear``'s, so saved models load as before; the outputs equal the
        concatenation's up to float rounding."""
        first = cast(nn.Linear, mlp[0])
        per_row_inputs = own if summary is None else torch.cat([own, summary], dim=-1)
        per_row = nn.functional.linear(per_row_inputs, first.weight[:, self.f :], first.bias)  # (B, hidden)
        hidden = nn.functional.linear(cand, first.weight[:, : self.f]) + per_row[:, None, :]
        for layer in list(mlp)[1:]:  # its Tanh, then the other (Linear, Tanh) layers
            hidden = layer(hidden)
        return hidden

    def forward_actor(self, obs: torch.Tensor) -> torch.Tensor:
        cand, own = self._split(obs)
        summary = None
        if self.context is not None:
            embedded = self._paired_mlp(self.context, cand, own)
            summary = torch.cat([embedded.mean(dim=1), embedded.max(dim=1).values], dim=-1)
        hidden = self._paired_mlp(cast(nn.Sequential, self.scorer[0]), cand, own, summary)
        logits = self.scorer[1](hidden).squeeze(-1)
        if self.extra is not None:
            logits = torch.cat([logits, self.extra(own)], dim=-1)
        return logits

    def forward_critic(self, obs: torch.Tensor) -> torch.Tensor:
        cand, own = self._split(obs)
        pooled = self._paired_mlp(self.value_candidates, cand, own).mean(dim=1)
        return self.value_head(torch.cat([pooled, self.value_own(own)], dim=-1))

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(obs), self.forward_critic(obs)


class SubsetDistribution(Distribution):
    """A choice of at most ``choose`` of K candidates as a MultiBinary action: candidates are drawn one at a time
    without replacement, each with probability ∝ exp(score) among those left *and a "stop" item* (Plackett–Luce,
    sampled as Gumbel-top-k), until ``choose`` are drawn or "stop" is. So the policy can say "exactly these m − 1"
    (MultiHop's slot), which K independent Bernoulli bits say only by luck, and can still send fewer to save bits.

    The probability of a set S of j ≤ c chosen candidates sums the orders they could have been drawn in:
    P(S) = Σ_σ Π_t exp(s_σt) / Z_t · [j < c] exp(s_stop) / Z_j, with Z_t the sum over what is left at draw t.
    That is j! orders (6 for MultiHop's m = 4), enumerated; ``choose`` is held to :data:`MAX_CHOOSE`. An action
    with more than c bits set counts as its first c in candidate order, which is what the env sends. The entropy
    has no closed form: PPO then uses −log-probability, SB3's estimate.

    Logits: (B, K + 1), the last is "stop".
    """

    MAX_CHOOSE = 6
    MASKED_SCORE = -1e8

    def __init__(self, candidates: int, choose: int):
        super().__init__()
        if not 1 <= choose <= self.MAX_CHOOSE:
            raise ValueError(f"argument 'choose' must be between 1 and {self.MAX_CHOOSE}, got {choose!r}")
        self.k, self.c = int(candidates), min(int(choose), int(candidates))
        self.orders = torch.tensor(list(itertools.permutations(range(self.c))), dtype=torch.long)  # (c!, c)
        # order p serves a set of j chosen when its first j positions hold 0 … j − 1; each order of the j chosen
        # then appears (c − j)! times among the valid orders, which the sum divides out
        valid = torch.stack([(self.orders[:, :j] < j).all(dim=1) for j in range(self.c + 1)], dim=1)  # (c!, c + 1)
        self.valid = valid
        self.repeats = torch.tensor([math.lgamma(self.c - j + 1) for j in range(self.c + 1)], dtype=torch.float64)
        self.logits: torch.Tensor | None = None
        self.unmasked_logits: torch.Tensor | None = None

    def proba_distribution_net(self, latent_dim: int) -> nn.Module:
        return nn.Identity()  # the extractor's outputs are the K + 1 scores

    def proba_distribution(self, action_logits: torch.Tensor) -> SubsetDistribution:
        self.unmasked_logits = self.logits = action_logits
        return self

    def apply_masking(self, masks) -> None:
        """sb3-contrib's masking (``MaskableActorCriticPolicy`` calls it after :meth:`proba_distribution`): a masked
        candidate is never drawn, and every probability is over the allowed candidates and "stop" alone.
        ``masks``: (B, 2K) as sb3-contrib lays out a MultiBinary mask (may be 0, may be 1, per bit), or (B, K)
        per bit whether it may be set; None undoes the masking. "Stop" is always allowed. A masked score is
        :data:`MASKED_SCORE`, as sb3-contrib's masked categorical does: finite, so a log-probability stays a
        number, and exp(score − max) is exactly 0."""
        assert self.unmasked_logits is not None
        if masks is None:
            self.logits = self.unmasked_logits
            return
        logits = self.unmasked_logits
        allowed = torch.as_tensor(masks, dtype=torch.bool, device=logits.device).reshape(logits.shape[0], -1)
        if allowed.shape[1] == 2 * self.k:
            allowed = allowed.reshape(-1, self.k, 2)[:, :, 1]
        elif allowed.shape[1] != self.k:
            raise ValueError(f"action masks must have {self.k} or {2 * self.k} columns, got {allowed.shape[1]}")
        stop = torch.ones_like(allowed[:, :1])
        self.logits = torch.where(torch.cat([allowed, stop], dim=1), logits, torch.full_like(logits, self.MASKED_SCORE))

    def _chosen(self, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, c) indices of the first c set bits in candidate order (padded with 0) and their count j."""
        bits = actions.reshape(-1, self.k) > 0.5
        key = bits * (self.k - torch.arange(self.k, device=bits.device))  # earlier candidates rank higher
        top = torch.topk(key, self.c, dim=1)
        count = (top.values > 0).sum(dim=1)
        return torch.where(top.values > 0, top.indices, torch.zeros_like(top.indices)), count

    def _order_log_prob(self, items: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
        """log P of drawing ``items[:, :count]`` in that order, then "stop" when count < c."""
        assert self.logits is not None
        logits = self.logits
        removed = torch.zeros_like(logits, dtype=torch.bool)
        total = torch.zeros(logits.shape[0], dtype=logits.dtype, device=logits.device)
        for t in range(self.c + 1):
            norm = torch.logsumexp(logits.masked_fill(removed, -torch.inf), dim=1)
            if t < self.c:
                drawn = logits.gather(1, items[:, t : t + 1]).squeeze(1) - norm
                total = total + torch.where(t < count, drawn, torch.zeros_like(drawn))
            stop = logits[:, -1] - norm
            total = total + torch.where(count == t, stop, torch.zeros_like(stop)) * (t < self.c)
            if t < self.c:
                took = nn.functional.one_hot(items[:, t], self.k + 1).bool() & (t < count)[:, None]
                removed = removed | took
        return total

    def log_prob(self, actions: torch.Tensor) -> torch.Tensor:
        items, count = self._chosen(actions)
        per_order = torch.stack([self._order_log_prob(items[:, order], count) for order in self.orders])  # (c!, B)
        valid = self.valid[:, count.cpu()].to(per_order.device)  # (c!, B)
        per_order = per_order.masked_fill(~valid, -torch.inf)
        return torch.logsumexp(per_order, dim=0) - self.repeats.to(per_order.device, per_order.dtype)[count]

    def entropy(self) -> None:
        return None

    def _take(self, scores: torch.Tensor) -> torch.Tensor:
        """The MultiBinary action of drawing in descending ``scores`` until c are drawn or "stop" is."""
        order = torch.argsort(scores, dim=1, descending=True)[:, : self.c]
        before_stop = torch.cumsum(order == self.k, dim=1) == 0
        actions = torch.zeros(scores.shape[0], self.k + 1, dtype=torch.float32, device=scores.device)
        actions.scatter_(1, order, before_stop.float())
        return actions[:, : self.k]

    def sample(self) -> torch.Tensor:
        assert self.logits is not None
        gumbel = -torch.log(-torch.log(torch.rand_like(self.logits).clamp(1e-20, 1.0)))
        return self._take(self.logits + gumbel)

    def mode(self) -> torch.Tensor:
        assert self.logits is not None
        return self._take(self.logits)

    def actions_from_params(self, action_logits: torch.Tensor, deterministic: bool = False) -> torch.Tensor:
        self.proba_distribution(action_logits)
        return self.get_actions(deterministic=deterministic)

    def log_prob_from_params(self, action_logits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        actions = self.actions_from_params(action_logits)
        return actions, self.log_prob(actions)


class _CandidateHeads:
    """SB3 actor-critic whose logits are the candidate scores themselves (no mixing layer after them); with
    ``subset`` the scores (and a "stop" score from the robot's own features) drive a :class:`SubsetDistribution`
    over the layout's ``choose``.

    ``stop_bias`` starts the "stop" score there instead of near 0. From random weights every score is near 0, so the
    deterministic action (highest score first) stops at once in about one robot in ``candidates + 1`` and sends
    only its own estimate, and that is the single most likely sampled set too; a bias of −3 starts the policy
    filling its slot, as every paper algorithm does, and PPO can still learn to stop. It changes only the
    initial weights: a warm start (DAgger) fits them anyway, and a saved model loads as saved.

    A mixin: the SB3 policy class it is mixed into (:class:`CandidatePolicy`, :class:`MaskableCandidatePolicy`) is
    what ``super()`` reaches and what provides the attributes declared below."""

    mlp_extractor: Any
    action_dist: Any
    action_net: Any
    optimizer: Any
    optimizer_class: Any
    optimizer_kwargs: dict[str, Any]
    init_weights: Any
    parameters: Any

    def __init__(
        self,
        *args,
        layout: dict,
        hidden: int = 64,
        context: bool = False,
        subset: bool = False,
        stop_bias: float = 0.0,
        **kwargs,
    ):
        self.layout = dict(layout)
        self.hidden = hidden
        self.context = context
        self.subset = subset
        if stop_bias and not subset:
            raise ValueError("stop_bias applies to policy 'candidate_subset' only (the others have no 'stop' score)")
        if not math.isfinite(stop_bias):
            raise ValueError(f"stop_bias must be a finite number, got {stop_bias!r}")
        self.stop_bias = float(stop_bias)
        if subset and not self.layout.get("choose"):
            raise ValueError("policy 'candidate_subset' needs an env whose observation_layout() gives 'choose'")
        super().__init__(*args, **kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = CandidateExtractor(
            self.layout["candidates"],
            self.layout["features"],
            self.layout["globals"],
            self.layout.get("extra_actions", 0) + (1 if self.subset else 0),  # the "stop" score
            self.hidden,
            self.context,
        )

    def _get_action_dist_from_latent(self, latent_pi: torch.Tensor):
        if self.subset:
            return self.action_dist.proba_distribution(action_logits=self.action_net(latent_pi))
        return super()._get_action_dist_from_latent(latent_pi)  # type: ignore[misc]  # the SB3 policy mixed into

    def _build(self, lr_schedule) -> None:
        # with the Bernoulli distribution SB3 gives MultiBinary, which it knows how to build
        super()._build(lr_schedule)  # type: ignore[misc]  # the SB3 policy this is mixed into
        if self.subset:
            self.action_dist = SubsetDistribution(self.layout["candidates"], int(self.layout["choose"]))
        # the extractor's actor output already is one logit per action: SB3's linear action head would mix them
        self.action_net = nn.Identity()
        # small output weights, as SB3 gives its action head: the first policy is close to uniform
        extractor = cast(CandidateExtractor, self.mlp_extractor)
        self.init_weights(extractor.scorer[-1], gain=0.01)
        if extractor.extra is not None:
            extra_out = cast(nn.Linear, extractor.extra[-1])
            self.init_weights(extra_out, gain=0.01)
            if self.subset:
                with torch.no_grad():  # the "stop" score is the extra head's last output
                    extra_out.bias[-1] = self.stop_bias
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def _get_constructor_parameters(self) -> dict:
        data = super()._get_constructor_parameters()  # type: ignore[misc]  # the SB3 policy this is mixed into
        data.update(
            layout=self.layout, hidden=self.hidden, context=self.context, subset=self.subset, stop_bias=self.stop_bias
        )
        return data


class CandidatePolicy(_CandidateHeads, ActorCriticPolicy):
    """:class:`_CandidateHeads` on SB3's ``ActorCriticPolicy`` (PPO, and the batched trainer on unmasked envs)."""


class MaskableCandidatePolicy(_CandidateHeads, MaskableActorCriticPolicy):
    """:class:`_CandidateHeads` on sb3-contrib's ``MaskableActorCriticPolicy``: the same network, given the env's
    action masks (MaskablePPO, and the batched trainer where the env masks actions, e.g. MultiHop's
    ``mask_unheld``); with ``subset`` a masked candidate is never drawn (:meth:`SubsetDistribution.apply_masking`)."""


POLICIES = {
    "mlp": "MlpPolicy",
    "candidates": CandidatePolicy,
    "candidate_set": CandidatePolicy,
    "candidate_subset": CandidatePolicy,
}
