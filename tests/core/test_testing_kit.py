"""The conformance kit users run on their own env (``mrcomm_env.testing.check_env``): every registered env passes
every check, a PettingZoo env that is not ours passes the generic ones, and each check fails, naming itself, on an
env broken in the way it looks for."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from gymnasium import spaces
from mpe2 import simple_spread_v3
from pettingzoo import ParallelEnv

import mrcomm_env
from mrcomm_env.mapsync.env import MapSyncEnv
from mrcomm_env.testing import DECLARED_CHECKS, GENERIC_CHECKS, check_env

ALL_CHECKS = [*GENERIC_CHECKS, *DECLARED_CHECKS]
SHORT = {"max_cycles": 12}


@pytest.mark.parametrize("env_id", mrcomm_env.env_ids())
def test_every_registered_env_passes_every_check(env_id):
    # the documented configurations run inside (documented_configs); the default one here, its episodes cut short
    assert check_env(functools.partial(mrcomm_env.make, env_id, **SHORT), steps=12) == ALL_CHECKS


def test_a_pettingzoo_env_that_is_not_ours_gets_the_generic_checks():
    # MPE2's simple_spread: agents of one space, plain infos (none), a state()
    assert check_env(functools.partial(simple_spread_v3.parallel_env, max_cycles=10), steps=10) == list(GENERIC_CHECKS)


class _LateInfoKey(MapSyncEnv):
    def _agent_infos(self):
        infos = dict(super()._agent_infos())
        if self.step_count > 1:
            infos["late"] = np.zeros(self.n_agents)
        return infos


class _Relay(ParallelEnv):
    """A PettingZoo env that is not ours: two robots pass a counter; ``label`` adds a text info (which our base
    class could not even report: its infos are float columns)."""

    metadata = {"name": "relay_v0"}

    def __init__(self, label: bool = False, max_cycles: int = 12):
        self.possible_agents = ["a", "b"]
        self.label, self.max_cycles = label, max_cycles
        self._obs = spaces.Box(0.0, 1.0, shape=(1,), dtype=np.float32)
        self._act = spaces.Discrete(2)

    def observation_space(self, agent):
        return self._obs

    def action_space(self, agent):
        return self._act

    def _infos(self):
        return {a: ({"sent": 1.0, "label": "x"} if self.label else {"sent": 1.0}) for a in self.agents}

    def reset(self, seed=None, options=None):
        self.agents, self.t = list(self.possible_agents), 0
        self.value = np.random.default_rng(seed).uniform(0.0, 1.0)
        return {a: np.array([self.value], dtype=np.float32) for a in self.agents}, self._infos()

    def step(self, actions):
        self.t += 1
        self.value = (self.value + 0.1 * sum(actions.values())) % 1.0
        obs = {a: np.array([self.value], dtype=np.float32) for a in self.agents}
        rewards = {a: float(self.value) for a in self.agents}
        done = self.t >= self.max_cycles
        ends = {a: False for a in self.agents}
        truncations = {a: done for a in self.agents}
        infos = self._infos()
        if done:
            self.agents = []
        return obs, rewards, ends, truncations, infos


class _UnseededNoise(MapSyncEnv):
    def _observe(self):
        obs = super()._observe()
        return np.clip(obs + np.random.default_rng().uniform(0.0, 1e-3, obs.shape).astype(obs.dtype), 0.0, 1.0)


class _ObservationOutOfSpace(MapSyncEnv):
    def _observe(self):
        return super()._observe() + 2.0


class _MemoryGrowsWithHorizon(MapSyncEnv):
    @classmethod
    def memory_estimate(cls, cfg):
        return super().memory_estimate(cfg) + 8.0 * cfg["max_cycles"]


class _AcceptsAnyAction(MapSyncEnv):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._check_action = lambda agents, actions: [int(a) % self._act_space.n for a in actions]


@pytest.mark.parametrize(
    ("broken", "check"),
    [
        (_LateInfoKey, "plain_infos"),
        (functools.partial(_Relay, label=True), "plain_infos"),
        (_UnseededNoise, "parallel_seed"),  # PettingZoo's own seed test catches it before ours
        (_ObservationOutOfSpace, "finite_in_space"),
        (_MemoryGrowsWithHorizon, "memory_budget"),
        (_AcceptsAnyAction, "bad_actions"),
    ],
    ids=lambda v: v if isinstance(v, str) else getattr(v, "__name__", "relay_with_text_info"),
)
def test_each_check_fails_naming_itself_on_an_env_broken_its_way(broken, check):
    with pytest.raises(AssertionError, match=f"check '{check}' failed"):
        check_env(functools.partial(broken, **SHORT), steps=12)


def test_the_foreign_env_without_its_flaw_passes():
    # the control for the text-info case above: the same env with plain infos passes every generic check
    assert check_env(_Relay, steps=12) == list(GENERIC_CHECKS)


def test_the_determinism_check_stands_on_its_own():
    # run alone, it catches what PettingZoo's seed test caught above, naming the first step that differs
    with pytest.raises(AssertionError, match="reset of seed 0 differs between two runs"):
        GENERIC_CHECKS["deterministic_episodes"](functools.partial(_UnseededNoise, **SHORT), 0, 12)
