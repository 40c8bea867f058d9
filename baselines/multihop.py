"""Scripted slot-filling policies for MultiHop-v0 (Julian et al., paper 003).

Each policy ranks robot i's estimates by a priority; in the env's ``absolute`` layout (v0) the priorities
are the action, and the env sends i's own estimate plus the ``m − 1`` known estimates of highest priority
at i's slot (priority 0 withholds). In the default ``relative`` layout the policy selects its ``m − 1``
highest-priority estimates, as select bits over the env's distance-ranked candidates. Every policy here
reads only what robot i knows: its own position, its estimate list (positions, time stamps) and what it
sent.

* ``location_based`` — Algorithm 1 with persistent counters, O(mn) per robot and frame, vectorised over
  all robots (``rule="text"``: lowest counter as §3.2 says; ``rule="listing"``: argmax as printed).
* ``probabilistic`` — eq. (2): sample without replacement proportional to ``d^-α`` (Gumbel-top-k).
* ``flooding`` — all known estimates (meant for ``slot_size = n``; below that it rotates round-robin).
* ``no_hop`` — only the robot's own estimate (the paper's m = 1 scheme at any m).
* ``age_aware`` — ours: rank by ``d^-α × (t_ij − s_ij)``, importance times the freshness gained since the
  robot last broadcast j (``s_ij`` = the stamp it sent then). An estimate whose stamp it already sent is
  held by every neighbour on a static lossless channel, so resending it is wasted room; ``f × gain`` is
  the importance-weighted age its neighbours shed. Estimates without gain only fill leftover room.
* ``heard_aware`` — ours, with ``observe_heard``: rank by ``d^-α × Σ_k (t_ij − h_ikj)⁺``, importance times the
  freshness robot i's neighbours k ≠ j lack beyond the freshest stamp ``h_ikj`` it heard k broadcast or broadcast
  to k (the local view's ``heard``); ``age_aware``'s idea with each neighbour's table bounded from what the robot
  heard instead of from its own broadcasts alone. Estimates no neighbour lacks are not sent.
* ``random`` — uniform random priorities.
"""

from __future__ import annotations

import numpy as np

from mrcomm_baselines.common import RandomPolicy
from mrcomm_env.core.config import Choice, Param
from mrcomm_env.core.policy import Policy
from mrcomm_env.multihop import protocol as proto

ENV_ID = "mrcomm/MultiHop-v0"
DEFAULT_POLICY = "location_based"


def _as_actions(views, prio: np.ndarray, observations) -> dict:
    """Each robot's (N,) priorities as the env's action. In the ``absolute`` layout that is the action itself;
    in the ``relative`` one each robot selects the ``m − 1`` others of highest positive priority, mapped to
    their candidate ranks (the env then sends those it holds at its slot)."""
    if views.params["layout"] == "absolute":
        prio = prio.astype(np.float32)
        return {a: prio[views.index(a)] for a in observations}
    n, room = views.n_agents, _slot_size(views) - 1
    p = np.where(np.eye(n, dtype=bool), -1.0, prio)
    top = np.argsort(-p, axis=1, kind="stable")[:, :room]
    chosen = np.zeros((n, n), dtype=bool)
    rows = np.repeat(np.arange(n), top.shape[1])
    chosen[rows, top.ravel()] = np.take_along_axis(p, top, axis=1).ravel() > 0.0
    selected = np.take_along_axis(chosen, views.team("candidates"), axis=1).astype(np.int8)
    return {a: selected[views.index(a)] for a in observations}


def _importance(views) -> tuple[np.ndarray, np.ndarray]:
    """Each robot's eq. (1) importances of its own estimates and which estimates it holds (row i: robot i's)."""
    known = views.team("stamps") > proto.UNKNOWN
    return proto.importance(views.team("estimated_distances"), known, views.params["alpha"]), known


def _slot_size(views) -> int:
    return int(views.team("slot_size")[0])


def _rank_priorities(order: np.ndarray, n: int, base: np.ndarray) -> np.ndarray:
    """Priorities in (0.5, 1] for ``order`` (n, m) (first = highest), ``base`` (< 0.5) elsewhere."""
    prio = base.copy()
    m = order.shape[1]
    rows = np.repeat(np.arange(n), m)
    cols = order.ravel()
    val = np.tile(1.0 - np.arange(m) / (2.0 * m), n)
    ok = cols >= 0
    prio[rows[ok], cols[ok]] = val[ok]
    return prio


