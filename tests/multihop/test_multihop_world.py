"""MultiHop's copy-axis world (multihop/copy_axis.py): each copy is the single env seeded s + i in either layout,
the env steps as its world of one copy, and the world refuses what the env refuses."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.batches import as_bytes, assert_copies_are_single_envs
from helpers.multihop_reference import ReferenceMultiHop
from hypothesis import given, settings
from hypothesis import strategies as st

import mrcomm_env
from mrcomm_env.core.batched import BatchedEnv
from mrcomm_env.multihop.env import MultiHopEnv

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
    # each robot rewarded by what its neighbours hold, with its own bits priced; in either layout
    {"grid_side": 4, "slot_size": 3, "max_cycles": 20, "reward_mode": "neighbourhood", "lam": 0.3},
    {"grid_side": 3, "max_cycles": 10, "reward_mode": "neighbourhood", "layout": "absolute"},
    # what each robot heard (its table, its sixth feature): the comparison's training setting, a partial grid, and a
    # field where some robots have no neighbour (the feature is 0 there)
    {"grid_side": 4, "slot_size": 4, "max_cycles": 20, "reward_mode": "neighbourhood", "observe_heard": True},
    {"grid_side": 5, "n_robots": 22, "slot_size": 2, "max_cycles": 15, "observe_heard": True},
    {"scene": "field", "n_robots": 9, "comm_range": 8.0, "arena_size": 60.0, "max_cycles": 12, "observe_heard": True},
    # mask_unheld: the masks in the infos (the world's from its observation, the reference's from the stamps)
    {"grid_side": 4, "slot_size": 4, "max_cycles": 20, "observe_heard": True, "mask_unheld": True},
    {"scene": "field", "n_robots": 9, "comm_range": 8.0, "arena_size": 60.0, "max_cycles": 12, "mask_unheld": True},
    # robots that move (random waypoints): each slot's links where the robots are then, new waypoints drawn from each
    # copy's generator; the documented configuration, the absolute layout, the neighbourhood reward with a bit cost,
    # and robots fast enough in a small arena to reach a waypoint in most slots
    {"scene": "field", "n_robots": 12, "speed": 2.0, "comm_range": 35.0, "max_cycles": 25},
    {"scene": "field", "n_robots": 9, "speed": 5.0, "comm_range": 20.0, "max_cycles": 15, "layout": "absolute"},
    {"scene": "field", "n_robots": 10, "speed": 3.0, "max_cycles": 15, "reward_mode": "neighbourhood", "lam": 0.3},
    {"scene": "field", "n_robots": 8, "speed": 400.0, "arena_size": 10.0, "comm_range": 4.0, "max_cycles": 10},
    {"scene": "field", "n_robots": 9, "speed": 2.0, "max_cycles": 12, "mask_unheld": True, "slot_size": 9},
    # the coverage controller (the paper's flying robots, Fig. 3): each robot flies on what it holds, between slots;
    # the default team, a slow channel (several Euler steps a slot), the absolute layout with each robot's reward
    {"scene": "coverage", "max_cycles": 12},
    {"scene": "coverage", "n_robots": 6, "baud": 300.0, "slot_size": 2, "max_cycles": 6, "lam": 0.4},
    {"scene": "coverage", "n_robots": 7, "max_cycles": 8, "layout": "absolute", "reward_mode": "neighbourhood"},
]


@pytest.mark.parametrize("kwargs", MULTIHOP_COPY_AXIS_CASES, ids=lambda v: str(v))
def test_a_multihop_copy_axis_world_gives_each_copy_the_single_env_episodes(kwargs):
    env_id = "mrcomm/MultiHop-v0"
    batch = mrcomm_env.make_batched(env_id, 3, **kwargs)
    assert batch.world is not None  # every scene
    horizon = 2 * kwargs["max_cycles"] + 3
    singles = assert_copies_are_single_envs(batch, env_id, kwargs, horizon, lambda: ReferenceMultiHop(**kwargs))
    assert singles[0].__dict__.get("_one_copy") is None  # the oracle, not the world of one copy
    batch.sync_copies()
    for copy, single in zip(batch.envs, singles):
        assert copy.step_count == single.step_count and copy.t == single.t and copy.agents == single.agents
        for name in ("stamps", "first_known", "sent_stamp", "last_sent"):
            assert as_bytes(getattr(copy, name)) == as_bytes(getattr(single, name)), name
        if kwargs.get("observe_heard"):
            assert as_bytes(copy.heard) == as_bytes(single.heard)
        assert as_bytes(copy.ages()) == as_bytes(single.ages())
        moving = kwargs.get("speed", 0.0) > 0.0 or kwargs.get("scene") == "coverage"
        if moving:  # where the robots are (and head, in the field), and the positions their estimates carry
            for name in ("pos", "est", "adj") + (("waypoint",) if kwargs.get("scene") == "field" else ()):
                assert as_bytes(getattr(copy, name)) == as_bytes(getattr(single, name)), name
        if kwargs.get("layout", "relative") == "relative":  # the candidates' ranking is the relative layout's
            if not moving:  # a static scene ranks again only when what is held changes
                assert as_bytes(copy._ranked_known) == as_bytes(single._ranked_known)
            assert as_bytes(copy._candidates.astype(np.int64)) == as_bytes(single._candidates.astype(np.int64))
        mine, theirs = copy.metrics(), single.metrics()
        assert mine.keys() == theirs.keys()
        assert all(mine[k] == theirs[k] or (np.isnan(mine[k]) and np.isnan(theirs[k])) for k in mine), (mine, theirs)


@st.composite
def _multihop_world_scenes(draw):
    """MultiHop arguments its copy-axis world takes (a grid, or a field static or moving, either layout, either
    reward, with or without what each robot heard): grids with partial rows, fields with their own links, robots
    from still to fast enough to reach a waypoint in most slots, every slot size from no hop to flooding, bit
    costs."""
    common = {
        "alpha": draw(st.sampled_from([0.25, 1.0, 3.0])),
        "bits_per_estimate": draw(st.sampled_from([8, 192])),
        "baud": draw(st.sampled_from([300.0, 3000.0])),
        "lam": draw(st.sampled_from([0.0, 0.7])),
        "max_cycles": draw(st.integers(1, 6)),
        "layout": draw(st.sampled_from(["relative", "absolute"])),
        "reward_mode": draw(st.sampled_from(["team", "neighbourhood"])),
    }
    if common["layout"] == "relative":
        common["observe_heard"] = draw(st.booleans())
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
        if not kwargs.get("observe_heard"):  # what a robot heard is observed on static links only
            kwargs["speed"] = draw(st.sampled_from([0.0, 0.5, 5.0, 300.0]))
    return {**kwargs, "slot_size": draw(st.integers(1, n))}


@settings(max_examples=25, deadline=None)
@given(kwargs=_multihop_world_scenes())
def test_a_multihop_copy_axis_world_of_drawn_scenes_gives_each_copy_the_reference_episodes(kwargs):
    """The fixed cases above, and drawn ones (25 per run, the same ones in ``make test``)."""
    batch = mrcomm_env.make_batched("mrcomm/MultiHop-v0", 3, **kwargs)
    assert batch.world is not None
    horizon = 2 * kwargs["max_cycles"] + 2
    assert_copies_are_single_envs(batch, "mrcomm/MultiHop-v0", kwargs, horizon, lambda: ReferenceMultiHop(**kwargs))


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
    assert world.__dict__.get("_one_copy") is not None and reference.__dict__.get("_one_copy") is None
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


@pytest.mark.parametrize(
    ("n", "density"),
    [(2, 1.0), (5, 0.3), (20, 0.1), (64, 0.05), (65, 0.05), (130, 0.02), (200, 0.5), (300, 1.0), (300, 0.004)],
)
def test_the_moving_world_buckets_pairs_by_hops_as_scipy_does(n, density):
    """The hop buckets a moving world takes at every frame's end (``frame_numba.hop_buckets``, a breadth-first
    search over 64-bit words) against scipy's shortest paths, bucketed as the env buckets them: chains, islands and
    whole cliques, across the 64-robot word boundary."""
    from scipy.sparse.csgraph import shortest_path

    from mrcomm_env.multihop import frame_numba

    rng = np.random.default_rng(n)
    links = rng.random((3, n, n)) < density
    links |= links.transpose(0, 2, 1)
    links[:, np.arange(n), np.arange(n)] = False
    flat, bounds = np.zeros((3, n * (n - 1)), dtype=np.int32), np.zeros((3, 5), dtype=np.int64)
    frame_numba.hop_buckets(links, flat, bounds)
    eye = np.eye(n, dtype=bool)
    for copy in range(3):
        hops = shortest_path(links[copy], unweighted=True, directed=False)
        masks = [hops == 1, hops == 2, hops == 3, (hops >= 4) & ~eye]
        want = [np.flatnonzero(mask.ravel()) for mask in masks]
        assert bounds[copy].tolist() == np.cumsum([0] + [w.size for w in want]).tolist()
        assert flat[copy, : bounds[copy, -1]].tolist() == np.concatenate(want).tolist()


def test_the_multihop_world_refuses_what_the_env_refuses_and_steps_as_the_copies_in_turn():
    kwargs = {"grid_side": 3, "slot_size": 2, "max_cycles": 6}
    make = lambda: mrcomm_env.make("MultiHop-v0", **kwargs)  # noqa: E731
    world, in_turn = BatchedEnv(make, 2), BatchedEnv(make, 2, copy_axis=False)
    assert world.world is not None and in_turn.world is None
    assert as_bytes(world.reset(seed=2)[0]) == as_bytes(in_turn.reset(seed=2)[0])
    rng = np.random.default_rng(4)
    for _ in range(8):  # float 0s and 1s are MultiBinary actions too (SB3 sends float32)
        actions = rng.integers(0, 2, size=(2, 9, 8)).astype(np.float32)
        a, b = world.step(actions), in_turn.step(actions)
        assert as_bytes(a.observations) == as_bytes(b.observations) and as_bytes(a.rewards) == as_bytes(b.rewards)
    bad = np.zeros((2, 9, 8))
    bad[1, 4, 2] = 0.5
    with pytest.raises(ValueError, match=r"action of robot_4 \(copy 1\) must be an array of 0s and 1s of shape \(8,\)"):
        world.step(bad)
    with pytest.raises(ValueError, match="action of robot_4 must be an array of 0s and 1s"):
        in_turn.step(bad)  # the env objects refuse it alike
    with pytest.raises(ValueError, match="'actions' must hold 0s and 1s"):
        world.step(np.full((2, 9, 8), "1"))


def test_the_absolute_layout_world_ranks_priorities_as_the_protocol_with_ties_and_zeros():
    """``frame_numba.priority_ranks`` against the oracle's ``priority_ranking`` (numpy's stable sort of whole rows) on
    priorities from four levels, so that most rows hold ties and withheld (0) robots, as random floats never do, and
    with robots not yet held: each row it writes is the reference's row as far as a frame reads it (until the
    (m − 1)-th robot held), by scans alone and past ``SCAN_PICKS`` by its sort."""
    from helpers.multihop_reference import priority_ranking

    from mrcomm_env.multihop import frame_numba

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
    assert as_bytes(world.reset(seed=2)[0]) == as_bytes(in_turn.reset(seed=2)[0])
    rng = np.random.default_rng(4)
    for _ in range(8):  # float64 priorities, tied and zero among them: both round them to the Box's float32 first
        actions = rng.choice([0.0, 0.1, 0.3, 1.0 / 3.0, 1.0], size=(2, 9, 9))
        a, b = world.step(actions), in_turn.step(actions)
        assert as_bytes(a.observations) == as_bytes(b.observations) and as_bytes(a.rewards) == as_bytes(b.rewards)
        assert all(as_bytes(a.infos[k]) == as_bytes(b.infos[k]) for k in b.infos)
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
