"""ChannelAssociation's copy-axis world (channel_association/copy_axis.py): each copy is the single env seeded s + i,
and the world begins ended episodes without the copies' env objects."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.batches import as_bytes, assert_copies_are_single_envs
from hypothesis import given, settings
from hypothesis import strategies as st

import mrcomm_env
from mrcomm_env.core.batched import BatchedEnv, sample_actions

#: ChannelAssociation scenes that its copy-axis worlds (copy_axis.py) step: every branch of a step (ranges short
#: of the arena where positions must matter). Mobile and
#: stationary, a robot faster than the arena (the unfolded bounce), robots bouncing in one copy while the other
#: copies' robots fly on (a reflection rounds: it must touch only the copies that hit a wall), §5.2's extra edges with
#: missed receptions
#: (per-copy draws), premature drops (drop_time 2: conflicts), a crowded field, one robot alone with the
#: emission cost. The episodes end by truncation, and stationary ones also by termination.
COPY_AXIS_CASES = [
    {"n_robots": 12, "max_cycles": 25},
    {"n_robots": 9, "mobile_fraction": 0.0, "max_cycles": 30},
    {
        "n_robots": 6,
        "mobile_fraction": 0.5,
        "speed": 30.0,
        "wireless_range": 5.0,
        "visual_range": 5.0,
        "max_cycles": 12,
    },
    {
        "n_robots": 16,
        "mobile_fraction": 0.5,
        "speed": 3.0,
        "separation": 2.0,
        "wireless_range": 3.0,
        "visual_range": 3.0,
        "max_cycles": 15,
    },
    {"n_robots": 10, "mobile_fraction": 0.3, "visual_range": 6.0, "miss_probability": 0.2, "max_cycles": 15},
    {"n_robots": 20, "mobile_fraction": 0.3, "separation": 1.5, "drop_time": 2, "max_cycles": 20},
    {"n_robots": 2, "mobile_fraction": 1.0, "separation": 0.01, "speed": 5.0, "emission_cost": 0.3, "max_cycles": 8},
    # §4 neighbourhoods: one observer per copy; episodes that terminate, and missed receptions (per-copy draws)
    {"scene": "neighborhood", "w": 8, "v": 6, "max_cycles": 40},
    {"scene": "neighborhood", "w": 12, "v": 12, "miss_probability": 0.3, "emission_cost": 0.2, "max_cycles": 20},
    # each robot's own reward: the shipped training configuration, moving robots that miss, a neighbourhood
    {"n_robots": 25, "mobile_fraction": 0.0, "reward_mode": "individual", "max_cycles": 40},
    {
        "n_robots": 10,
        "mobile_fraction": 0.3,
        "visual_range": 6.0,
        "miss_probability": 0.2,
        "reward_mode": "individual",
        "emission_cost": 0.3,
        "max_cycles": 15,
    },
    {"scene": "neighborhood", "w": 10, "v": 7, "miss_probability": 0.2, "reward_mode": "individual", "max_cycles": 30},
]


@pytest.mark.parametrize("kwargs", COPY_AXIS_CASES, ids=lambda v: str(v))
def test_a_copy_axis_world_gives_each_copy_the_single_env_episodes(kwargs):
    env_id = "mrcomm/ChannelAssociation-v0"
    batch = mrcomm_env.make_batched(env_id, 4, **kwargs)
    assert batch.world is not None  # these configurations are stepped as one array world
    singles = assert_copies_are_single_envs(batch, env_id, kwargs, horizon=3 * kwargs["max_cycles"] + 2)
    # the copies read through their env objects (sync_copies) hold the single envs' state, to the last bit
    batch.sync_copies()
    for copy, single in zip(batch.envs, singles):
        assert copy.bits_sent() == single.bits_sent() and copy.step_count == single.step_count
        assert copy.agents == single.agents  # the episode goes on, whoever began it (env or world)
        if kwargs.get("scene") == "neighborhood":
            assert as_bytes(copy.vis_robot) == as_bytes(single.vis_robot)
        assert as_bytes(copy.positions) == as_bytes(single.positions)
        assert as_bytes(copy.filter.C) == as_bytes(single.filter.C) and as_bytes(copy.filter.vlabel) == as_bytes(
            single.filter.vlabel
        )
        if single.mobile:
            assert as_bytes(copy.vel) == as_bytes(single.vel)


@st.composite
def _world_scenes(draw):
    """ChannelAssociation arguments its copy-axis worlds take (bit sets: ``miss_tolerance`` 0, at most 64 IDs),
    drawn across the ranges a step branches on: field or neighbourhood, still or moving robots, ranges from a
    fraction of the spacing to the arena, missed receptions, short drop times, both rewards, emission costs."""
    common = {
        "reward_mode": draw(st.sampled_from(["team", "individual"])),
        "emission_cost": draw(st.sampled_from([0.0, 0.25])),
        "miss_probability": draw(st.sampled_from([0.0, 0.0, 0.15, 0.5])),
        "drop_time": draw(st.integers(1, 6)),
        "max_cycles": draw(st.integers(1, 10)),
    }
    if draw(st.booleans()):
        w = draw(st.integers(1, 64))
        return {"scene": "neighborhood", "w": w, "v": draw(st.integers(1, w)), **common}
    wireless = draw(st.floats(0.5, 30.0))
    return {
        "n_robots": draw(st.integers(2, 30)),
        "mobile_fraction": draw(st.sampled_from([0.0, 0.3, 1.0])),
        "speed": draw(st.sampled_from([0.0, 1.4, 40.0])),
        "separation": draw(st.sampled_from([1.0, 3.0])),
        "wireless_range": wireless,
        "visual_range": draw(st.floats(0.25, 1.0)) * wireless,
        **common,
    }


@settings(max_examples=25, deadline=None)
@given(kwargs=_world_scenes())
def test_copy_axis_worlds_of_drawn_scenes_give_each_copy_the_single_env_episodes(kwargs):
    """The fixed cases above, and drawn ones (25 per run, the same ones in ``make test``)."""
    batch = mrcomm_env.make_batched("mrcomm/ChannelAssociation-v0", 3, **kwargs)
    assert batch.world is not None
    horizon = 2 * kwargs["max_cycles"] + 2  # every copy ends twice, by truncation if nothing else
    assert_copies_are_single_envs(batch, "mrcomm/ChannelAssociation-v0", kwargs, horizon, some_terminate=False)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_robots": 25, "mobile_fraction": 0.0, "reward_mode": "individual", "max_cycles": 40},  # as shipped
        {"n_robots": 9, "mobile_fraction": 0.4, "max_cycles": 7},  # moving robots: ends by the time limit only
        {"scene": "neighborhood", "w": 8, "v": 6, "max_cycles": 40},
    ],
    ids=["still field", "moving field", "neighbourhood"],
)
def test_channel_association_worlds_begin_ended_episodes_without_their_env_objects(kwargs, monkeypatch):
    """Episodes end every few steps in these scenes: the world begins the next ones and computes the ended ones'
    metrics itself (``reset_copies``, ``final_metrics``), never asking the copies' env objects. A terminated
    episode's completion time is its length; a truncated one has none (-1)."""
    batch = mrcomm_env.make_batched("mrcomm/ChannelAssociation-v0", 4, **kwargs)
    batch.reset(seed=3)
    asked = []
    for env in batch.envs:
        monkeypatch.setattr(env, "reset_arrays", lambda *args, **kw: asked.append("reset_arrays"))
        monkeypatch.setattr(env, "metrics", lambda: asked.append("metrics"))
    rng = np.random.default_rng(0)
    lengths = np.zeros(4, dtype=int)
    ends = {"terminated": 0, "truncated": 0}
    for _ in range(60):
        out = batch.step(sample_actions(batch.action_space, rng, (4, batch.n_agents)))
        lengths += 1
        assert sorted(out.final_metrics) == sorted(out.reset_infos) == np.flatnonzero(out.ended).tolist()
        for i, metrics in out.final_metrics.items():
            if out.terminated[i]:
                ends["terminated"] += 1
                assert metrics["completion_time"] == lengths[i] and metrics["fraction_matched"] == 1.0
            else:
                ends["truncated"] += 1
                assert metrics["completion_time"] == -1 and lengths[i] == kwargs["max_cycles"]
            lengths[i] = 0
            assert (out.reset_infos[i]["bits_sent"] == 0).all()
    assert asked == []
    if kwargs.get("mobile_fraction", 0.0) > 0:
        assert ends["truncated"] >= 8 and ends["terminated"] == 0
    else:
        assert ends["terminated"] >= 8


