"""Bad actions and seeds get a ValueError that says what is allowed, for every env; numpy integer seeds work."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces

import mrcomm_env
from mrcomm_env.registry import env_ids

SMALL = {
    "mrcomm/AsyncCL-v0": {"n_robots": 3, "max_cycles": 5},
    "mrcomm/ChannelAssociation-v0": {"n_robots": 4, "max_cycles": 5},
    "mrcomm/MultiHop-v0": {"grid_side": 3, "max_cycles": 5},
}


def small_env(env_id, **overrides):
    env = mrcomm_env.make(env_id, **{**SMALL.get(env_id, {"max_cycles": 5}), **overrides})
    env.reset(seed=0)
    return env


def valid_actions(env):
    return {a: env.action_space(a).sample() for a in env.agents}


@pytest.mark.parametrize("env_id", env_ids())
@pytest.mark.parametrize("actions", [None, [0, 0, 0], (1,), "robot_0", 3], ids=repr)
def test_actions_must_be_a_dict_keyed_by_agent(env_id, actions):
    with pytest.raises(ValueError, match="dict keyed by agent"):
        small_env(env_id).step(actions)


@pytest.mark.parametrize("env_id", env_ids())
@pytest.mark.parametrize("seed", [-1, 1.5, True, "3", 2.0])
def test_bad_seeds_are_value_errors(env_id, seed):
    with pytest.raises(ValueError, match="'seed'"):
        small_env(env_id).reset(seed=seed)


@pytest.mark.parametrize("env_id", env_ids())
def test_numpy_integer_seeds_give_the_same_episode_as_ints(env_id):
    a, b = small_env(env_id), small_env(env_id)
    obs_a, _ = a.reset(seed=3)
    obs_b, _ = b.reset(seed=np.int64(3))
    for agent in a.agents:
        np.testing.assert_array_equal(obs_a[agent], obs_b[agent])
    actions = valid_actions(a)
    assert a.step(actions)[1] == b.step(actions)[1]


def discrete_envs():
    return [e for e in env_ids() if isinstance(small_env(e).action_space("robot_0"), spaces.Discrete)]


#: Box actions: MultiHop's v0 layout (its default layout is MultiBinary)
BOX_CASES = [("mrcomm/MultiHop-v0", {"layout": "absolute"})]
MULTIBINARY_CASES = [("mrcomm/MultiHop-v0", {"layout": "relative"})]


@pytest.mark.parametrize("env_id", discrete_envs())
@pytest.mark.parametrize("bad", [1.0, 1 + 0j, np.float32(1.0), "1", np.array([1]), None], ids=repr)
def test_discrete_actions_follow_gymnasiums_contains(env_id, bad):
    env = small_env(env_id)
    assert not env.action_space("robot_0").contains(bad)  # gymnasium agrees these are not actions
    actions = valid_actions(env)
    actions[env.agents[-1]] = bad
    with pytest.raises(ValueError, match=f"action of {env.agents[-1]}"):
        env.step(actions)


@pytest.mark.parametrize("env_id", discrete_envs())
def test_discrete_accepts_numpy_integers(env_id):
    env = small_env(env_id)
    env.step({a: np.int64(0) for a in env.agents})


@pytest.mark.parametrize(("env_id", "kwargs"), BOX_CASES)
def test_box_actions_name_the_agent_at_fault(env_id, kwargs):
    env = small_env(env_id, **kwargs)
    assert isinstance(env.action_space("robot_0"), spaces.Box)
    shape = env.action_space("robot_0").shape
    victim = env.agents[len(env.agents) // 2]
    for bad, words in [
        (np.zeros(shape[0] - 1), "shape"),  # ragged: numpy cannot stack the batch
        (np.zeros(shape) + 0.5j, "real"),  # complex: the imaginary part must not be dropped silently
        (np.full(shape, np.nan), "finite"),
        (np.full(shape, 2.0), "within"),
        ([0.1] * (shape[0] + 1), "shape"),
    ]:
        actions = {a: np.zeros(shape, dtype=np.float32) for a in env.agents}
        actions[victim] = bad
        with pytest.raises(ValueError, match=f"action of {victim} .*{words}"):
            env.step(actions)


@pytest.mark.parametrize(("env_id", "kwargs"), MULTIBINARY_CASES)
def test_multibinary_actions_name_the_agent_at_fault(env_id, kwargs):
    env = small_env(env_id, **kwargs)
    space = env.action_space("robot_0")
    assert isinstance(space, spaces.MultiBinary)
    victim = env.agents[1]
    for bad in (
        np.full(space.shape, 2),
        np.zeros(space.shape[0] + 1, dtype=np.int8),
        np.full(space.shape, 0.5),
        np.zeros(space.shape) + 1j,
        "0101",
    ):
        assert not space.contains(bad)  # gymnasium agrees these are not actions
        actions = {a: np.zeros(space.shape, dtype=np.int8) for a in env.agents}
        actions[victim] = bad
        with pytest.raises(ValueError, match=f"action of {victim}"):
            env.step(actions)
    # float 0/1 arrays are actions, as gymnasium's MultiBinary.contains says (SB3 sends float32)
    env.step({a: np.ones(space.shape, dtype=np.float32) for a in env.agents})
