"""Network structures for observations laid out as a list of candidates.

Several envs observe *candidates* (MultiHop's distance-ranked estimates, RendezvousMapping's landmarks):
``K`` blocks of ``F`` features each, then ``G`` features of the robot itself, and act on them one by one
(a select bit per candidate, or a choice among them). A plain MLP over the flat vector has to learn that
output k depends on block k, separately for every k. ``CandidatePolicy`` scores every candidate with the
same small network (permutation-equivariant, as in pointer/attention policies), so what it learns about one
candidate applies to all, and the same network serves any K.

An env declares its layout with ``observation_layout()`` → ``{"candidates": K, "features": F,
"globals": G, "extra_actions": E}``; ``E`` more logits (e.g. "hold") come from the robot's own features.
"""

from __future__ import annotations

import torch
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
        cand = obs[:, : self.k * self.f].reshape(-1, self.k, self.f)
        own = obs[:, self.k * self.f : self.k * self.f + self.g]
        paired = torch.cat([cand, own[:, None, :].expand(-1, self.k, -1)], dim=-1)
        return paired, own

    def forward_actor(self, obs: torch.Tensor) -> torch.Tensor:
        paired, own = self._split(obs)
        if self.context is not None:
            embedded = self.context(paired)
            summary = torch.cat([embedded.mean(dim=1), embedded.max(dim=1).values], dim=-1)
            paired = torch.cat([paired, summary[:, None, :].expand(-1, self.k, -1)], dim=-1)
        logits = self.scorer(paired).squeeze(-1)
        if self.extra is not None:
            logits = torch.cat([logits, self.extra(own)], dim=-1)
        return logits

    def forward_critic(self, obs: torch.Tensor) -> torch.Tensor:
        paired, own = self._split(obs)
        pooled = self.value_candidates(paired).mean(dim=1)
        return self.value_head(torch.cat([pooled, self.value_own(own)], dim=-1))

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(obs), self.forward_critic(obs)


class CandidatePolicy(ActorCriticPolicy):
    """SB3 actor-critic whose logits are the candidate scores themselves (no mixing layer after them)."""

    def __init__(self, *args, layout: dict, hidden: int = 64, context: bool = False, **kwargs):
        self.layout = dict(layout)
        self.hidden = hidden
        self.context = context
        super().__init__(*args, **kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = CandidateExtractor(
            self.layout["candidates"],
            self.layout["features"],
            self.layout["globals"],
            self.layout.get("extra_actions", 0),
            self.hidden,
            self.context,
        )

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        # the extractor's actor output already is one logit per action: SB3's linear action head would mix them
        self.action_net = nn.Identity()
        # small output weights, as SB3 gives its action head: the first policy is close to uniform
        self.init_weights(self.mlp_extractor.scorer[-1], gain=0.01)
        if self.mlp_extractor.extra is not None:
            self.init_weights(self.mlp_extractor.extra[-1], gain=0.01)
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def _get_constructor_parameters(self) -> dict:
        data = super()._get_constructor_parameters()
        data.update(layout=self.layout, hidden=self.hidden, context=self.context)
        return data


POLICIES = {"mlp": "MlpPolicy", "candidates": CandidatePolicy, "candidate_set": CandidatePolicy}