def test_the_copy_axis_world_and_the_copies_in_turn_step_alike():
    env_id, kwargs = "mrcomm/ChannelAssociation-v0", {"n_robots": 8, "mobile_fraction": 0.25, "max_cycles": 9}
    make = lambda: mrcomm_env.make(env_id, **kwargs)  # noqa: E731
    world, in_turn = BatchedEnv(make, 3), BatchedEnv(make, 3, copy_axis=False)
    assert world.world is not None and in_turn.world is None
    assert BatchedEnv(make, 1).world is None  # one copy steps its env object
    first = [world.reset(seed=5), in_turn.reset(seed=5)]
    assert as_bytes(first[0][0]) == as_bytes(first[1][0])
    rng = np.random.default_rng(1)
    for _ in range(20):
        actions = sample_actions(world.action_space, rng, (3, world.n_agents))
        a, b = world.step(actions), in_turn.step(actions)
        assert as_bytes(a.observations) == as_bytes(b.observations) and as_bytes(a.rewards) == as_bytes(b.rewards)
        assert a.final_metrics == b.final_metrics
    assert world.metrics() == in_turn.metrics()
    with pytest.raises(ValueError, match="action of robot_1 .*must be an integer in \\[0, 1\\]"):
        world.step(np.array([[0, 2] + [0] * 6] * 3))
    with pytest.raises(ValueError, match="action of robot_1 .*must be an integer"):
        in_turn.step(np.array([[0, 2] + [0] * 6] * 3))  # the env objects refuse it alike
    with pytest.raises(ValueError, match="'actions' must hold integers in \\[0, 1\\]"):
        world.step(np.full((3, 8), 1.0))  # 1.0 is not an action of Discrete(2), as for the env
