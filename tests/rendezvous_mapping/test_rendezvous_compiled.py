"""RendezvousMapping-v0 (paper 004): the compiled partition pass, utility, spanning forest, observation, window and
fusion against their numpy/scipy references, down to whole episodes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.numerics import bit_identical
from helpers.rendezvous import make_packet, random_spd
from helpers.rendezvous_reference import (
    ReferenceRendezvous,
    ReferenceTeamMaps,
    adjacency,
    reference_add_entries,
    reference_candidate_lists,
    reference_mean_of,
    reference_observation,
    reference_packets,
    reference_recommend,
    reference_window,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment

from mrcomm_env.rendezvous import filters, plan_numba, protocol, world
from mrcomm_env.rendezvous.env import RendezvousMappingEnv

# ------------------------------------------------------------------------------------------------ compiled plan
COMPILED_PLAN = (protocol.recommend, protocol.utility_matrix, world.spanning_forest)
REFERENCE_PLAN = (reference_recommend, protocol.broadcast_utility, world.dijkstra_forest)


def _use_plan_backend(monkeypatch, compiled: bool) -> None:
    """The package's compiled recommendation, utility and spanning forest, or their numpy/scipy references
    (``reference_recommend``, ``protocol.broadcast_utility`` on any shapes, scipy's Dijkstra forest), wherever
    ``protocol`` and ``world`` are called through (the env, the baselines)."""
    recommend, utility, forest = COMPILED_PLAN if compiled else REFERENCE_PLAN
    monkeypatch.setattr(protocol, "recommend", recommend)
    monkeypatch.setattr(protocol, "utility_matrix", utility)
    monkeypatch.setattr(world, "spanning_forest", forest)


def _tied_layout(rng, L: int) -> np.ndarray:
    """Landmark estimates with the ties the pass must settle as the reference does: an exact grid (equal
    separations: complete clusters, regular graphs whose Perron vector ties every member, equidistant outliers)
    or a random field."""
    if rng.random() < 0.5:
        side = math.ceil(math.sqrt(L))
        grid = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:L]
        return grid * float(rng.choice([5.0, 10.0]))
    return rng.uniform(0, 100, size=(L, 2))


def _random_plan(rng, min_vehicles: int, max_landmarks: int, tie_probability: float, exhausted_share: float):
    """``(U, landmark estimates, d_comms)`` of a random plan: 1–12 vehicles, tied layouts, and with probability
    ``tie_probability`` a share of exhausted landmarks, worth exactly 0 (ties in U: a row's n best tie at 0)."""
    n = int(rng.integers(min_vehicles, 13))
    L = int(rng.integers(n, max_landmarks))
    lm = _tied_layout(rng, L)
    U = rng.random((n, L))
    if rng.random() < tie_probability:
        U[:, rng.random(L) < exhausted_share] = 0.0
    return U, lm, float(rng.choice([0.0, 5.0, 10.0, 10.5, 15.0, 30.0, math.inf]))


def test_compiled_partition_pass_plans_what_the_reference_plans(monkeypatch):
    rng = np.random.default_rng(11)
    passes = ties = eigenvectors = 0
    for _ in range(400):
        U, lm, d = _random_plan(rng, min_vehicles=1, max_landmarks=90, tie_probability=0.4, exhausted_share=0.7)
        plans = []
        for compiled in (False, True):
            _use_plan_backend(monkeypatch, compiled)
            plans.append(protocol.recommend(U, lm, d, record=True))
        want, got = plans
        assert np.array_equal(want.assignment, got.assignment) and np.array_equal(want.in_main, got.in_main)
        assert (want.central, want.connected) == (got.central, got.connected)
        assert len(want.steps) == len(got.steps)
        for a, b in zip(want.steps, got.steps):
            assert np.array_equal(a.working, b.working) and np.array_equal(a.cluster_of, b.cluster_of)
            assert (a.main, a.central, a.outlier) == (b.main, b.central, b.outlier)
            passes += 1
            main = a.assignment[a.cluster_of == a.main]
            ties += len(main) > 1
            eigenvectors += not adjacency(lm[main], d).all()  # l_c from the Perron vector, not a tie
    # many passes, many main clusters that needed l_c settled, and many whose eigenvector settled it
    assert passes > 1000 and ties > 100 and eigenvectors > 100


def test_compiled_munkres_is_scipys_linear_sum_assignment_including_its_ties():
    from mrcomm_env.rendezvous import plan_numba

    rng = np.random.default_rng(3)
    for trial in range(3000):
        rows = int(rng.integers(1, 13))
        cost = rng.random((rows, int(rng.integers(rows, 40))))
        if trial % 3 == 1:  # few distinct values: many optimal matchings, settled by scipy's tie rules
            cost = np.floor(cost * 3.0)
        elif trial % 3 == 2:  # exhausted landmarks: whole columns worth exactly 0
            cost[:, rng.random(cost.shape[1]) < 0.6] = 0.0
        matched_rows, matched_columns = linear_sum_assignment(cost, maximize=True)
        assert np.array_equal(matched_rows, np.arange(rows))
        assert np.array_equal(plan_numba.lsap_max(cost), matched_columns)


def test_compiled_eq8_sign_is_numpys_or_says_rounding_could_change_it():
    from mrcomm_env.rendezvous import plan_numba

    rng = np.random.default_rng(8)
    answered = unsure = 0
    for trial in range(20000):
        axis = rng.uniform(-50.0, 50.0, size=2)
        offset = rng.uniform(-50.0, 50.0, size=2)
        if trial % 2:  # nearly perpendicular: x·y within rounding of 0
            offset = np.array([-axis[1], axis[0]]) * rng.uniform(0.1, 3.0) + rng.normal(0.0, 1e-14, size=2)
        sign = plan_numba._sign_of_dot(offset[0], offset[1], axis[0], axis[1])
        if sign == 2:
            unsure += 1
            continue
        answered += 1
        assert sign == int(np.sign(offset[None, :] @ axis)[0]), (offset, axis)
    assert answered > 10000 and unsure > 1000


def test_compiled_spanning_forest_is_scipys_dijkstra_forest_or_says_it_is_ambiguous():
    from mrcomm_env.rendezvous import forest_numba

    rng = np.random.default_rng(5)
    exact = ambiguous = deep = 0
    for trial in range(3000):
        n = int(rng.integers(2, 31))
        if trial % 3 == 0:  # a random team
            pos = rng.uniform(0.0, 60.0, size=(n, 2))
        elif trial % 3 == 1:  # vehicles on an exact grid: many shortest paths of equal length
            pos = rng.integers(0, 5, size=(n, 2)) * 10.0
        else:  # half the team co-located (a rendezvous), the rest at random
            pos = rng.uniform(0.0, 60.0, size=(n, 2))
            pos[rng.random(n) < 0.5] = pos[0]
        links = world.vehicle_links(pos, float(rng.choice([0.0, 10.0, 15.0, 20.0, 30.0, math.inf])))
        labels, parent = world.dijkstra_forest(pos, links)  # scipy's Dijkstra
        got_labels, got_parent, tied = forest_numba.spanning_forest(pos, links, world.LINK_LENGTH_FLOOR)
        assert bit_identical(world.spanning_forest(pos, links), (labels, parent))  # the dispatch, either branch
        if tied:
            ambiguous += 1
            continue
        exact += 1
        assert bit_identical((got_labels, got_parent), (labels, parent))
        # a tree that is not a star: Dijkstra chose among longer paths, not only the root's links
        deep += bool(((parent >= 0) & (parent[np.maximum(parent, 0)] >= 0)).any())
    # both branches taken many times, and many of the exact trees were more than one hop deep
    assert exact > 1000 and ambiguous > 100 and deep > 500


def test_compiled_recommendation_loop_plans_what_the_reference_plans_from_any_pass(monkeypatch):
    """The whole loop compiled (its own candidate columns, ties to the lowest column) gives the reference's plan,
    and so does resuming it from the working set of any of the reference's passes."""
    from mrcomm_env.rendezvous import plan_numba

    def compiled_from(U, lm, d, working):
        nonlocal chose_columns, tied_columns
        if len(working) > U.shape[0] ** 2:  # a pre-selection of the columns Munkres sees
            chose_columns += 1
            nth = np.sort(U[:, working], axis=1)[:, -U.shape[0]]  # each row's n-th best
            tied_columns += int(((U[:, working] == nth[:, None]).sum(axis=1) > 1).any())
        status, working, assignment, in_main, central, connected = plan_numba.recommend_loop(U, lm, d, working)
        statuses[status] += 1
        return (assignment, in_main, central, connected) if status == plan_numba.PLANNED else None

    rng = np.random.default_rng(13)
    chose_columns = tied_columns = 0
    statuses = {plan_numba.PLANNED: 0, plan_numba.AMBIGUOUS: 0}
    resumed = 0
    for _ in range(300):  # more landmarks than a row's n best: the loop's own pre-selection, on ties too
        U, lm, d = _random_plan(rng, min_vehicles=2, max_landmarks=200, tie_probability=0.5, exhausted_share=0.8)
        _use_plan_backend(monkeypatch, False)
        want = protocol.recommend(U, lm, d, record=True)
        _use_plan_backend(monkeypatch, True)
        got = protocol.recommend(U, lm, d)
        expected = (want.assignment, want.in_main, want.central, want.connected)
        assert bit_identical(got.assignment, want.assignment) and bit_identical(got.in_main, want.in_main)
        assert (type(got.central), got.central, got.connected) == (int, want.central, want.connected)
        for step in want.steps:
            plan = compiled_from(U, lm, d, step.working)
            if plan is not None:
                resumed += 1
                assert all(bit_identical(a, b) for a, b in zip(plan, expected, strict=True))
    # plans finished in the loop, and many whose pass had more columns than Munkres needs, with a row's n-th best
    # tied among them
    assert resumed > 500 and statuses[plan_numba.PLANNED] > 500
    assert chose_columns > 100 and tied_columns > 100


def test_candidate_columns_break_ties_to_the_lowest_column():
    """A row's n best among tied utilities are its lowest columns, on both backends; NaN ranks after every number.
    Worked by hand: n = 2 rows over 6 working columns (more than n² = 4, so the union is taken)."""
    U = np.array(
        [
            [0.0, 0.5, 0.0, 0.5, 0.5, 0.0],  # three tied at the best: columns 1 and 3
            [np.nan, 0.0, 0.0, 0.0, 0.0, 0.2],  # 0.2 at column 5, then the first tied 0 (column 1); NaN last
        ]
    )
    working = np.arange(6)
    want = np.array([1, 3, 5])  # the sorted union of {1, 3} and {5, 1}
    assert np.array_equal(protocol.candidate_columns(U, working), want)
    assert np.array_equal(protocol.best_positions(-U, working), [[1, 3], [5, 1]])
    assert np.array_equal(plan_numba._candidate_columns(U, working, 2), want)
    # working columns in another order: ties go to the first positions in it (row 0: columns 4 and 3 before 1)
    working = np.array([5, 4, 3, 2, 1])
    assert np.array_equal(protocol.best_positions(-U, working), [[1, 2], [0, 1]])
    assert np.array_equal(protocol.candidate_columns(U, working), [5, 4, 3])


def test_recommend_resumes_the_reference_passes_where_the_compiled_loop_hands_over(monkeypatch):
    """The compiled loop stops when an eq. (8) sign could round either way (rare in random plans, so forced here):
    ``protocol.recommend`` then runs its passes one call each from the working set it stopped at, and plans what the
    reference plans."""
    from mrcomm_env.rendezvous import plan_numba

    rng = np.random.default_rng(17)
    resumed = 0
    for _ in range(200):
        U, lm, d = _random_plan(rng, min_vehicles=2, max_landmarks=120, tie_probability=0.5, exhausted_share=0.8)
        _use_plan_backend(monkeypatch, False)
        want = protocol.recommend(U, lm, d, record=True)
        if len(want.steps) < 2:
            continue
        stop_at = want.steps[int(rng.integers(1, len(want.steps)))].working
        handed_over = []

        def hand_over(U, landmark_pos, d_comms, working, stop_at=stop_at, handed_over=handed_over):
            handed_over.append(True)
            return plan_numba.AMBIGUOUS, stop_at.copy(), np.full(len(U), -1), np.zeros(len(U), bool), -1, False

        monkeypatch.setattr(plan_numba, "recommend_loop", hand_over)
        _use_plan_backend(monkeypatch, True)
        got = protocol.recommend(U, lm, d)
        monkeypatch.undo()
        assert handed_over
        assert bit_identical(got.assignment, want.assignment) and bit_identical(got.in_main, want.in_main)
        assert (got.central, got.connected) == (want.central, want.connected)
        resumed += 1
    assert resumed > 50


@pytest.mark.parametrize(
    "kwargs",
    [
        {},  # the default
        {"n_vehicles": 1, "n_landmarks": 3},  # nobody else to list, more candidate slots than landmarks
        {"n_vehicles": 3, "k_candidates": 8, "d_comms": 0.0},  # more slots than other vehicles; split at once
        {"n_vehicles": 12, "k_candidates": 1, "sigma": 0.0, "d_comms": 15.0},  # an exact grid: tied distances
        {"speed": 0.01, "t_window": 2.0, "area": 1e6},  # nothing within reach: every candidate far away
    ],
)
def test_compiled_observation_is_the_reference_at_every_step(monkeypatch, kwargs):
    """The same state observed by both backends, byte for byte, over whole episodes of random actions."""
    env = RendezvousMappingEnv(max_cycles=30, **kwargs)
    env.reset(seed=8)
    rng = np.random.default_rng(3)
    observed = 0
    while True:
        both = []
        for compiled in (False, True):
            _use_plan_backend(monkeypatch, compiled)
            both.append(env._observe() if compiled else reference_observation(env))
        reference, twin = both
        assert twin.dtype == reference.dtype == np.float32 and twin.shape == reference.shape
        assert twin.tobytes() == reference.tobytes(), np.argwhere(twin != reference)[:5]
        observed += 1
        if not env.agents:
            break
        env.step({a: int(rng.integers(env.K + 2)) for a in env.agents})
    assert observed > 5


@pytest.mark.parametrize(
    "kwargs",
    [
        {},  # the default
        # crowded: a dozen vehicles on a dozen landmarks reach the floor within a window, on tied instants
        {"n_vehicles": 12, "n_landmarks": 12, "area": 400.0, "obs_rate": 4.0, "obs_per_landmark": 7},
        {"speed": 0.3},  # most targets out of reach (d_max = 4.5 m): travel towards them
        {"sigma": 0.0, "d_comms": 15.0, "n_vehicles": 8},  # an exact grid: tied distances and detours
        # a high floor at a high rate: hundreds of kept observations in a window
        {"obs_per_landmark": 1000, "obs_rate": 50.0, "n_landmarks": 20, "n_vehicles": 6, "area": 900.0},
    ],
)
def test_compiled_window_is_the_reference_at_every_step(monkeypatch, kwargs):
    """The same window by both backends: positions, landmarks stayed at, action kinds and feasibility, and the
    kept observations in order (random actions, infeasible ones included)."""
    from mrcomm_env.rendezvous import env as env_module
    from mrcomm_env.rendezvous import window_numba

    assert (window_numba.GO, window_numba.DETOUR_RENDEZVOUS, window_numba.RENDEZVOUS, window_numba.HOLD) == (
        env_module.GO,
        env_module.DETOUR_RENDEZVOUS,
        env_module.RENDEZVOUS,
        env_module.HOLD,
    )
    env = RendezvousMappingEnv(max_cycles=25, **kwargs)
    env.reset(seed=5)
    rng = np.random.default_rng(2)
    kinds, kept = set(), 0
    while env.agents:
        actions = [int(rng.integers(env.K + 2)) for _ in env.agents]
        kind_before, ok_before = env.action_kind.copy(), env.action_ok.copy()
        want = reference_window(env, actions)
        want_kind, want_ok = env.action_kind.copy(), env.action_ok.copy()
        env.action_kind[:], env.action_ok[:] = kind_before, ok_before
        got = window_numba.window(
            np.asarray(actions, dtype=np.int64), env.mask, env.candidates, env.assignment, env.central,
            env.rendezvous_point, env.at_landmark, env.pos, env._estimates, env.ticks, env.cfg.t_window,
            env.cfg.speed, env.world_count, env.cfg.obs_per_landmark, env.action_kind, env.action_ok,
        )  # fmt: skip
        for a, b in zip(want, got, strict=True):
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
        assert np.array_equal(env.action_kind, want_kind) and np.array_equal(env.action_ok, want_ok)
        kinds.update(want_kind.tolist())
        kept += len(want[2])
        env.step(dict(zip(env.agents, actions)))
    assert kept > 0 and len(kinds) >= 3


def test_compiled_fusion_adds_packets_and_takes_means_as_numpy_does():
    """Entries with repeated landmarks (np.add.at's order matters), added into one map by the kernel and by numpy's
    ``np.add.at``, and the means of the maps: bit for bit."""
    rng = np.random.default_rng(4)
    L = 12
    for trial in range(300):
        m = int(rng.integers(1, 20))
        landmarks = rng.integers(0, L if trial % 2 else 3, m).astype(np.int32)
        dcount = rng.integers(1, 4, m).astype(np.int32)
        R_inv = random_spd(rng, 10.0 ** rng.integers(-4, 5)) if trial % 3 else np.eye(2) * rng.uniform(0.1, 1e4)
        dy = rng.normal(0.0, 10.0 ** rng.integers(-3, 6), (m, 2))
        start = (np.eye(2) * rng.uniform(1e-4, 1e6, (L, 1, 1)), rng.normal(0.0, 100.0, (L, 2)))
        maps = []
        for add, mean in ((reference_add_entries, reference_mean_of), (filters._add_entries, filters.mean_of)):
            Y, y, count = start[0].copy(), start[1].copy(), np.zeros(L, dtype=np.int64)
            add(Y, y, count, landmarks, dy, dcount, R_inv)
            maps.append((Y, y, count, mean(Y[None], y[None])))
        for want, got in zip(*maps):
            assert want.dtype == got.dtype and want.tobytes() == got.tobytes()


def test_compiled_group_fusion_is_the_references():
    """Groups fused over random trees in random meeting sequences, with packets piling up past the cumulative table's
    first size: the bits each tree edge carries both ways (``fusion_numba.edge_bits``) and every member's map and
    version vector after the exchange, the same bytes as the numpy oracles' (``ReferenceTeamMaps``)."""
    rng = np.random.default_rng(17)
    L, edges, silent = 9, 0, 0
    for _ in range(20):
        n = int(rng.integers(2, 9))
        R_inv = random_spd(rng)
        both = [
            maps_class(n, np.broadcast_to(np.eye(2), (L, 2, 2)).copy(), np.zeros((L, 2)), R_inv)
            for maps_class in (ReferenceTeamMaps, filters.TeamMaps)
        ]
        for _ in range(int(rng.integers(5, 40))):
            for v in range(n):
                if rng.random() < 0.7:
                    packet = make_packet(rng, L)
                    for maps in both:
                        maps.add_own(v, packet)
            pos = rng.uniform(0, 30, size=(n, 2))
            labels, parent = world.spanning_forest(pos, world.vehicle_links(pos, float(rng.uniform(0, 30))))
            for g in range(labels.max() + 1):
                members = np.flatnonzero(labels == g)
                sent = [maps.fuse_group(members, parent) for maps in both]
                assert sent[0] == sent[1] and list(sent[0]) == list(sent[1])
                assert all(type(bits) is int for bits in sent[1].values())
                edges += len(sent[0])
                silent += sum(bits == 0 for bits in sent[0].values())
                for name in ("known", "Y", "y", "count"):
                    assert getattr(both[0], name).tobytes() == getattr(both[1], name).tobytes(), name
    assert edges > 300 and 0 < silent < edges


def test_compiled_candidate_ranking_is_numpys_bit_for_bit():
    """``candidate_lists`` and its numpy oracle: the same bytes, with tied and zero utilities, recommendations worth
    something or nothing or absent, NaN, and K below, at and above L."""
    from mrcomm_env.rendezvous.env import candidate_lists

    rng = np.random.default_rng(12)
    ties = nans = 0
    for trial in range(400):
        n, L, K = int(rng.integers(1, 11)), int(rng.integers(1, 40)), int(rng.integers(1, 12))
        utility = np.round(rng.random((n, L)), int(rng.integers(0, 3)))  # rounded: many exact ties
        utility[:, rng.random(L) < 0.3] = 0.0  # believed exhausted
        if trial % 7 == 0:
            utility[rng.random((n, L)) < 0.05] = np.nan
        assignment = rng.integers(-1, L, n)
        got = [ranking(utility, assignment, K) for ranking in (reference_candidate_lists, candidate_lists)]
        for want, have in zip(*got):
            assert want.dtype == have.dtype and want.tobytes() == have.tobytes()
        ties += int(sum(len(np.unique(row)) < L for row in utility))
        nans += int(np.isnan(utility).any())
    assert ties > 200 and nans > 20
    for ranking in (reference_candidate_lists, candidate_lists):  # a recommendation that is no landmark: IndexError
        with pytest.raises(IndexError):
            ranking(np.ones((2, 5)), np.array([0, 5]), 3)


def test_compiled_utility_is_numpys_bit_for_bit(monkeypatch):
    """Eq. (1)–(4) of one map per vehicle on both backends: the same bytes, with landmarks out of reach (ε), exhausted
    or over-observed (worth 0), exactly at the window's edge, at distance 0, and under a nearly singular Y."""
    rng = np.random.default_rng(9)
    edges = reaches = exhausted = 0
    for trial in range(200):
        n, L = int(rng.integers(1, 11)), int(rng.integers(1, 60))
        speed, t_window, info, rate = (float(x) for x in rng.uniform(0.2, 3.0, 4))
        budget = int(rng.integers(1, 12))
        vehicles = rng.uniform(0, 40, (n, 2))
        landmarks = rng.uniform(0, 40, (n, L, 2))
        landmarks[:, : L // 4] = vehicles[:, None, :]  # distance 0
        if trial % 3 == 0:  # a landmark exactly one window's travel away: t_obs = 0 takes ε
            landmarks[:, -1] = vehicles + np.array([speed * t_window, 0.0])
        scale = 10.0 ** rng.integers(-6, 7, (n, L, 1, 1))
        Y = np.array([random_spd(rng, 0.1) for _ in range(n * L)]).reshape(n, L, 2, 2) * scale
        Y[:, 0, 0, 1] = Y[:, 0, 1, 0] = np.sqrt(Y[:, 0, 0, 0] * Y[:, 0, 1, 1]) * (1 - 1e-12)  # |Y| ≈ 0
        count = rng.integers(0, budget + 3, (n, L))
        got = []
        for compiled in (False, True):
            _use_plan_backend(monkeypatch, compiled)
            args = (Y, count, vehicles, landmarks, speed, t_window, info, rate, budget)
            got.append(protocol.utility_matrix(*args))
        assert got[0].dtype == got[1].dtype and got[0].tobytes() == got[1].tobytes()
        travel = np.linalg.norm(vehicles[:, None, :] - landmarks, axis=-1) / speed
        edges += int((t_window - travel == 0.0).sum())
        reaches += int((travel < t_window).sum())
        exhausted += int((count >= budget).sum())
    assert edges > 10 and reaches > 1000 and exhausted > 1000
    # shapes numpy broadcasts (one estimate shared by every vehicle) are numpy's on both backends
    shared = []
    for compiled in (False, True):
        _use_plan_backend(monkeypatch, compiled)
        shared.append(protocol.utility_matrix(Y, count, vehicles, landmarks[:1], speed, t_window, info, rate, budget))
    assert shared[0].shape == (n, L) and shared[0].tobytes() == shared[1].tobytes()


@pytest.mark.parametrize("add", [reference_add_entries, filters._add_entries], ids=["numpy", "compiled"])
def test_a_packet_outside_the_map_raises_and_adds_nothing(add):
    Y, y, count = np.ones((4, 2, 2)), np.ones((4, 2)), np.zeros(4, dtype=np.int64)
    with pytest.raises(IndexError):
        add(Y, y, count, np.array([1, 4], np.int32), np.ones((2, 2)), np.ones(2, np.int32), np.eye(2))
    assert (Y == 1).all() and (y == 1).all() and (count == 0).all()


def test_compiled_packets_of_a_window_are_the_references(monkeypatch):
    """Random kept observations (repeated pairs, vehicles out of order, a vehicle with none) become the same
    packets, maps and counts on both backends, to the last bit."""
    import copy

    rng = np.random.default_rng(11)
    env = RendezvousMappingEnv(n_vehicles=7, n_landmarks=30, obs_per_landmark=50)
    env.reset(seed=1)
    for trial in range(200):
        m = int(rng.integers(1, 40))
        v = rng.integers(0, 6, m)  # vehicle 6 never observes
        lm = rng.integers(0, 30 if trial % 2 else 3, m)  # half the trials: three landmarks, many repeats
        runs = []
        for compiled in (False, True):
            _use_plan_backend(monkeypatch, compiled)
            twin = copy.deepcopy(env)
            if not compiled:  # the numpy grouping of the packets (an instance attribute: this twin only)
                twin._packets = lambda v, lm, w, twin=twin: reference_packets(v, lm, w, 30, twin.n_agents)
            twin._apply_observations(v, lm)
            runs.append(twin)
        want, got = runs
        for name in ("Y", "y", "count", "known"):
            assert getattr(want.maps, name).tobytes() == getattr(got.maps, name).tobytes(), name
        assert np.array_equal(want.step_obs, got.step_obs) and np.array_equal(want.world_count, got.world_count)
        for ours, theirs in zip(want.maps.logs, got.maps.logs, strict=True):
            assert (ours.first, ours.kept) == (theirs.first, theirs.kept)
            assert ours.cum_bits[: ours.kept + 1].tobytes() == theirs.cum_bits[: theirs.kept + 1].tobytes()
            for a, b in zip(ours.packets(), theirs.packets(), strict=True):
                for field in ("landmarks", "dy", "count"):
                    x, y = getattr(a, field), getattr(b, field)
                    assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), field
        env = got  # go on from there: packets accumulate
    assert sum(log.made for log in env.maps.logs) > 200


@pytest.mark.parametrize(
    "kwargs",
    [
        {"d_comms": 10.0},  # the default: the team splits and regroups
        {"d_comms": math.inf, "n_vehicles": 6},  # one complete plan per phase
        {"d_comms": 0.0, "n_vehicles": 5},  # co-located only
        {"d_comms": 15.0, "sigma": 0.0, "n_vehicles": 12},  # an exact grid: ties everywhere
        {"d_comms": 20.0, "clumping": 0.9, "n_vehicles": 8},
    ],
)
@pytest.mark.parametrize("policy", ["paper_protocol", "random"])
def test_whole_episodes_are_identical_with_the_compiled_plan_and_forest(monkeypatch, kwargs, policy):
    _assert_backends_agree(monkeypatch, {"n_landmarks": 80, "area": 3600.0, "max_cycles": 25, **kwargs}, policy, 29)


@st.composite
def _drawn_configs(draw):
    """RendezvousMapping arguments across what the compiled plan, forest, window and fusion branch on: one vehicle
    to a crowd, few landmarks to many, no links to all, exact grids (ties) and clumps, a sensor floor of one."""
    n = draw(st.integers(1, 9))
    return {
        "n_vehicles": n,
        "n_landmarks": draw(st.integers(n, 70)),
        "area": draw(st.sampled_from([400.0, 3600.0, 20_000.0])),
        "speed": draw(st.sampled_from([0.2, 1.0, 3.0])),
        "t_window": draw(st.sampled_from([1.0, 10.0, 40.0])),
        "d_comms": draw(st.sampled_from([0.0, 5.0, 15.0, 40.0, math.inf])),
        "sigma": draw(st.sampled_from([0.0, 5.0, 30.0])),
        "clumping": draw(st.sampled_from([0.0, 0.5, 0.9])),
        "k_candidates": draw(st.integers(1, 8)),
        "obs_per_landmark": draw(st.sampled_from([1, 3, 20])),
        "obs_rate": draw(st.sampled_from([0.2, 1.0, 4.0])),
        "max_cycles": draw(st.integers(1, 10)),
    }


@settings(max_examples=25, deadline=None)
@given(kwargs=_drawn_configs(), policy=st.sampled_from(["paper_protocol", "random"]), seed=st.integers(0, 2**16))
def test_whole_episodes_of_drawn_configurations_are_identical_with_the_compiled_plan_and_forest(kwargs, policy, seed):
    """The fixed cases above, and drawn ones (25 per run, the same ones in ``make test``)."""
    with pytest.MonkeyPatch.context() as monkeypatch:
        _assert_backends_agree(monkeypatch, kwargs, policy, seed)


def _assert_backends_agree(monkeypatch, kwargs, policy, seed):
    """One seeded episode under the baseline ``policy`` on each backend: every observation, reward and info, the
    plans (assignment, l_c), the positions and the metrics, byte for byte."""
    from mrcomm_baselines import make_policy

    def episode(compiled):
        _use_plan_backend(monkeypatch, compiled)
        env = (RendezvousMappingEnv if compiled else ReferenceRendezvous)(**kwargs)
        pol = make_policy("RendezvousMapping-v0", policy)
        views = env.local_views()
        obs, infos = env.reset(seed=seed)
        pol.reset(views, seed)
        trace = [(obs, infos)]
        while env.agents:
            obs, rewards, _, _, infos = env.step(pol.act(obs, views))
            trace.append((obs, rewards, infos, env.assignment.copy(), env.central.copy(), env.pos.copy()))
        return trace, repr(env.metrics())

    reference, compiled = episode(False), episode(True)
    assert len(reference[0]) == len(compiled[0]) > 1
    for want, got in zip(reference[0], compiled[0]):
        assert all(bit_identical(a, b) for a, b in zip(want, got, strict=True))
    assert reference[1] == compiled[1]
