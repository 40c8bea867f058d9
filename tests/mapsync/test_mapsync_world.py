"""MapSync's copy-axis world (mapsync/copy_axis.py): each copy is the single env seeded s + i, recent bits fade as
the env's do, and state changed from outside is taken in."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.batches import as_bytes, assert_copies_are_single_envs
from hypothesis import given, settings
from hypothesis import strategies as st

import mrcomm_env
from mrcomm_env.core.batched import BatchedEnv

MAPSYNC_COPY_AXIS_CASES = [
    {"max_cycles": 25},
    {"appear_rate": 0.002, "vanish_rate": 0.02, "max_cycles": 30},
    {"preset": "paper", "max_cycles": 20},
    {"n_robots": 5, "grid_size": 8, "appear_rate": 0.02, "vanish_rate": 0.05, "max_cycles": 20},
    {"n_robots": 9, "grid_size": 6, "appear_rate": 0.05, "res": 4, "k": 1, "max_cycles": 15},
    {"n_robots": 3, "grid_size": 3, "n_obstacles": 8, "lam": 5.0, "max_cycles": 10},
    {"grid_size": 4, "explicit_database": True, "max_cycles": 12},
]


def _assert_mapsync_copies_hold_the_single_envs_state(batch, singles):
    batch.sync_copies()
    for copy, single in zip(batch.envs, singles):
        for name in ("maps", "stamps", "truth", "pos", "known", "new_cells", "last_sync", "last_test", "robot_syncs"):
            assert as_bytes(getattr(copy, name)) == as_bytes(getattr(single, name)), name
        assert list(copy.detections) == list(single.detections) and copy._next_session == single._next_session
        assert copy.np_random.bit_generator.state == single.np_random.bit_generator.state
        mine, theirs = copy.metrics(), single.metrics()
        assert mine.keys() == theirs.keys()
        assert all(mine[k] == theirs[k] or (np.isnan(mine[k]) and np.isnan(theirs[k])) for k in mine), (mine, theirs)


@pytest.mark.parametrize("kwargs", MAPSYNC_COPY_AXIS_CASES, ids=lambda v: str(v))
def test_a_mapsync_copy_axis_world_gives_each_copy_the_single_env_episodes(kwargs):
    env_id = "mrcomm/MapSync-v0"
    batch = mrcomm_env.make_batched(env_id, 3, **kwargs)
    assert batch.world is not None  # no bits_per_step, links always up
    singles = assert_copies_are_single_envs(batch, env_id, kwargs, 2 * kwargs["max_cycles"] + 3)
    _assert_mapsync_copies_hold_the_single_envs_state(batch, singles)
    assert sum(env.metrics()["syncs"] for env in singles) > 0


@st.composite
def _mapsync_world_configurations(draw):
    """MapSync arguments its copy-axis world takes (no bits_per_step, links always up): grids from 2×2, teams of
    up to 8 (busy peers), 1 to 12 Protocol 1 rounds, Algorithm 1's resolutions, still and changing worlds (OR and
    last-writer-wins merges), bit prices."""
    size = draw(st.integers(2, 10))
    return {
        "grid_size": size,
        "n_robots": draw(st.integers(2, 8)),
        "n_obstacles": draw(st.integers(0, min(size * size - 1, 15))),
        "k": draw(st.integers(1, 12)),
        "res": draw(st.sampled_from([1, 2, 5, 16])),
        "appear_rate": draw(st.sampled_from([0.0, 0.01, 0.2])),
        "vanish_rate": draw(st.sampled_from([0.0, 0.05, 0.5])),
        "lam": draw(st.sampled_from([0.0, 0.1, 3.0])),
        "database_seed": draw(st.integers(0, 2**63 - 1)),
        "max_cycles": draw(st.integers(1, 10)),
    }


@settings(max_examples=25, deadline=None)
@given(kwargs=_mapsync_world_configurations())
def test_a_mapsync_copy_axis_world_of_drawn_configurations_gives_each_copy_the_single_env_episodes(kwargs):
    """The fixed cases above, and drawn ones (25 per run, the same ones in ``make test``)."""
    batch = mrcomm_env.make_batched("mrcomm/MapSync-v0", 3, **kwargs)
    assert batch.world is not None
    singles = assert_copies_are_single_envs(batch, "mrcomm/MapSync-v0", kwargs, 2 * kwargs["max_cycles"] + 2)
    _assert_mapsync_copies_hold_the_single_envs_state(batch, singles)


def test_the_mapsync_world_is_for_links_without_a_budget_and_refuses_what_the_env_refuses():
    for limited in ({"bits_per_step": 64}, {"comm_range": 5.0}, {"link_prob": 0.5}):
        assert mrcomm_env.make_batched("MapSync-v0", 2, **limited).world is None  # the copies step in turn
    make = lambda: mrcomm_env.make("MapSync-v0", max_cycles=6)  # noqa: E731
    world, in_turn = BatchedEnv(make, 2), BatchedEnv(make, 2, copy_axis=False)
    assert world.world is not None and in_turn.world is None
    world.reset(seed=1)
    in_turn.reset(seed=1)
    bad = np.array([[0, 1], [5, 0]])
    with pytest.raises(ValueError, match=r"action of robot_0 \(copy 1\) must be an integer in \[0, 4\], got 5"):
        world.step(bad)
    with pytest.raises(ValueError, match=r"action of robot_0 must be an integer in \[0, 4\]"):
        in_turn.step(bad)  # the env objects refuse it alike
    with pytest.raises(ValueError, match=r"'actions' must hold integers in \[0, 4\]"):
        world.step(np.ones((2, 2)))  # 1.0 is not an action of Discrete(5), as for the env


def test_a_mapsync_world_lets_the_recent_bits_fade_out_as_the_env_does():
    """After a copy's last sync its recent bits decay by 0.9 per step until they fall below 1e-6·n and are zeroed
    (about 130 quiet steps after a full map): the world's copies follow the env objects step by step, through the
    zeroing, while the other copies keep syncing."""
    make = lambda: mrcomm_env.make("MapSync-v0", appear_rate=0.01, vanish_rate=0.05, max_cycles=400)  # noqa: E731
    world, in_turn = BatchedEnv(make, 3), BatchedEnv(make, 3, copy_axis=False)
    for batch in (world, in_turn):
        batch.reset(seed=4)
    rng = np.random.default_rng(5)
    zeroed_at = None
    for step in range(300):
        actions = np.zeros((3, 2), dtype=np.int64)
        actions[0, 0] = 3 if step in (0, 150) else 0  # copy 0: a full sync, then quiet; copy 1 syncs at random
        actions[1] = rng.integers(0, 5, size=2)
        a, b = world.step(actions), in_turn.step(actions)
        assert as_bytes(a.observations) == as_bytes(b.observations) and as_bytes(a.rewards) == as_bytes(b.rewards), step
        if zeroed_at is None and step > 0 and in_turn.envs[0].recent_bits.max() == 0.0:
            zeroed_at = step
    assert zeroed_at is not None and 100 < zeroed_at < 150  # the fade-out ran its course before the second sync


def test_a_mapsync_world_takes_in_state_changed_from_outside():
    """The env objects are the copies' state between steps: an env changed from outside (the training VecEnv's
    set_attr or env_method) and taken back with ``reload_copies`` steps on as the single env changed alike."""
    kwargs = {"appear_rate": 0.01, "vanish_rate": 0.05, "max_cycles": 40}
    batch = mrcomm_env.make_batched("MapSync-v0", 2, **kwargs)
    single = mrcomm_env.make("MapSync-v0", **kwargs)
    batch.reset(seed=7)
    single.reset(seed=8)  # copy 1
    rng = np.random.default_rng(2)
    for step in range(30):
        if step == 10:
            batch.sync_copies()
            for env in (batch.envs[1], single):  # a robot forgets its map
                env.maps[0] = False
                env.stamps[0] = -1
                env.known[0] = 0
                env._dirty = True
            batch.reload_copies()
        actions = rng.integers(0, 5, size=(2, 2))
        out = batch.step(actions)
        obs, rewards, *_ = single.step(dict(zip(single.agents, actions[1].tolist())))
        assert as_bytes(out.observations[1]) == as_bytes(np.stack(list(obs.values())))
        assert out.rewards[1].tolist() == list(rewards.values())
