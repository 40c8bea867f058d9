"""MultiHop-v0 (paper 003): protocol core against independent references, env mechanics, baselines."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.multihop_reference import ReferenceMultiHop, deliver_one, priority_ranking, priority_select
from helpers.numerics import assert_close_conditioned, bit_identical, tolerance

from mrcomm_baselines.multihop import POLICIES
from mrcomm_env.multihop import protocol as proto
from mrcomm_env.multihop import theory
from mrcomm_env.multihop.env import MultiHopEnv


def algorithm1_reference(counters, f, known, own, m, rule):
    """Algorithm 1 line by line (§3.2 text: argmin; listing: argmax), plain Python, one robot."""
    n = len(counters)
    c = list(counters)
    M = {j for j in range(n) if known[j] or j == own}
    N = []
    for _ in range(min(m, len(M))):
        fs = {j: (math.inf if j == own else f[j]) for j in M}
        if own in M:
            P = {j: (1.0 if j == own else 0.0) for j in M}
        else:
            tot = sum(fs.values())
            P = {j: fs[j] / tot for j in M}
        for j in M:
            c[j] *= 1.0 - P[j]
        key = (lambda j: (c[j], j)) if rule == "text" else (lambda j: (-c[j], j))
        # own first (§3.1: infinite importance). The text's argmin finds it (c_ii = 0); the listing's argmax
        # would not, so with the listing the own pick is forced, as the env always includes it (§2.2).
        k = own if own in M else min(M, key=key)
        if rule == "text":
            assert k == min(M, key=key)
        M.remove(k)
        N.append(k)
        c[k] = 1.0
    return N, c


@pytest.mark.parametrize("rule", ["text", "listing"])
def test_location_based_select_matches_line_by_line_algorithm1(rule):
    rng = np.random.default_rng(0)
    B, n = 12, 9
    for m in (1, 2, 4, 9):
        counters = rng.uniform(0.2, 1.0, (B, n))
        known = rng.random((B, n)) < 0.7
        own = rng.integers(0, n, B)
        dist = rng.uniform(0.5, 5.0, (B, n))
        f = proto.importance(dist, known, 1.3)
        ref = [algorithm1_reference(counters[b], f[b], known[b], own[b], m, rule) for b in range(B)]
        c = counters.copy()
        order = proto.location_based_select(c, f, known, own, m, rule)
        for b in range(B):
            got = [int(x) for x in order[b] if x >= 0]
            assert set(got) == set(ref[b][0])  # a full slot's order does not matter; the set does
            if len(ref[b][0]) == m and known[b].sum() - known[b, own[b]] > m - 1:
                assert got == ref[b][0]
            # counters are products of ≤ m factors (1 − P), P = f / Σf over ≤ n terms, all in [0, 1]: each factor
            # carries ≤ n + 3 roundings of 1, so two implementations differ by ≤ 2·C·m·(n + 3)·ε (absolute)
            assert_close_conditioned(c[b], ref[b][1], tolerance(1.0, m * (n + 3)), err_msg=f"counters, m={m}")


def test_text_rule_is_round_robin_for_equal_importance():
    # equal importance, one pick per slot: "lowest counter" = longest since selected -> round robin
    n = 6
    counters = np.ones((1, n))
    known = np.ones((1, n), dtype=bool)
    f = np.ones((1, n))
    picks = [
        int(proto.location_based_select(counters, f, known, np.array([0]), 2, "text")[0, 1]) for _ in range(3 * (n - 1))
    ]
    for start in range(0, len(picks), n - 1):
        assert sorted(picks[start : start + n - 1]) == list(range(1, n))


def test_text_rule_sends_closer_estimates_more_often():
    n = 8
    counters = np.ones((1, n))
    known = np.ones((1, n), dtype=bool)
    f = proto.importance(np.arange(n, dtype=float)[None], known, 1.0)
    count = np.zeros(n)
    for _ in range(400):
        order = proto.location_based_select(counters, f, known, np.array([0]), 3, "text")
        count[order[0, 1:]] += 1
    assert np.all(np.diff(count[1:]) <= 0)  # monotone in importance (eq. 1)
    assert count[-1] > 0  # ...but far estimates still disperse (the point of not taking the top-m)


def test_probabilistic_first_pick_follows_eq2():
    rng = np.random.default_rng(1)
    n, draws = 5, 40000
    dist = np.array([[0.0, 1.0, 2.0, 3.0, 4.0]])
    known = np.ones((1, n), dtype=bool)
    f = proto.importance(dist, known, 1.0)
    f_b = np.repeat(f, draws, axis=0)
    order = proto.probabilistic_select(rng, f_b, np.ones((draws, n), dtype=bool), np.zeros(draws, dtype=int), 2)
    assert np.all(order[:, 0] == 0)
    freq = np.bincount(order[:, 1], minlength=n)[1:] / draws
    expect = theory.eq2_probabilities(f[0], np.arange(n) != 0)[1:]
    np.testing.assert_allclose(freq, expect, atol=0.01)


def test_deliver_keeps_newest_stamps():
    stamps = np.array([[[5.0, 1.0, proto.UNKNOWN], [2.0, 3.0, 9.0], [proto.UNKNOWN, proto.UNKNOWN, 4.0]]])
    sel = np.array([[True, True, True]])
    proto.deliver(stamps, np.array([0]), np.array([0]), np.array([[1, 2]]), sel)
    np.testing.assert_array_equal(stamps[0, 1], [5.0, 3.0, 9.0])  # 5 newer than 2; 1 older than 3
    np.testing.assert_array_equal(stamps[0, 2], [5.0, 1.0, 4.0])


def test_frame_time_and_rate_in_real_units():
    env = MultiHopEnv(grid_side=3, slot_size=2, bits_per_estimate=100, baud=1000.0)
    env.reset(seed=0)
    env.step({a: env.action_space(a).sample() for a in env.agents})
    # the env adds the slot duration nine times (one rounding each); the formulas round a few times
    assert_close_conditioned(env.t, 9 * 2 * 100 / 1000.0, tolerance(env.t, 9 + 3), err_msg="frame time")
    assert_close_conditioned(
        env.metrics()["frame_rate"], 1000.0 / (2 * 9 * 100), tolerance(1.0 / env.t, 6), err_msg="frame rate"
    )
    # §4: nine robots, 192 bits, 3000 baud: about 1.7, 0.6 and 0.2 Hz
    for m, hz in theory.paper_frame_rates().items():
        assert 3000.0 / (m * 9 * 192) == pytest.approx(hz, rel=0.15)


def flooding_reference(side, order, frames):
    """Set-based flooding on a 4-neighbour grid with the given slot order: first-arrival slot index."""
    n = side * side
    nbrs = [[j for j in range(n) if abs(j // side - i // side) + abs(j % side - i % side) == 1] for i in range(n)]
    knows = [{i} for i in range(n)]
    first = np.full((n, n), np.inf)
    np.fill_diagonal(first, 0)
    slot = 0
    for _ in range(frames):
        for s in order:
            slot += 1
            for r in nbrs[s]:
                for j in knows[s] - knows[r]:
                    first[r, j] = slot
                knows[r] |= knows[s]
    return first


def assert_times_match(got, slots, slot):
    """Times the simulation accumulated slot by slot (t += slot) against ``slots`` × slot: never known (inf) exactly
    where the reference says so; else within the rounding of as many additions as slots elapsed (cond 1)."""
    assert np.array_equal(np.isinf(got), np.isinf(slots))
    fin = np.isfinite(slots)
    ref = slots[fin] * slot
    ops = int(slots[fin].max(initial=0)) + 1
    assert_close_conditioned(got[fin], ref, tolerance(np.abs(ref).max(initial=0.0), ops), err_msg="arrival times")


def test_flooding_cold_start_matches_set_based_reference():
    side = 4
    env = MultiHopEnv(grid_side=side, slot_size=side * side, max_cycles=20)
    obs, _ = env.reset(seed=3)
    pol = POLICIES["flooding"]()
    pol.reset(env.local_views(), 3)
    for _ in range(8):
        obs, *_ = env.step(pol.act(obs, env.local_views()))
    first = flooding_reference(side, env.tdma.order.tolist(), 8)
    slot = env.slot_dur
    assert_times_match(env.first_known, first, slot)
    blk = proto.centred_block(side, 2)
    worst = first[np.ix_(blk, blk)].max()
    assert_close_conditioned(
        env.metrics()["propagation_time_2x2"],
        worst * slot,
        tolerance(worst * slot, worst + 1),
        err_msg="propagation_time_2x2",
    )
    assert env.metrics()["propagation_time_6x6"] != env.metrics()["propagation_time_6x6"]  # nan: does not fit


def test_batched_sweep_core_floods_like_the_reference():
    from mrcomm_env.multihop.sweep import GridSim

    sim = GridSim(side=4, m=16, runs=3, seed=5)
    arrival = np.full((3, 17, 16), np.inf)
    for _ in range(6):
        sim.frame(arrival, 0.0)
    for b in range(3):
        ref = flooding_reference(4, sim.orders[b].tolist(), 6)
        np.fill_diagonal(ref, np.inf)
        got = arrival[b, :16].copy()
        np.fill_diagonal(got, np.inf)
        assert_times_match(got, ref, sim.slot)


def test_no_hop_only_neighbours_ever_known():
    env = MultiHopEnv(grid_side=5, slot_size=3, max_cycles=10)
    obs, _ = env.reset(seed=0)
    pol = POLICIES["no_hop"]()
    pol.reset(env.local_views(), 0)
    while env.agents:
        obs, _, _, _, infos = env.step(pol.act(obs, env.local_views()))
    known = env.stamps > proto.UNKNOWN
    np.testing.assert_array_equal(known & ~np.eye(25, dtype=bool), env.adj)
    assert all(v["bits_sent"] == 192 for v in infos.values())  # own estimate only


def test_stamps_monotone_bounded_and_bits_counted():
    env = MultiHopEnv(scene="field", n_robots=10, speed=3.0, comm_range=40.0, slot_size=4, max_cycles=15)
    obs, _ = env.reset(seed=2)
    pol = POLICIES["location_based"]()
    pol.reset(env.local_views(), 2)
    prev = env.stamps.copy()
    total = 0.0
    while env.agents:
        obs, rew, _, _, infos = env.step(pol.act(obs, env.local_views()))
        assert np.all(env.stamps >= prev)
        assert np.all(env.stamps <= env.t)
        np.testing.assert_array_equal(np.diag(env.stamps), env.t)  # set to the frame's end time itself
        prev = env.stamps.copy()
        bits = sum(v["bits_sent"] for v in infos.values())
        assert bits == env.last_sent.sum() * 192
        assert all(v["bits_sent"] <= 4 * 192 for v in infos.values())
        total += bits
        for o in obs.values():
            assert o.dtype == np.float32 and np.all((o >= 0) & (o <= 1))
        assert next(iter(rew.values())) <= 0
        # a received position is the sender's true position at its stamp: robots move at <= speed
        known = env.stamps > proto.UNKNOWN
        err = np.linalg.norm(env.est - env.pos[None], axis=-1)
        # rounding of the distance (a few operations on coordinates of size |pos|) and of the age (on t)
        slack = tolerance(np.abs(env.pos).max() + 3.0 * env.t, ops=8)
        assert np.all(err[known] <= 3.0 * (env.t - env.stamps[known]) + slack)
    assert env.metrics()["bits_sent"] == total


def test_reward_is_importance_weighted_age():
    env = MultiHopEnv(grid_side=3, slot_size=3, alpha=2.0, layout="absolute")
    env.reset(seed=4)
    _, rew, *_ = env.step({a: np.ones(9, np.float32) for a in env.agents})
    d = np.linalg.norm(env.pos[:, None] - env.pos[None], axis=-1)
    w = np.where(np.eye(9, dtype=bool), 0.0, np.maximum(d, 1e-9) ** -2.0)
    age = np.where(env.stamps > proto.UNKNOWN, env.t - env.stamps, env.t)
    # in units of ten frames: a frame is 9 slots of 3 estimates × 192 bits at 3000 bit/s
    frame = 9 * 3 * 192 / 3000.0
    expect = -(w * age).sum() / w.sum()
    # sums of 81 non-negative terms (cond 1) in whatever order: 2·81 roundings plus the quotient and the unit
    assert_close_conditioned(rew["robot_0"], expect / (10 * frame), tolerance(abs(expect) / (10 * frame), 2 * 81 + 4))
    assert_close_conditioned(env.metrics()["weighted_mean_age"], -expect, tolerance(abs(expect), 2 * 81 + 2))


def test_bit_cost_is_the_share_of_slot_capacity_used():
    kw = dict(grid_side=3, slot_size=3, alpha=1.0, layout="absolute")
    free, priced = MultiHopEnv(**kw), MultiHopEnv(**kw, lam=2.0)
    free.reset(seed=1)
    priced.reset(seed=1)
    actions = {a: np.ones(9, np.float32) for a in free.agents}
    r_free = free.step(actions)[1]["robot_0"]
    r_priced = priced.step(actions)[1]["robot_0"]
    bits = priced.metrics()["bits_sent"]
    assert bits == 192 * priced.last_sent.sum()  # 192 bits per estimate sent, its own one included
    assert_close_conditioned(r_free - r_priced, 2.0 * bits / (9 * 3 * 192), tolerance(abs(r_free) + 2.0, 8))


def test_relative_layout_selects_candidates_nearest_first():
    env = MultiHopEnv(grid_side=3, slot_size=3, max_cycles=5)
    env.reset(seed=0)
    env.stamps[:] = 0.0  # everyone holds everyone: the candidates are ranked by distance alone
    env._rank_candidates()
    views = env.local_views()
    for i in range(9):
        cand = views[f"robot_{i}"]["candidates"]
        assert i not in cand and sorted(cand) == [j for j in range(9) if j != i]
        d = np.linalg.norm(env.pos[cand] - env.pos[i], axis=1)
        assert np.all(np.diff(d) >= 0)  # nearest first
    # select ranks 1, 4 and 6: only the first two fit the slot (m − 1 = 2), in rank order; own always sent
    bits = np.zeros(8, dtype=np.int8)
    bits[[1, 4, 6]] = 1
    candidates = env._candidates.copy()
    env.step({a: bits for a in env.agents})
    for i in range(9):
        assert set(np.flatnonzero(env.last_sent[i])) == {i, candidates[i, 1], candidates[i, 4]}
    env.step({a: np.zeros(8, dtype=np.int8) for a in env.agents})
    np.testing.assert_array_equal(env.last_sent, np.eye(9, dtype=bool))  # nothing selected: only its own


def test_relative_observation_is_ranked_candidate_features():
    env = MultiHopEnv(grid_side=3, slot_size=3, max_cycles=5)
    obs, _ = env.reset(seed=2)
    for _ in range(3):
        obs, *_ = env.step({a: np.ones(8, dtype=np.int8) for a in env.agents})
    i = 4
    row = obs[f"robot_{i}"][: 5 * 8].reshape(8, 5)
    cand = env._candidates[i]
    known = env.stamps[i, cand] > proto.UNKNOWN
    np.testing.assert_array_equal(row[:, 0], known.astype(np.float32))
    gain = np.maximum(env.stamps[i, cand] - env.sent_stamp[i, cand], 0.0)
    expect = np.where(known, gain / (gain + env.frame_dur), 0.0)
    np.testing.assert_allclose(row[:, 3], expect, rtol=1e-6)  # float32 observation
    assert 0.0 <= row.min() and row.max() <= 1.0


def test_neighbourhood_reward_is_what_the_neighbours_hold():
    env = MultiHopEnv(grid_side=3, slot_size=3, reward_mode="neighbourhood", layout="absolute")
    env.reset(seed=3)
    _, rew, *_ = env.step({a: np.ones(9, np.float32) for a in env.agents})
    age = np.where(env.stamps > proto.UNKNOWN, env.t - env.stamps, env.t)
    w = env._w
    own = (w * age).sum(axis=1) / w.sum(axis=1)
    frame = 9 * 3 * 192 / 3000.0
    for i in range(9):
        nbrs = np.flatnonzero(env.adj[i])
        expect = -own[nbrs].mean() / (10 * frame)
        # 9-term weighted sums per robot, a mean over ≤ 4 neighbours (a matrix product) and the unit
        assert_close_conditioned(rew[f"robot_{i}"], expect, tolerance(abs(expect), 2 * 9 + 2 * 9 + 4))


def test_grid_with_partial_last_row():
    env = MultiHopEnv(grid_side=3, n_robots=7, slot_size=7)
    env.reset(seed=0)
    # ids 0..6 on 3 columns: 6 sits below 3 only
    assert set(np.flatnonzero(env.adj[6])) == {3}
    assert set(np.flatnonzero(env.adj[4])) == {1, 3, 5}
    assert math.isnan(env.metrics()["propagation_time_2x2"])  # centred blocks only on a square grid


def test_slot_order_random_per_episode_and_seeded():
    env = MultiHopEnv(grid_side=4)
    env.reset(seed=1)
    a = env.tdma.order.copy()
    env.reset(seed=1)
    np.testing.assert_array_equal(a, env.tdma.order)
    env.reset(seed=2)
    assert not np.array_equal(a, env.tdma.order)


@pytest.mark.parametrize(
    "bad",
    [
        dict(scene="field", n_robots=1),
        dict(slot_size=0),
        dict(slot_size=101),
        dict(alpha=0.0),
        dict(alpha=-1.0),
        dict(bits_per_estimate=0),
        dict(baud=0.0),
        dict(baud=-5.0),
        dict(scene="coverage", slot_size=10),
    ],
)
def test_bad_arguments_raise(bad):
    with pytest.raises(ValueError):
        MultiHopEnv(**bad)


def test_action_priorities_select_top_m_with_own_always():
    env = MultiHopEnv(grid_side=3, slot_size=3, max_cycles=5, layout="absolute")
    env.reset(seed=0)
    env.stamps[:] = 0.0  # everyone knows everyone
    prio = np.tile(np.linspace(0.1, 0.9, 9, dtype=np.float32), (9, 1))
    env.step({a: prio[i] for i, a in enumerate(env.agents)})
    for i in range(9):
        expect = {i} | set([j for j in np.argsort(-prio[i]) if j != i][:2])
        assert set(np.flatnonzero(env.last_sent[i])) == expect
    env.step({a: np.zeros(9, np.float32) for a in env.agents})
    np.testing.assert_array_equal(env.last_sent, np.eye(9, dtype=bool))  # priority 0 withholds


def test_age_aware_beats_location_based_at_equal_m():
    res = {}
    for name in ("location_based", "age_aware"):
        env = MultiHopEnv(grid_side=6, slot_size=4, max_cycles=160)
        obs, _ = env.reset(seed=0)
        pol = POLICIES[name]()
        pol.reset(env.local_views(), 0)
        rewards = []
        while env.agents:
            obs, r, *_ = env.step(pol.act(obs, env.local_views()))
            rewards.append(r["robot_0"])
        res[name] = -np.mean(rewards[80:])
    assert res["age_aware"] < res["location_based"]


def test_coverage_cost_of_3x3_grid_and_controller_reaches_it():
    L = 100.0
    c = (np.arange(3) + 0.5) * L / 3
    pos = np.array([[x, y] for x in c for y in c])
    pts = (np.mgrid[0:300, 0:300].reshape(2, -1).T + 0.5) * (L / 300)
    # centroidal 3×3 configuration: each cell a square of side L/3, mean squared distance 2 (L/3)² / 12
    assert theory.coverage_cost(pos, pts) == pytest.approx(L**2 / 54, rel=1e-3)
    env = MultiHopEnv(scene="coverage", slot_size=9, max_cycles=10**6)
    obs, _ = env.reset(seed=0)
    pol = POLICIES["flooding"]()
    pol.reset(env.local_views(), 0)
    while env.t < 250:
        obs, *_ = env.step(pol.act(obs, env.local_views()))
    assert env.coverage_cost() < 1.05 * L**2 / 54


def test_single_run_fast_paths_equal_the_batched_core():
    rng = np.random.default_rng(7)
    n, m = 12, 4
    for _ in range(20):
        prio = np.where(rng.random((n, n)) < 0.2, 0.0, rng.random((n, n)))
        prio[rng.random((n, n)) < 0.2] = 0.5  # ties
        known = rng.random((n, n)) < 0.6
        rank, count = priority_ranking(prio)
        for s in range(n):
            cand = rank[s, : count[s]]
            k = known[s].copy()
            k[s] = True
            fast = cand[k[cand]][:m]
            np.testing.assert_array_equal(np.sort(fast), np.sort(priority_select(prio[s], known[s], s, m)))
        stamps = np.where(known, rng.uniform(0, 10, (n, n)), proto.UNKNOWN)
        pos = rng.random((n, n, 2))
        s = int(rng.integers(n))
        rcv = np.flatnonzero(rng.random(n) < 0.4)
        rcv = rcv[rcv != s]
        idx = priority_select(prio[s], known[s], s, m)
        a, pa = stamps.copy(), pos.copy()
        deliver_one(a, s, rcv, idx, pa)
        bst, bpos = stamps[None].copy(), pos[None].copy()
        sel = np.zeros((1, n), dtype=bool)
        sel[0, idx] = True
        proto.deliver(bst, np.array([0]), np.array([s]), rcv[None], sel, bpos)
        np.testing.assert_array_equal(a, bst[0])
        np.testing.assert_array_equal(pa, bpos[0])


def test_flooding_fresh_stamp_time_equals_cold_start_time():
    # with m = n every slot forwards everything, so a fresh stamp spreads exactly like the cold start
    from mrcomm_env.multihop.sweep import grid_propagation

    blocks = {k: proto.centred_block(4, k) for k in (2, 4)}
    res = grid_propagation(4, 16, 3, seed=9, blocks=blocks, warm_frames=2, max_frames=50)
    # times are sums of the slot duration, the steady ones less the start time t0: at most as many roundings of
    # the episode's end time as slots elapsed (cold frames, warm frames, steady frames)
    slot = theory.slot_duration(16, 192, 3000.0)
    frame = 16 * slot
    end = max(res["cold"][k][0].max() + res["steady"][k][0].max() for k in blocks) + (2 + 2) * frame
    for k in blocks:
        for stat in (0, 1):
            assert_close_conditioned(
                res["cold"][k][stat],
                res["steady"][k][stat],
                tolerance(end, int(end / slot) + 1),
                err_msg=f"block {k}, stat {stat}",
            )
    # m = 1 never completes a subgraph with non-adjacent pairs (the 2×2's diagonals)
    res1 = grid_propagation(4, 1, 2, seed=9, blocks={2: blocks[2]}, steady=False, max_frames=20)
    assert np.all(np.isinf(res1["cold"][2][0]))


def test_the_render_colour_scale_is_fixed_for_the_episode():
    """The age colours mean the same in every frame of an episode (they once followed each frame's range)."""
    from matplotlib.figure import Figure

    env = MultiHopEnv(grid_side=4, max_cycles=30, render_mode="rgb_array")
    env.reset(seed=0)
    limits = []
    for _ in range(3):
        for _ in range(10):
            env.step({a: env.action_space(a).sample() for a in env.agents})
        ax = Figure().add_subplot()
        env._render(ax)
        scatter = next(c for c in ax.collections if c.get_array() is not None and c.norm is not None)
        limits.append((scatter.norm.vmin, scatter.norm.vmax))
    assert len(set(limits)) == 1 and limits[0][0] < limits[0][1]


@pytest.mark.parametrize(
    ("kwargs", "policy"),
    [
        ({"grid_side": 6, "max_cycles": 40}, "location_based"),  # cold start to steady state: first arrivals
        ({"grid_side": 5, "slot_size": 25, "max_cycles": 12}, "random"),  # flooding
        ({"grid_side": 4, "slot_size": 1, "max_cycles": 12}, "random"),  # no hop
        ({"scene": "field", "n_robots": 15, "speed": 0.0, "max_cycles": 15}, "age_aware"),  # static disk links
        ({"grid_side": 4, "layout": "absolute", "reward_mode": "neighbourhood", "max_cycles": 15}, "random"),
        ({"scene": "field", "n_robots": 8, "speed": 2.0, "max_cycles": 6}, "random"),  # moving: each slot's links
        ({"scene": "field", "n_robots": 12, "speed": 2.0, "comm_range": 35.0, "max_cycles": 30}, "location_based"),
        ({"scene": "coverage", "max_cycles": 4}, "random"),  # the coverage controller flies between slots
    ],
)
def test_whole_episodes_are_identical_with_the_compiled_frame(kwargs, policy):
    """The env (its world of one copy) plays the episodes of the frame written slot by slot in numpy."""
    from mrcomm_baselines import make_policy

    def episode(compiled):
        env = MultiHopEnv(**kwargs) if compiled else ReferenceMultiHop(**kwargs)
        pol = make_policy("MultiHop-v0", policy)
        views = env.local_views()
        obs, infos = env.reset(seed=23)
        pol.reset(views, 23)
        trace = [(obs, infos)]
        while env.agents:
            obs, rewards, _, _, infos = env.step(pol.act(obs, views))
            arrays = (env.stamps, env.first_known, env.last_sent, env.sent_stamp)
            trace.append((obs, rewards, infos, env.t, *(a.copy() for a in arrays)))
        return trace, repr(env.metrics()), env.ledger.total_bits.tolist()

    reference, compiled = episode(False), episode(True)
    assert len(reference[0]) == len(compiled[0]) > 1
    for want, got in zip(reference[0], compiled[0]):
        assert all(bit_identical(a, b) for a, b in zip(want, got, strict=True))
    assert reference[1:] == compiled[1:]
