"""Scripted sync schedules for MapSync-v0 (Alsayegh et al., paper 002).

The action of a robot picks a protocol (0 idle, 1 equality, 2 bisection, 3 full, 4 sketch); the env pairs it
with the linked peer it synced with least recently, and when both ends ask, one sync runs. Every policy here
reads only the shared step clock and the robot's own local view (``busy``, ``last_test``).

* ``periodic_equality_then_bisection`` — the paper's case study (§V-C): every ``period`` = 10 moves the robots
  test their maps and correct them with Algorithm 1 when they differ. Algorithm 1's first call *is*
  Protocol 1 on the whole map (line 7 with l = 1, u = n), so by default one ``bisection`` action does both
  without paying the whole-map test twice; ``separate_test=True`` runs ``equality`` first and ``bisection``
  on the next step only after a "different" verdict, as the case study's prose can also be read.
* ``periodic_full`` — every ``period`` moves, send the whole map (the naive O(n) protocol of §I).
* ``periodic_sketch`` — every ``period`` moves, the streaming PinSketch (beyond the paper).
* ``never`` — no communication: the floor of bits and the ceiling of disagreement.
* ``random`` — uniformly random actions.
"""

from __future__ import annotations

import numpy as np

from mrcomm_baselines.common import RandomPolicy
from mrcomm_env.core.config import Bool, Int, Param
from mrcomm_env.core.policy import Policy
from mrcomm_env.mapsync.env import BISECTION, EQUALITY, FULL, IDLE, SKETCH, TEST_DIFFERENT
from mrcomm_env.mapsync.world import PAPER_PERIOD

ENV_ID = "mrcomm/MapSync-v0"
DEFAULT_POLICY = "periodic_equality_then_bisection"

_PERIOD = Param(PAPER_PERIOD, "sync every this many moves (the case study: 10)", Int(lo=1))


class _Periodic(Policy):
    """Ask for ``protocol`` every ``period`` moves (at steps period, 2·period, …)."""

    PARAMS = {"period": _PERIOD}
    protocol = IDLE

    def __init__(self, **params):
        super().__init__(**params)
        self._period = self.params.period  # read every step: a plain attribute

    def due(self, views) -> bool:
        step = views.step
        return step > 0 and step % self._period == 0

    def act(self, observations, views):
        action = self.protocol if self.due(views) else IDLE
        return dict.fromkeys(observations, action)


class PeriodicFull(_Periodic):
    """Every ``period`` moves, send the whole map (n bits) and merge."""

    name = "periodic_full"
    FROM_PAPER = "§I, the naive O(n) protocol"
    protocol = FULL


class PeriodicSketch(_Periodic):
    """Every ``period`` moves, reconcile with the streaming PinSketch (bits close to log2 C(n, d))."""

    name = "periodic_sketch"
    protocol = SKETCH


class PeriodicEqualityThenBisection(_Periodic):
    """The paper's case study: every ``period`` moves test the maps (Protocol 1) and, if they differ, correct
    them with Algorithm 1 (one ``bisection`` action, whose first call is the whole-map test, unless
    ``separate_test``)."""

    name = "periodic_equality_then_bisection"
    FROM_PAPER = "§V-C, the case study"
    PARAMS = {
        "period": _PERIOD,
        "separate_test": Param(
            False,
            "run `equality` first and `bisection` on the next step only after a "
            '"different" verdict (pays the whole-map test twice when they differ)',
            Bool(),
        ),
    }

    def reset(self, views, seed=None):
        super().reset(views, seed)
        self.tested_at = np.full(views.n_agents, -2, dtype=np.int64)

    def act(self, observations, views):
        if not self.params.separate_test:
            action = BISECTION if self.due(views) else IDLE
            return dict.fromkeys(observations, action)
        out = {}
        step = views.step
        for agent in observations:
            i = views.index(agent)
            mine = views[agent]
            if self.due(views):
                out[agent] = EQUALITY
                self.tested_at[i] = step
            elif self.tested_at[i] == step - 1 and not mine["busy"] and (mine["last_test"] == TEST_DIFFERENT).any():
                out[agent] = BISECTION
            else:
                out[agent] = IDLE
        return out


class Never(Policy):
    """Never communicate."""

    name = "never"

    def act(self, observations, views):
        return dict.fromkeys(observations, IDLE)


POLICIES = {
    "periodic_equality_then_bisection": PeriodicEqualityThenBisection,
    "periodic_full": PeriodicFull,
    "periodic_sketch": PeriodicSketch,
    "never": Never,
    "random": RandomPolicy,
}
