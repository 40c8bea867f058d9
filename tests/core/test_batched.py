"""A batch of M copies (``mrcomm_env.make_batched``) is M single envs: copy i of a batch seeded s gives, episode
after episode, byte for byte the observations, rewards, ends, infos, bits and metrics of the PettingZoo env seeded
s + i driven with the same actions (its automatic resets continue the copy's own random stream, as a reset
without a seed does)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.batches import as_bytes, assert_copies_are_single_envs

import mrcomm_env
from mrcomm_env.core.batched import BatchedEnv, sample_actions
from mrcomm_env.registry import env_ids

#: small configurations with short episodes, so that every copy ends (and resets) more than once in a test
SMALL = {
    "mrcomm/AsyncCL-v0": {"n_robots": 3, "max_cycles": 6},
    "mrcomm/ChannelAssociation-v0": {"n_robots": 5, "max_cycles": 6},
    "mrcomm/MapSync-v0": {"max_cycles": 6},
    "mrcomm/MultiHop-v0": {"grid_side": 3, "max_cycles": 4},
    "mrcomm/RendezvousMapping-v0": {"n_vehicles": 4, "n_landmarks": 40, "area": 1600.0, "max_cycles": 4},
}
#: one more case per action-space kind and per scene that ends by itself (termination, not only truncation)
EXTRA_CASES = [
    ("mrcomm/MultiHop-v0", {"grid_side": 3, "max_cycles": 4, "layout": "absolute"}),  # Box actions
    ("mrcomm/ChannelAssociation-v0", {"scene": "neighborhood", "w": 3, "v": 2, "max_cycles": 12}),  # terminates
]


def test_every_env_has_a_small_batch_case():
    assert set(SMALL) == set(env_ids())


@pytest.mark.parametrize(("env_id", "kwargs"), [*SMALL.items(), *EXTRA_CASES], ids=lambda v: str(v))
def test_copy_i_of_a_batch_seeded_s_is_the_single_env_seeded_s_plus_i(env_id, kwargs):
    batch = mrcomm_env.make_batched(env_id, 3, **kwargs)
    assert_copies_are_single_envs(batch, env_id, kwargs, horizon=3 * kwargs["max_cycles"] + 2)


def test_copy_false_returns_the_batch_buffer_and_the_same_numbers():
    make = lambda: mrcomm_env.make("MultiHop-v0", grid_side=3, slot_size=2, max_cycles=4)  # noqa: E731
    copying, buffered = BatchedEnv(make, 2), BatchedEnv(make, 2, copy=False)
    first = copying.reset(seed=1)[0], buffered.reset(seed=1)[0]
    assert as_bytes(first[0]) == as_bytes(first[1])
    actions = np.ones((2, 9, 8), dtype=np.int8)
    kept = copying.step(actions).observations
    held = copying.step(actions).observations
    assert not np.shares_memory(kept, held)  # copy=True: every step a new array, which the next step leaves alone
    one, two = buffered.step(actions).observations, buffered.step(actions).observations
    assert np.shares_memory(one, two)  # copy=False: the batch's own buffer, rewritten by the next step
    assert as_bytes(two) == as_bytes(held)


def test_a_batch_refuses_bad_arguments_naming_them():
    with pytest.raises(ValueError, match="'n_copies' must be an integer ≥ 1"):
        mrcomm_env.make_batched("MapSync-v0", 0)
    with pytest.raises(ValueError, match="'n_copies' must be an integer ≥ 1"):
        mrcomm_env.make_batched("MapSync-v0", 2.0)
    with pytest.raises(ValueError, match="'make_copy' must build an mrcomm environment"):
        BatchedEnv(dict, 2)
    batch = mrcomm_env.make_batched("MapSync-v0", 2, max_cycles=3)
    with pytest.raises(RuntimeError, match="before reset"):
        batch.step(np.zeros((2, batch.n_agents), dtype=np.int64))
    batch.reset(seed=0)
    with pytest.raises(ValueError, match=r"'actions' must have shape \(copies, agents, \*action shape\) = \(2, 2\)"):
        batch.step(np.zeros((2, batch.n_agents + 1), dtype=np.int64))
    with pytest.raises(ValueError, match="'seed' must hold one seed per copy"):
        batch.reset(seed=[1, 2, 3])
    with pytest.raises(ValueError, match="'seed' must be None, an integer ≥ 0"):
        batch.reset(seed=-1)
    with pytest.raises(ValueError, match=r"action of robot_1 \(copy 1\) must be an integer"):
        batch.step(np.array([[0, 0], [0, 99]]))


def test_copies_that_together_exceed_the_memory_budget_are_refused_before_they_are_built():
    built = []
    cls = mrcomm_env.registry.env_class("MapSync-v0")
    budget_gib = 0.01
    cfg = cls(memory_budget_gib=budget_gib).cfg
    fits = max(m for m in range(1, 10_000) if cls.batch_memory_estimate(cfg, m) <= budget_gib * 2**30)
    # one copy's estimate is the env's own; each further copy adds its state, not the shared working memory
    per_copy = cls.batch_memory_estimate(cfg, 2) - cls.batch_memory_estimate(cfg, 1)
    assert 0 < per_copy < cls.memory_estimate(cfg) - cls.MEMORY_SHARED + 2**17
    assert cls.batch_memory_estimate(cfg, 1) == cls.memory_estimate(cfg)

    def make_copy():
        built.append(1)
        return cls(memory_budget_gib=budget_gib)

    BatchedEnv(make_copy, fits).close()  # at the budget: accepted
    built.clear()
    with pytest.raises(
        ValueError, match=rf"'n_copies' \({fits + 1} copies\) needs an estimated .* over the memory budget"
    ):
        BatchedEnv(make_copy, fits + 1)
    assert len(built) == 1  # the first copy states the estimate; no other was built


def test_step_arrays_is_step_without_dictionaries():
    env = mrcomm_env.make("ChannelAssociation-v0", n_robots=4, max_cycles=5)
    with pytest.raises(RuntimeError, match="before reset"):
        env.step_arrays(np.zeros(4, dtype=np.int64))
    env.reset_arrays(seed=0)
    with pytest.raises(ValueError, match=r"'actions' must hold one action per agent \(4\) in agent order, got shape"):
        env.step_arrays(np.zeros(3, dtype=np.int64))
    with pytest.raises(ValueError, match=r"'actions' must hold one action per agent \(4\) in agent order, got 5"):
        env.step_arrays([0] * 5)
    for _ in range(5):
        *_, terminated, truncated, _ = env.step_arrays(np.ones(4, dtype=np.int64))
    assert truncated and not terminated and env.agents == []
    with pytest.raises(RuntimeError, match="finished episode"):
        env.step_arrays(np.ones(4, dtype=np.int64))


@pytest.mark.parametrize("space_kind", ["discrete", "multibinary", "box"])
def test_sample_actions_draws_valid_actions_of_every_kind(space_kind):
    from gymnasium import spaces

    space = {
        "discrete": spaces.Discrete(3, start=2),
        "multibinary": spaces.MultiBinary(5),
        "box": spaces.Box(-1.0, 2.0, shape=(4,), dtype=np.float32),
    }[space_kind]
    actions = sample_actions(space, np.random.default_rng(1), (6, 7))
    assert actions.shape[:2] == (6, 7)
    assert all(space.contains(a if a.shape else int(a)) for a in actions.reshape(42, *space.shape))
    with pytest.raises(ValueError, match="'space' must be"):
        sample_actions(spaces.Box(-np.inf, np.inf, shape=(1,)), np.random.default_rng(1), (2,))


@pytest.mark.parametrize(
    ("env_id", "n_copies"), [("MultiHop-v0", 128), ("MapSync-v0", 256), ("RendezvousMapping-v0", 512)]
)
def test_a_batch_holds_about_what_its_memory_estimate_says(env_id, n_copies):
    """``batch_memory_estimate`` counts the shared working memory once and each copy's own state: within a factor
    of 2 of what the batch holds: the largest state per copy (MultiHop's copy-axis world, numba counted), MapSync's
    copy-axis world, and the largest shared part (RendezvousMapping, copies stepped in turn)."""
    from mrcomm_env.experiments.limits import measure_batched

    env = mrcomm_env.make(env_id)
    estimate_mb = env.batch_memory_estimate(env.cfg, n_copies) / 2**20
    result = measure_batched(env_id, {}, n_copies, seconds=0.0, min_steps=1, timeout=300)
    held_mb = result["rss_after_mb"] - result["rss_before_mb"]
    assert estimate_mb / 2 <= held_mb <= 2 * estimate_mb, (held_mb, estimate_mb)
    # while counting every copy at one env's peak would have been far above it
    assert n_copies * env.memory_estimate(env.cfg) / 2**20 > 2 * held_mb


#: a world that steps the copies as arrays (MapSync's unlimited links) and one whose copies step in turn
RESTART_CASES = [("MapSync-v0", {"max_cycles": 8}), ("AsyncCL-v0", {"n_robots": 3, "max_cycles": 8})]


@pytest.mark.parametrize(("env_id", "kwargs"), RESTART_CASES, ids=lambda v: str(v))
def test_restart_begins_new_episodes_of_the_named_copies_only(env_id, kwargs):
    batch = BatchedEnv(lambda: mrcomm_env.make(env_id, **kwargs), 3)
    singles = [mrcomm_env.make(env_id, **kwargs) for _ in range(3)]
    batch.reset(seed=4)
    agents = singles[0].possible_agents
    for i, env in enumerate(singles):
        env.reset(seed=4 + i)
    rng = np.random.default_rng(1)

    def step_all():
        actions = sample_actions(batch.action_space, rng, (3, batch.n_agents))
        out = batch.step(actions)
        single_obs = [env.step(dict(zip(agents, actions[i])))[0] for i, env in enumerate(singles)]
        return out, [np.stack([obs[a] for a in agents]) for obs in single_obs]

    for _ in range(3):
        step_all()
    reset_infos = batch.restart([1])
    first, first_infos = singles[1].reset()  # no seed: the copy's own stream goes on
    assert list(reset_infos) == [1]
    assert {k: v.tolist() for k, v in reset_infos[1].items()} == {
        k: [first_infos[a][k] for a in agents] for k in first_infos[agents[0]]
    }
    assert as_bytes(batch.observations[1]) == as_bytes(np.stack([first[a] for a in agents]))
    for _ in range(3):  # copy 1 is now three steps into its second episode, the others six into their first
        out, single_obs = step_all()
        for i, env in enumerate(singles):
            assert as_bytes(out.observations[i]) == as_bytes(single_obs[i])
            assert batch.bits_sent()[i] == env.bits_sent()
    frame = batch.render_copy(1)
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[-1] == 3


def test_restart_and_observations_need_a_reset_first():
    batch = BatchedEnv(lambda: mrcomm_env.make("MapSync-v0", max_cycles=4), 2)
    with pytest.raises(RuntimeError, match="reset"):
        batch.restart([0])
    with pytest.raises(RuntimeError, match="reset"):
        _ = batch.observations