def _fill(f: np.ndarray) -> np.ndarray:
    """Below-selection priorities: by importance in (0.01, 0.4]; unknown estimates 0.005 so that one that
    arrives before the robot's slot still fills room left over (as Algorithm 1 run at the slot would)."""
    fmax = np.maximum(f.max(axis=1, keepdims=True), 1e-300)
    return np.where(f > 0, 0.01 + 0.39 * f / fmax, 0.005)


class LocationBased(Policy):
    """Algorithm 1 with persistent counters (§3.2), one counter row per robot."""

    name = "location_based"
    FROM_PAPER = "Algorithm 1, §3.2"
    PARAMS = {
        "rule": Param(
            "text",
            "`text`: take the lowest counter (§3.2); `listing`: argmax as printed in Algorithm 1",
            Choice(("text", "listing")),
        )
    }

    def reset(self, views, seed=None):
        super().reset(views, seed)
        self.counters = np.ones((views.n_agents, views.n_agents))

    def act(self, observations, views):
        n = views.n_agents
        f, known = _importance(views)
        order = proto.location_based_select(self.counters, f, known, np.arange(n), _slot_size(views), self.params.rule)
        return _as_actions(views, _rank_priorities(order, n, _fill(f)), observations)


class AgeAware(Policy):
    """Ours: importance × freshness gained since this robot last broadcast the estimate (see
    :func:`mrcomm_env.multihop.protocol.age_aware_select`); no counters needed."""

    name = "age_aware"

    def act(self, observations, views):
        n = views.n_agents
        f, known = _importance(views)
        order = proto.age_aware_select(
            f, views.team("stamps"), views.team("sent_stamp"), known, np.arange(n), _slot_size(views)
        )
        return _as_actions(views, _rank_priorities(order, n, _fill(f)), observations)


class HeardAware(Policy):
    """Ours, on an env with ``observe_heard`` (module docstring): what each neighbour lacks, from what the robot
    heard; sends only estimates some neighbour lacks."""

    name = "heard_aware"

    def reset(self, views, seed=None):
        super().reset(views, seed)
        if views.team("heard").shape[1] == 0:
            raise ValueError("policy 'heard_aware' needs MultiHop-v0 with observe_heard=True (its local view 'heard')")

    def act(self, observations, views):
        f, known = _importance(views)
        heard = views.team("heard")
        neighbour = np.isfinite(heard).any(axis=2)  # [i, k]: k was heard (every robot broadcasts its own estimate)
        held = np.where(known, views.team("stamps"), 0.0)
        lacking = np.maximum(held[:, None, :] - np.where(np.isfinite(heard), heard, 0.0), 0.0)
        judged = neighbour[:, :, None] & ~np.eye(views.n_agents, dtype=bool)[None]  # k's own estimate is current
        gain = f * np.where(judged, lacking, 0.0).sum(axis=1)
        return _as_actions(views, np.where(known, gain, 0.0), observations)


class Probabilistic(Policy):
    """Eq. (2): successive draws proportional to d^-α without replacement (Plackett–Luce = Gumbel-top-k)."""

    name = "probabilistic"
    FROM_PAPER = "eq. (2), §3.1"

    def act(self, observations, views):
        n = views.n_agents
        f, known = _importance(views)
        order = proto.probabilistic_select(self.rng, f, known, np.arange(n), _slot_size(views))
        return _as_actions(views, _rank_priorities(order, n, _fill(f)), observations)


class Flooding(Policy):
    """Every known estimate (slot_size = n); with a shorter slot, a round-robin window over the list."""

    name = "flooding"
    FROM_PAPER = "§2.1 and §4, simple flooding with m = n"

    def reset(self, views, seed=None):
        super().reset(views, seed)
        self.frame = 0

    def act(self, observations, views):
        n, m = views.n_agents, _slot_size(views)
        offset = self.frame * max(m - 1, 1)
        self.frame += 1
        j = np.arange(n)
        prio = 1.0 - ((j[None, :] - j[:, None] - 1 - offset) % n) / n
        return _as_actions(views, prio, observations)


class NoHop(Policy):
    """Only the robot's own estimate (the paper's m = 1 scheme)."""

    name = "no_hop"
    FROM_PAPER = "§4, the no-hop scheme with m = 1"

    def act(self, observations, views):
        return _as_actions(views, np.zeros((views.n_agents, views.n_agents)), observations)


POLICIES = {
    "location_based": LocationBased,
    "flooding": Flooding,
    "no_hop": NoHop,
    "probabilistic": Probabilistic,
    "age_aware": AgeAware,
    "heard_aware": HeardAware,
    "random": RandomPolicy,
}
