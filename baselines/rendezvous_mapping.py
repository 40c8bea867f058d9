"""Scripted planners for RendezvousMapping-v0 (Chapman & Sukkarieh, paper 004).

Actions are ``Discrete(K + 2)``: ``0 … K−1`` go to candidate i, ``K`` rendezvous at the group's central
landmark l_c (observing l_p(v) on the way when the detour fits), ``K + 1`` hold. Every policy reads only what
each vehicle knows: its own map, the positions it learnt at the last fusion, its candidates and mask. Members
of a connected group hold identical maps after fusion, so a group's plan is computed once, from its
lowest-index member's view, which is what each member would compute alone.

* ``paper_protocol`` — §IV–§V: utility matrix eq. (1)–(4), Munkres (``linear_sum_assignment``), clusters
  (connected components = fine Dulmage–Mendelsohn blocks), cluster value eq. (6), eigenvector centrality,
  partition eq. (7)–(8) until connected (``mrcomm_env.rendezvous.protocol``), then the Action module of
  Fig. 5: (1) assigned? (2) in the main cluster? (3) reachable, ‖x_lp − x_v‖ < u t_window? (4) path to l_c,
  ‖x_lp − x_v‖ + ‖x_lc − x_lp‖ < u t_window? give action 1 (observe l_p and stay), 2 (observe l_p, then
  rendezvous at l_c) or 3 (go to l_c and wait). Actions 2 and 3 are both the env's rendezvous action,
  which applies condition (4) itself. When d_comms covers the whole area every position is connected, the
  module is bypassed (§VI-B.2) and every vehicle heads for l_p, reachable or not (the ε utility of §IV-A).
  The paper does not say what a team split by a failed rendezvous does; here every member of a group smaller
  than the team takes the rendezvous action, which then leads to the last whole-team l_c (the env's regroup
  rule), observing l_p on the way when the detour fits.
* ``no_partition`` — §VI-B.2: Munkres over the candidates, no partition and no rendezvous (infinite
  communication assumed).
* ``always_rendezvous`` — §VI-B.3: continuous rendezvousing, every vehicle takes the rendezvous action.
* ``greedy`` — each vehicle goes to its own highest-utility candidate, ignoring teammates and connectivity.
* ``random`` — a uniformly random *feasible* action (the mask is honoured).
"""

from __future__ import annotations

import math

import numpy as np

from mrcomm_env.core.policy import LocalViews, Policy
from mrcomm_env.rendezvous import protocol, theory

ENV_ID = "mrcomm/RendezvousMapping-v0"
DEFAULT_POLICY = "paper_protocol"

#: the three actions of §V, as reported by ``PaperProtocol.last_actions``, and regrouping a split team
OBSERVE, OBSERVE_THEN_RENDEZVOUS, RENDEZVOUS, REGROUP = 1, 2, 3, 4


def groups(views: LocalViews) -> list[np.ndarray]:
    """The connected groups, each as its members (every vehicle knows its own group)."""
    group = np.asarray(views.team("group"))
    seen = np.zeros(len(group), dtype=bool)
    out = []
    for v in range(len(group)):
        if not seen[v]:
            members = np.flatnonzero(group[v])
            seen[members] = True
            out.append(members)
    return out


