"""A batch of M copies (``mrcomm_env.make_batched``) is M single envs: copy i of a batch seeded s gives, episode
after episode, byte for byte the observations, rewards, ends, infos, bits and metrics of the PettingZoo env seeded
s + i driven with the same actions (its automatic resets continue the copy's own random stream, as a reset
without a seed does)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mrcomm_env
from mrcomm_env.core.batched import BatchedEnv, sample_actions
from mrcomm_env.multihop.env import MultiHopEnv
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


def _bytes(array) -> bytes:
    return np.ascontiguousarray(array).tobytes()


@pytest.mark.parametrize(("env_id", "kwargs"), [*SMALL.items(), *EXTRA_CASES], ids=lambda v: str(v))
def test_copy_i_of_a_batch_seeded_s_is_the_single_env_seeded_s_plus_i(env_id, kwargs):
    batch = mrcomm_env.make_batched(env_id, 3, **kwargs)
    _assert_copies_are_single_envs(batch, env_id, kwargs, horizon=3 * kwargs["max_cycles"] + 2)


#: ChannelAssociation scenes that its copy-axis worlds (copy_axis.py) step: every branch of a step (ranges short
#: of the arena where positions must matter). Mobile and
#: stationary, a robot faster than the arena (the unfolded bounce), robots bouncing in one copy while the other
#: copies' robots fly on (a reflection rounds: it must touch only the copies that hit a wall), §5.2's extra edges with missed receptions
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
    singles = _assert_copies_are_single_envs(batch, env_id, kwargs, horizon=3 * kwargs["max_cycles"] + 2)
    # the copies read through their env objects (sync_copies) hold the single envs' state, to the last bit
    batch.sync_copies()
    for copy, single in zip(batch.envs, singles):
        assert copy.bits_sent() == single.bits_sent() and copy.step_count == single.step_count
        assert copy.agents == single.agents  # the episode goes on, whoever began it (env or world)
        if kwargs.get("scene") == "neighborhood":
            assert _bytes(copy.vis_robot) == _bytes(single.vis_robot)
        assert _bytes(copy.positions) == _bytes(single.positions)
        assert _bytes(copy.filter.C) == _bytes(single.filter.C) and _bytes(copy.filter.vlabel) == _bytes(
            single.filter.vlabel
        )
        if single.mobile:
            assert _bytes(copy.vel) == _bytes(single.vel)


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
    _assert_copies_are_single_envs(batch, "mrcomm/ChannelAssociation-v0", kwargs, horizon, some_terminate=False)


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
    assert _bytes(first[0][0]) == _bytes(first[1][0])
    rng = np.random.default_rng(1)
    for _ in range(20):
        actions = sample_actions(world.action_space, rng, (3, world.n_agents))
        a, b = world.step(actions), in_turn.step(actions)
        assert _bytes(a.observations) == _bytes(b.observations) and _bytes(a.rewards) == _bytes(b.rewards)
        assert a.final_metrics == b.final_metrics
    assert world.metrics() == in_turn.metrics()
    with pytest.raises(ValueError, match="action of robot_1 .*must be an integer in \\[0, 1\\]"):
        world.step(np.array([[0, 2] + [0] * 6] * 3))
    with pytest.raises(ValueError, match="action of robot_1 .*must be an integer"):
        in_turn.step(np.array([[0, 2] + [0] * 6] * 3))  # the env objects refuse it alike
    with pytest.raises(ValueError, match="'actions' must hold integers in \\[0, 1\\]"):
        world.step(np.full((3, 8), 1.0))  # 1.0 is not an action of Discrete(2), as for the env


#: static MultiHop scenes with the team reward, in either layout: the copy-axis world of multihop/copy_axis.py
MULTIHOP_COPY_AXIS_CASES = [
    {"grid_side": 4, "slot_size": 3, "max_cycles": 20},
    {"grid_side": 5, "n_robots": 22, "slot_size": 2, "lam": 0.5, "max_cycles": 25},  # a partial last row; bit cost
    {"scene": "field", "n_robots": 12, "comm_range": 35.0, "max_cycles": 15},  # each copy its own links and buckets
    # robots out of everyone's range: estimates never known, first arrivals tracked all episode; flooding (m = n)
    {"scene": "field", "n_robots": 9, "comm_range": 8.0, "arena_size": 60.0, "slot_size": 9, "max_cycles": 12},
    {"grid_side": 2, "slot_size": 1, "max_cycles": 5},
    # v0's layout (BenchMARL's MultiHop task): Box priorities per robot index, ties and zeros among random draws
    {"grid_side": 4, "slot_size": 3, "max_cycles": 20, "layout": "absolute"},
    {"scene": "field", "n_robots": 9, "comm_range": 8.0, "arena_size": 60.0, "max_cycles": 12, "layout": "absolute"},
]


class ReferenceMultiHop(MultiHopEnv):
    """MultiHop stepped by its reference code (``_step_world``'s numpy frame end, ranking and observation), not as
    the copy-axis world of one copy, which the single env otherwise runs too."""

    @classmethod
    def copy_axis_world(cls, cfg):
        return None


@pytest.mark.parametrize("kwargs", MULTIHOP_COPY_AXIS_CASES, ids=lambda v: str(v))
def test_a_multihop_copy_axis_world_gives_each_copy_the_single_env_episodes(kwargs):
    env_id = "mrcomm/MultiHop-v0"
    batch = mrcomm_env.make_batched(env_id, 3, **kwargs)
    assert batch.world is not None  # compiled backend (extra "fast"), static scene, team reward
    horizon = 2 * kwargs["max_cycles"] + 3
    singles = _assert_copies_are_single_envs(batch, env_id, kwargs, horizon, lambda: ReferenceMultiHop(**kwargs))
    assert not singles[0]._world_eligible  # the reference, not the world of one copy
    batch.sync_copies()
    for copy, single in zip(batch.envs, singles):
        assert copy.step_count == single.step_count and copy.t == single.t and copy.agents == single.agents
        for name in ("stamps", "first_known", "sent_stamp", "last_sent"):
            assert _bytes(getattr(copy, name)) == _bytes(getattr(single, name)), name
        assert _bytes(copy.ages()) == _bytes(single.ages())
        if kwargs.get("layout", "relative") == "relative":  # the candidates' ranking is the relative layout's
            assert _bytes(copy._ranked_known) == _bytes(single._ranked_known)
            assert _bytes(copy._candidates.astype(np.int64)) == _bytes(single._candidates.astype(np.int64))
        mine, theirs = copy.metrics(), single.metrics()
        assert mine.keys() == theirs.keys()
        assert all(mine[k] == theirs[k] or (np.isnan(mine[k]) and np.isnan(theirs[k])) for k in mine), (mine, theirs)


@st.composite
def _multihop_world_scenes(draw):
    """MultiHop arguments its copy-axis world takes (a static grid or field, either layout, the team reward):
    grids with partial rows, fields with their own links, every slot size from no hop to flooding, bit costs."""
    common = {
        "alpha": draw(st.sampled_from([0.25, 1.0, 3.0])),
        "bits_per_estimate": draw(st.sampled_from([8, 192])),
        "baud": draw(st.sampled_from([300.0, 3000.0])),
        "lam": draw(st.sampled_from([0.0, 0.7])),
        "max_cycles": draw(st.integers(1, 6)),
        "layout": draw(st.sampled_from(["relative", "absolute"])),
    }
    if draw(st.booleans()):
        side = draw(st.integers(2, 6))
        n = draw(st.integers(2, side * side))
        kwargs = {"grid_side": side, "n_robots": n, **common}
    else:
        n = draw(st.integers(2, 25))
        kwargs = {
            "scene": "field",
            "n_robots": n,
            "arena_size": draw(st.sampled_from([10.0, 60.0, 200.0])),
            "comm_range": draw(st.sampled_from([5.0, 35.0, 200.0])),
            **common,
        }
    return {**kwargs, "slot_size": draw(st.integers(1, n))}


@settings(max_examples=25, deadline=None)
@given(kwargs=_multihop_world_scenes())
def test_a_multihop_copy_axis_world_of_drawn_scenes_gives_each_copy_the_reference_episodes(kwargs):
    """The fixed cases above, and drawn ones (25 per run, the same ones in ``make test``)."""
    batch = mrcomm_env.make_batched("mrcomm/MultiHop-v0", 3, **kwargs)
    assert batch.world is not None
    horizon = 2 * kwargs["max_cycles"] + 2
    _assert_copies_are_single_envs(batch, "mrcomm/MultiHop-v0", kwargs, horizon, lambda: ReferenceMultiHop(**kwargs))


def test_a_multihop_env_stepping_as_a_world_of_one_copy_takes_in_state_changed_from_outside():
    """The env's attributes are its state, whichever code steps it: an array replaced between steps and a moved
    clock are stepped on exactly as the reference steps them."""
    kwargs = {"grid_side": 4, "slot_size": 3, "max_cycles": 30}
    world, reference = MultiHopEnv(**kwargs), ReferenceMultiHop(**kwargs)
    agents = world.possible_agents
    trace = []
    for env in (world, reference):
        env.reset(seed=3)
        rng = np.random.default_rng(5)
        steps = []
        for k in range(20):
            if k == 8:  # robot 1 forgets robot 2 (a new array)
                stamps = env.stamps.copy()
                stamps[1, 2] = -np.inf
                env.stamps = stamps
            if k == 12:  # the clock moves on by half a frame (a number, no array replaced)
                env.t += 0.5 * env.frame_dur
            obs, rewards, _, _, infos = env.step({a: rng.integers(0, 2, 15) for a in agents})
            steps.append((np.stack([obs[a] for a in agents]).tobytes(), rewards, infos))
        trace.append((steps, repr(env.metrics()), env.ages().tobytes()))
    assert world._world_eligible and not reference._world_eligible
    assert trace[0] == trace[1]
    assert world.stamps[1, 2] > -np.inf  # robot 1 heard of robot 2 again after forgetting it


def test_the_multihop_world_sums_as_numpy_sums():
    """The world's ages are summed in scratch rows by ``numpy_sum``, which must be numpy's own pairwise sum to the
    last bit (a plain running sum differs from the eighth value on); values of nine orders of magnitude."""
    from mrcomm_env.core.sums_numba import numpy_sum

    rng = np.random.default_rng(7)
    for size in [*range(0, 300), 8191, 8192, 8193, 9900, 65536, 1023 * 1024]:
        values = rng.random(size + 5) * 10.0 ** rng.uniform(-3, 6, size + 5)
        assert numpy_sum(values, 3, size) == values[3 : 3 + size].sum(), size


def test_the_multihop_world_refuses_what_the_env_refuses_and_steps_as_the_copies_in_turn():
    kwargs = {"grid_side": 3, "slot_size": 2, "max_cycles": 6}
    make = lambda: mrcomm_env.make("MultiHop-v0", **kwargs)  # noqa: E731
    world, in_turn = BatchedEnv(make, 2), BatchedEnv(make, 2, copy_axis=False)
    assert world.world is not None and in_turn.world is None
    assert _bytes(world.reset(seed=2)[0]) == _bytes(in_turn.reset(seed=2)[0])
    rng = np.random.default_rng(4)
    for _ in range(8):  # float 0s and 1s are MultiBinary actions too (SB3 sends float32)
        actions = rng.integers(0, 2, size=(2, 9, 8)).astype(np.float32)
        a, b = world.step(actions), in_turn.step(actions)
        assert _bytes(a.observations) == _bytes(b.observations) and _bytes(a.rewards) == _bytes(b.rewards)
    bad = np.zeros((2, 9, 8))
    bad[1, 4, 2] = 0.5
    with pytest.raises(ValueError, match=r"action of robot_4 \(copy 1\) must be an array of 0s and 1s of shape \(8,\)"):
        world.step(bad)
    with pytest.raises(ValueError, match="action of robot_4 must be an array of 0s and 1s"):
        in_turn.step(bad)  # the env objects refuse it alike
    with pytest.raises(ValueError, match="'actions' must hold 0s and 1s"):
        world.step(np.full((2, 9, 8), "1"))


def test_the_absolute_layout_world_ranks_priorities_as_the_protocol_with_ties_and_zeros():
    """``frame_numba.priority_ranks`` against ``protocol.priority_ranking`` (numpy's stable sort of whole rows) on
    priorities from four levels, so that most rows hold ties and withheld (0) robots, as random floats never do, and
    with robots not yet held: each row it writes is the reference's row as far as a frame reads it (until the
    (m − 1)-th robot held), by scans alone and past ``SCAN_PICKS`` by its sort."""
    from mrcomm_env.multihop import frame_numba
    from mrcomm_env.multihop.protocol import priority_ranking

    rng = np.random.default_rng(3)
    sorted_rows = 0
    for n in (2, 3, 9, 40, 100):
        for m in sorted({1, 2, 3, 7, n}):
            priority = rng.choice([0.0, 0.25, 0.5, 1.0], size=(6, n, n))
            stamps = np.where(rng.random((6, n, n)) < rng.choice([0.1, 0.9]), 0.0, -np.inf)
            rank, count = np.zeros((6, n, n), dtype=np.int16), np.zeros((6, n), dtype=np.int64)
            frame_numba.priority_ranks(priority, stamps, m, rank, count)
            for c in range(6):
                expected_rank, expected_count = priority_ranking(priority[c])
                for i in range(n):
                    written = rank[c, i, : count[c, i]]
                    np.testing.assert_array_equal(written, expected_rank[i, : count[c, i]])
                    held = int((stamps[c, i, written[1:]] > -np.inf).sum())
                    assert count[c, i] == expected_count[i] or held == m - 1, (n, m, c, i)
                    sorted_rows += count[c, i] > frame_numba.SCAN_PICKS + 1
    assert sorted_rows > 0, "some rows must go past the scans into the sort"


def test_the_absolute_layout_world_steps_as_the_copies_in_turn_and_refuses_what_the_env_refuses():
    kwargs = {"grid_side": 3, "slot_size": 2, "max_cycles": 6, "layout": "absolute"}
    make = lambda: mrcomm_env.make("MultiHop-v0", **kwargs)  # noqa: E731
    world, in_turn = BatchedEnv(make, 2), BatchedEnv(make, 2, copy_axis=False)
    assert world.world is not None and in_turn.world is None
    assert _bytes(world.reset(seed=2)[0]) == _bytes(in_turn.reset(seed=2)[0])
    rng = np.random.default_rng(4)
    for _ in range(8):  # float64 priorities, tied and zero among them: both round them to the Box's float32 first
        actions = rng.choice([0.0, 0.1, 0.3, 1.0 / 3.0, 1.0], size=(2, 9, 9))
        a, b = world.step(actions), in_turn.step(actions)
        assert _bytes(a.observations) == _bytes(b.observations) and _bytes(a.rewards) == _bytes(b.rewards)
        assert all(_bytes(a.infos[k]) == _bytes(b.infos[k]) for k in b.infos)
    bad = np.zeros((2, 9, 9))
    bad[1, 4, 2] = 1.5
    with pytest.raises(ValueError, match=r"action of robot_4 \(copy 1\) must be finite and within \[0, 1\]"):
        world.step(bad)
    with pytest.raises(ValueError, match=r"action of robot_4 must be finite and within \[0, 1\]"):
        in_turn.step(bad)  # the env objects refuse it alike
    bad[1, 4, 2] = np.nan
    with pytest.raises(ValueError, match=r"robot_4 \(copy 1\) must be finite"):
        world.step(bad)
    with pytest.raises(ValueError, match="must be real arrays of shape"):
        world.step(np.full((2, 9, 9), "1"))


#: MapSync configurations its copy-axis world (mapsync/copy_axis.py) steps: links without a bit budget, always up.
#: The default (OR merge), the shipped training configuration (last-writer-wins), Fig. 7's layout, teams whose
#: robots find their peers busy, Protocol 1 with one round (it says "same" of maps that differ), a crowded 3×3
#: grid with a high bit price, the explicit database. Every protocol runs, as the actions are drawn.
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
            assert _bytes(getattr(copy, name)) == _bytes(getattr(single, name)), name
        assert list(copy.detections) == list(single.detections) and copy._next_session == single._next_session
        assert copy.np_random.bit_generator.state == single.np_random.bit_generator.state
        mine, theirs = copy.metrics(), single.metrics()
        assert mine.keys() == theirs.keys()
        assert all(mine[k] == theirs[k] or (np.isnan(mine[k]) and np.isnan(theirs[k])) for k in mine), (mine, theirs)


@pytest.mark.parametrize("kwargs", MAPSYNC_COPY_AXIS_CASES, ids=lambda v: str(v))
def test_a_mapsync_copy_axis_world_gives_each_copy_the_single_env_episodes(kwargs):
    env_id = "mrcomm/MapSync-v0"
    batch = mrcomm_env.make_batched(env_id, 3, **kwargs)
    assert batch.world is not None  # compiled backend (extra "fast"), no bits_per_step, links always up
    singles = _assert_copies_are_single_envs(batch, env_id, kwargs, 2 * kwargs["max_cycles"] + 3)
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
    singles = _assert_copies_are_single_envs(batch, "mrcomm/MapSync-v0", kwargs, 2 * kwargs["max_cycles"] + 2)
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
        assert _bytes(a.observations) == _bytes(b.observations) and _bytes(a.rewards) == _bytes(b.rewards), step
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
        assert _bytes(out.observations[1]) == _bytes(np.stack(list(obs.values())))
        assert out.rewards[1].tolist() == list(rewards.values())


def test_copy_false_returns_the_batch_buffer_and_the_same_numbers():
    make = lambda: mrcomm_env.make("MultiHop-v0", grid_side=3, slot_size=2, max_cycles=4)  # noqa: E731
    copying, buffered = BatchedEnv(make, 2), BatchedEnv(make, 2, copy=False)
    first = copying.reset(seed=1)[0], buffered.reset(seed=1)[0]
    assert _bytes(first[0]) == _bytes(first[1])
    actions = np.ones((2, 9, 8), dtype=np.int8)
    kept = copying.step(actions).observations
    held = copying.step(actions).observations
    assert not np.shares_memory(kept, held)  # copy=True: every step a new array, which the next step leaves alone
    one, two = buffered.step(actions).observations, buffered.step(actions).observations
    assert np.shares_memory(one, two)  # copy=False: the batch's own buffer, rewritten by the next step
    assert _bytes(two) == _bytes(held)


def _assert_copies_are_single_envs(batch, env_id, kwargs, horizon, make_single=None, some_terminate=True):
    n_copies, seed = batch.n_copies, 11
    make_single = make_single or (lambda: mrcomm_env.make(env_id, **kwargs))
    singles = [make_single() for _ in range(n_copies)]
    observations, infos = batch.reset(seed=seed)
    agents = singles[0].possible_agents
    for i, env in enumerate(singles):
        single_obs, single_infos = env.reset(seed=seed + i)
        assert _bytes(observations[i]) == _bytes(np.stack([single_obs[a] for a in agents]))
        assert {k: v[i].tolist() for k, v in infos.items()} == {
            k: [single_infos[a][k] for a in agents] for k in single_infos[agents[0]]
        }
    rng = np.random.default_rng(0)
    episodes_ended = np.zeros(n_copies, dtype=int)
    copies_terminated = 0
    for _ in range(horizon):
        actions = sample_actions(batch.action_space, rng, (n_copies, batch.n_agents))
        out = batch.step(actions)
        copies_terminated += int(out.terminated.sum())
        for i, env in enumerate(singles):
            obs, rewards, terminations, truncations, step_infos = env.step(dict(zip(agents, actions[i])))
            assert _bytes(out.rewards[i]) == _bytes(np.array([rewards[a] for a in agents]))
            assert (bool(out.terminated[i]), bool(out.truncated[i])) == (
                terminations[agents[0]],
                truncations[agents[0]],
            )
            assert {k: v[i].tolist() for k, v in out.infos.items()} == {
                k: [step_infos[a][k] for a in agents] for k in step_infos[agents[0]]
            }
            final = np.stack([obs[a] for a in agents])
            if env.agents:  # the episode goes on
                assert i not in out.final_observations
                assert _bytes(out.observations[i]) == _bytes(final)
                assert batch.bits_sent()[i] == env.bits_sent()
                continue
            episodes_ended[i] += 1
            assert _bytes(out.final_observations[i]) == _bytes(final)
            assert out.final_metrics[i] == env.metrics()
            next_obs, next_infos = env.reset()  # no seed: the copy's own stream goes on
            assert _bytes(out.observations[i]) == _bytes(np.stack([next_obs[a] for a in agents]))
            assert {k: v.tolist() for k, v in out.reset_infos[i].items()} == {
                k: [next_infos[a][k] for a in agents] for k in next_infos[agents[0]]
            }
            assert batch.bits_sent()[i] == env.bits_sent()  # the new episode's (RendezvousMapping sends at reset)
    assert (episodes_ended >= 2).all(), episodes_ended  # the automatic resets were exercised
    if some_terminate and kwargs.get("scene") == "neighborhood" and not kwargs.get("miss_probability"):
        assert copies_terminated > 0  # a perfect channel tells the IDs apart in a few steps: episodes terminate
    return singles


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
    ("env_id", "n_copies", "backend_name"),
    [("MultiHop-v0", 128, "numpy"), ("MultiHop-v0", 128, "auto"), ("RendezvousMapping-v0", 512, "numpy")],
)
def test_a_batch_holds_about_what_its_memory_estimate_says(env_id, n_copies, backend_name, monkeypatch):
    """``batch_memory_estimate`` counts the shared working memory once and each copy's own state: within a factor
    of 2 of what the batch holds. The largest state per copy (MultiHop) in turn and as a copy-axis world (compiled
    backend, numba counted), and the largest shared part (RendezvousMapping)."""
    from mrcomm_env.core import backend
    from mrcomm_env.experiments.limits import measure_batched

    monkeypatch.setenv("MRCOMM_BACKEND", backend_name)  # the child process that measures chooses by it
    # this process chose its backend once (functools.cache); the estimate here must use the child's choice
    monkeypatch.setattr(backend, "compiled", backend.compiled.__wrapped__)
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
    assert _bytes(batch.observations[1]) == _bytes(np.stack([first[a] for a in agents]))
    for _ in range(3):  # copy 1 is now three steps into its second episode, the others six into their first
        out, single_obs = step_all()
        for i, env in enumerate(singles):
            assert _bytes(out.observations[i]) == _bytes(single_obs[i])
            assert batch.bits_sent()[i] == env.bits_sent()
    frame = batch.render_copy(1)
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[-1] == 3


def test_restart_and_observations_need_a_reset_first():
    batch = BatchedEnv(lambda: mrcomm_env.make("MapSync-v0", max_cycles=4), 2)
    with pytest.raises(RuntimeError, match="reset"):
        batch.restart([0])
    with pytest.raises(RuntimeError, match="reset"):
        _ = batch.observations