def group_utility(views: LocalViews, members: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. (1)–(4) for one group from its lowest member's view: (U, landmark estimates, member positions)."""
    p = views.params
    w = int(members[0])
    est = np.asarray(views.team("landmark_estimates")[w])
    pos = np.asarray(views.team("known_positions")[w])[members]
    U = protocol.utility_matrix(
        np.asarray(views.team("map_information")[w]),
        np.asarray(views.team("map_count")[w]),
        pos,
        est,
        p["speed"],
        p["t_window"],
        theory.information_per_observation(p["obs_sigma"]),
        p["obs_rate"],
        p["obs_per_landmark"],
    )
    return U, est, pos


def slot_of(candidates: np.ndarray, landmark: int) -> int:
    """The candidate slot holding ``landmark``, −1 if it is not listed."""
    hit = np.flatnonzero(candidates == landmark)
    return int(hit[0]) if len(hit) else -1


class PaperProtocol(Policy):
    """§IV recommendation phase and §V Action module (Fig. 5)."""

    name = "paper_protocol"
    FROM_PAPER = "§IV–§V"

    def reset(self, views, seed=None):
        super().reset(views, seed)
        self.last_actions = np.zeros(views.n_agents, dtype=np.int64)
        self.last_plans: dict[int, protocol.Recommendation] = {}

    def act(self, observations, views):
        p = views.params
        K = int(views.action_space.n) - 2
        d_max = p["speed"] * p["t_window"]
        everywhere_linked = p["d_comms"] >= math.sqrt(2.0 * p["area"])  # the whole square is in range
        cands = np.asarray(views.team("candidates"))
        actions = np.full(views.n_agents, K, dtype=np.int64)
        self.last_plans = {}
        for members in groups(views):
            U, est, pos = group_utility(views, members)
            rec = protocol.recommend(U, est, p["d_comms"])
            self.last_plans[int(members[0])] = rec
            if len(members) < views.n_agents:  # the team is split: regroup (the env's rule), l_p on the way
                self.last_actions[members] = REGROUP
                continue
            for row, v in enumerate(members.tolist()):
                kind = action_module(rec, row, pos[row], est, d_max, everywhere_linked)
                self.last_actions[v] = kind
                if kind == OBSERVE:
                    slot = slot_of(cands[v], int(rec.assignment[row]))
                    actions[v] = slot if slot >= 0 else K  # not listed (believed exhausted): regroup instead
        return {a: int(actions[views.index(a)]) for a in observations}


def action_module(
    rec: protocol.Recommendation,
    row: int,
    x_v: np.ndarray,
    est: np.ndarray,
    d_max: float,
    everywhere_linked: bool = False,
) -> int:
    """Fig. 5: which of the three actions of §V vehicle ``row`` of the plan takes."""
    lp = int(rec.assignment[row])
    if lp < 0:  # condition 1: not assigned
        return RENDEZVOUS
    to_lp = float(np.hypot(*(est[lp] - x_v)))
    if everywhere_linked:
        return OBSERVE
    if rec.in_main[row]:  # condition 2
        return OBSERVE if to_lp < d_max else RENDEZVOUS  # condition 3
    to_lc = float(np.hypot(*(est[rec.central] - est[lp])))
    return OBSERVE_THEN_RENDEZVOUS if to_lp + to_lc < d_max else RENDEZVOUS  # condition 4


class NoPartition(Policy):
    """§VI-B.2: Munkres over each vehicle's candidates; no partition, no rendezvous."""

    name = "no_partition"
    FROM_PAPER = "§VI-B.2"

    def act(self, observations, views):
        K = int(views.action_space.n) - 2
        cands = np.asarray(views.team("candidates"))
        utils = np.asarray(views.team("candidate_utility"))
        actions = np.full(views.n_agents, K + 1, dtype=np.int64)
        for members in groups(views):
            U, _, _ = group_utility(views, members)
            listed = np.full(U.shape, -1.0)  # utilities are ≥ 0, so an unlisted landmark is never preferred
            for row, v in enumerate(members.tolist()):
                ok = cands[v] >= 0
                listed[row, cands[v][ok]] = U[row, cands[v][ok]]
            rows, lms = protocol.assign(listed, np.arange(U.shape[1]))
            for row, lm in zip(rows.tolist(), lms.tolist()):
                v = int(members[row])
                slot = slot_of(cands[v], lm) if listed[row, lm] >= 0 else -1
                if slot < 0 and (cands[v] >= 0).any():
                    slot = int(np.argmax(np.where(cands[v] >= 0, utils[v], -np.inf)))
                if slot >= 0:
                    actions[v] = slot
        return {a: int(actions[views.index(a)]) for a in observations}


class AlwaysRendezvous(Policy):
    """§VI-B.3: every vehicle regroups at l_c at every phase (observing l_p on the way when it fits)."""

    name = "always_rendezvous"
    FROM_PAPER = "§VI-B.3"

    def act(self, observations, views):
        K = int(views.action_space.n) - 2
        return dict.fromkeys(observations, K)


class Greedy(Policy):
    """Each vehicle to its own best candidate (eq. 1), ignoring teammates and connectivity."""

    name = "greedy"

    def act(self, observations, views):
        K = int(views.action_space.n) - 2
        cands = np.asarray(views.team("candidates"))
        utils = np.where(cands >= 0, np.asarray(views.team("candidate_utility")), -np.inf)
        best = np.argmax(utils, axis=1)
        actions = np.where(np.isfinite(utils.max(axis=1)), best, K + 1)
        return {a: int(actions[views.index(a)]) for a in observations}


class MaskedRandom(Policy):
    """A uniformly random feasible action per vehicle (seeded through ``reset``)."""

    name = "random"

    def act(self, observations, views):
        mask = np.asarray(views.team("action_mask"))
        out = {}
        for a in observations:
            out[a] = int(self.rng.choice(np.flatnonzero(mask[views.index(a)])))
        return out


POLICIES = {
    "paper_protocol": PaperProtocol,
    "no_partition": NoPartition,
    "always_rendezvous": AlwaysRendezvous,
    "greedy": Greedy,
    "random": MaskedRandom,
}
