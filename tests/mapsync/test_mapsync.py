"""MapSync-v0 (paper 002): protocols against independent references and bounds, env mechanics, baselines."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
from helpers.mapsync_reference import (
    ReferenceMapSync,
    StreamingDecoder,
    arithmetic_field,
    protocol1_batch,
    random_walk,
    reference_bisection,
    reference_change_world,
    reference_disagreement,
    reference_inner_products,
    reference_observation,
    reference_sense,
    reference_sketch,
    segment_inner_products,
    syndromes,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

import mrcomm_env
from mrcomm_baselines import make_policy
from mrcomm_env.experiments.evaluation import run_episode
from mrcomm_env.mapsync import kernels_numba, theory, world
from mrcomm_env.mapsync import protocol as proto
from mrcomm_env.mapsync.env import EQUALITY, FULL, IDLE, SKETCH, MapSyncEnv
from mrcomm_env.mapsync.philox import SharedStrings, philox4x32


def maps_with_differences(rng, n, d, density=0.3):
    x = rng.random(n) < density
    y = x.copy()
    diff = rng.choice(n, size=d, replace=False)
    y[diff] ^= True
    return x, y, np.sort(diff)


# ------------------------------------------------------------------------------------------------ shared strings
@pytest.mark.parametrize(
    ("counter", "key", "expected"),
    [  # Random123's known-answer vectors for Philox4x32-10 (kat_vectors)
        ((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
        ((0xFFFFFFFF,) * 4, (0xFFFFFFFF, 0xFFFFFFFF), (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
        (
            (0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344),
            (0xA4093822, 0x299F31D0),
            (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1),
        ),
    ],
)
def test_philox_matches_random123_known_answers(counter, key, expected):
    assert philox4x32(np.array(counter, dtype=np.uint64), key).tolist() == list(expected)


@pytest.mark.parametrize("n", [16, 45, 64, 100])
def test_on_demand_strings_equal_the_explicit_database(n):
    on_demand = SharedStrings(n, seed=1234)
    explicit = SharedStrings(n, seed=1234, explicit=True)
    rows = np.arange(on_demand.size)
    words = on_demand.words(rows, np.zeros(rows.size, np.int64), on_demand.words_per_string)
    assert np.array_equal(words, explicit.database)
    # bits past n are zero, so a string has exactly n bits
    bits = np.unpackbits(explicit.database.view(np.uint8), axis=1, bitorder="little")
    assert not bits[:, n:].any()
    # a segment's inner product from the database's bits (integer dot product) equals the packed popcount path
    rng = np.random.default_rng(n)
    x = rng.random(n) < 0.5
    index = rng.integers(0, on_demand.size, size=(12, 5))
    lo = rng.integers(0, n, 12)
    hi = np.minimum(n - 1, lo + rng.integers(0, n, 12))
    (fast,) = segment_inner_products([proto.pack(x)], on_demand, index, lo, hi)
    dense = bits[:, :n].astype(np.int64)
    slow = np.array([[dense[i, a : b + 1] @ x[a : b + 1] % 2 for i in row] for row, a, b in zip(index, lo, hi)])
    assert np.array_equal(fast, slow)


def test_different_seeds_give_different_databases():
    a = SharedStrings(64, seed=1).words(np.arange(50), np.zeros(50, np.int64), 2)
    b = SharedStrings(64, seed=2).words(np.arange(50), np.zeros(50, np.int64), 2)
    assert not np.array_equal(a, b)


# ------------------------------------------------------------------------------------------------ Protocol 1
@pytest.mark.parametrize(("n", "k", "bits"), [(1024, 7, 7 * 18), (16, 3, 3 * 12), (256, 10, 10 * 16)])
def test_proposition1_bit_cost(n, k, bits):
    # ⌈log2(100n)⌉: 102400 → 17, 1600 → 11, 25600 → 15 bits of index, plus the inner-product bit
    rng = np.random.default_rng(0)
    x, y, _ = maps_with_differences(rng, n, 3)
    result = proto.equality(x, y, SharedStrings(n, 5), k, rng)
    assert result.alice_bits == bits == theory.protocol1_bits(n, k)
    assert result.bob_bits == 1


@pytest.mark.parametrize(("k", "d"), [(1, 1), (3, 1), (3, 40), (5, 2)])
def test_proposition2_one_sided_error_is_two_to_minus_k(k, d):
    n, trials = 64, 3000
    rng = np.random.default_rng(100 * k + d)
    strings = SharedStrings(n, 99)
    false_equal = 0
    for _ in range(trials):
        x, y, _ = maps_with_differences(rng, n, d)
        false_equal += proto.equality(x, y, strings, k, rng).equal
    # for X ≠ Y a uniform r_i gives X·r_i = Y·r_i with probability exactly ½, so "equal" has probability 2^−k;
    # the count is Binomial(trials, 2^−k): accept the central 1 − 2·10⁻⁶ of it
    p = theory.protocol1_error_bound(k)
    lo, hi = stats.binom.ppf(1e-6, trials, p), stats.binom.ppf(1 - 1e-6, trials, p)
    assert lo <= false_equal <= hi


def test_protocol1_never_errs_on_equal_maps_and_the_printed_step4_never_says_equal():
    n, rng = 128, np.random.default_rng(3)
    strings = SharedStrings(n, 7)
    for _ in range(200):
        x = rng.random(n) < 0.5
        assert proto.equality(x, x.copy(), strings, 2, rng).equal
        # "if the counter is greater or equal than zero return 0 (different)": true for every counter
        assert not proto.equality(x, x.copy(), strings, 2, rng, step4="as_printed").equal


# ------------------------------------------------------------------------------------------------ Algorithm 1
def algorithm1_reference(x, y, lo, hi, res, p1_bits):
    """ERRORCORRECTION line by line (recursive), with an exact equality oracle for Protocol 1.

    Returns (differing cells found, Alice's bits, Bob's verdict bits).
    """
    if hi - lo + 1 <= res:  # lines 2–6
        cells = [c for c in range(lo, hi + 1) if x[c] != y[c]]
        return cells, hi - lo + 1, 0
    if np.array_equal(x[lo : hi + 1], y[lo : hi + 1]):  # line 7, Protocol 1 says "same"
        return [], p1_bits, 1
    mid = (lo + hi) // 2  # line 1
    left = algorithm1_reference(x, y, lo, mid, res, p1_bits)
    right = algorithm1_reference(x, y, mid + 1, hi, res, p1_bits)
    return left[0] + right[0], p1_bits + left[1] + right[1], 1 + left[2] + right[2]


@pytest.mark.parametrize(("n", "res", "d"), [(1024, 1, 1), (1024, 1, 5), (1000, 1, 17), (777, 4, 9), (4096, 8, 64)])
def test_bisection_corrects_everything_and_matches_the_recursive_algorithm(n, res, d):
    # k = 40: a missed difference has probability ≤ (tests)·2^−40, so the comparison is exact
    k, rng = 40, np.random.default_rng(n + d)
    x, y, diff = maps_with_differences(rng, n, d)
    result = proto.bisection(x, y, SharedStrings(n, 3), k, res, rng)
    assert np.array_equal(result.found, diff)
    cells, alice, bob = algorithm1_reference(x, y, 0, n - 1, res, theory.protocol1_bits(n, k))
    assert cells == diff.tolist() and result.alice_bits == alice and result.bob_bits == bob
    assert result.rounds == theory.recursion_depth(n, res) + (1 if res < n else 0)


@pytest.mark.parametrize(("n", "d"), [(1024, 1), (1024, 4), (1024, 64), (4096, 16), (1000, 3)])
def test_bisection_bits_stay_below_the_worst_case_bound(n, d):
    k, res = 10, 1
    bound = theory.algorithm1_worst_case(n, k, res, d)
    rng = np.random.default_rng(d)
    for _ in range(5):
        x, y, _ = maps_with_differences(rng, n, d)
        result = proto.bisection(x, y, SharedStrings(n, 8), k, res, rng)
        assert result.alice_bits <= bound["alice"] and result.bob_bits <= bound["bob"]


def test_bisection_bound_is_attained_and_the_papers_formula_is_not_a_bound():
    # one difference in a power-of-two map: every level tests both halves of the differing segment
    n, k, res = 1024, 10, 1
    x = np.zeros(n, dtype=bool)
    y = x.copy()
    y[300] = True
    result = proto.bisection(x, y, SharedStrings(n, 1), 40, res, np.random.default_rng(0))
    p1 = theory.protocol1_bits(n, 40)
    assert result.alice_bits == (1 + 2 * 9) * p1 + 2  # root, two tests on each of 9 levels, two 1-bit leaves
    assert result.alice_bits == theory.algorithm1_worst_case(n, 40, res, 1)["alice"]
    # §IV-B charges one Protocol 1 per level: 10 · p1 + 1, about half of what the algorithm sends
    assert result.alice_bits > theory.algorithm1_paper_worst_case(n, 40, res, 1)
    assert theory.algorithm1_paper_worst_case(n, k, res, 1) == 10 * theory.protocol1_bits(n, k) + 1


# ------------------------------------------------------------------------------------------------ sketch
def test_pinsketch_is_linear_and_decodes_up_to_capacity():
    rng = np.random.default_rng(0)
    gf = arithmetic_field(10)
    a = rng.choice(np.arange(1, 1024), 40, replace=False)
    b = rng.choice(np.arange(1, 1024), 40, replace=False)
    sym = np.setxor1d(a, b)
    t = 12
    assert np.array_equal(syndromes(gf, a, t) ^ syndromes(gf, b, t), syndromes(gf, sym, t))
    for d in (1, 2, 7, 12):
        diff = np.sort(rng.choice(np.arange(1, 1024), d, replace=False))
        decoder = StreamingDecoder(gf, 1023)
        for s in syndromes(gf, diff, d):
            decoder.add(int(s))
        assert np.array_equal(np.sort(decoder.decode()), diff)


def test_field_tables_are_a_field():
    for m in (2, 5, 10, 16):
        gf = arithmetic_field(m)
        assert sorted(gf.exp[: gf.order].tolist()) == list(range(1, gf.q))  # α generates every nonzero element
        a, b = 3 % gf.q or 1, gf.q - 1
        assert gf.mul(gf.div(a, b), b) == a


# n = 65536 with d = 64 takes seconds per run (Chien search over 65535 elements); the bits table covers it
@pytest.mark.parametrize(
    ("n", "d"),
    [(n, d) for n in (1024, 4096) for d in (1, 2, 3, 8, 16, 33, 64)]
    + [(65536, d) for d in (1, 4, 16)]
    # just above a power of two the field grows by a bit: still within 2× except n ∈ [1025, 1204] at d near 64
    + [(1025, 1), (1025, 2), (1025, 16), (1500, 1), (1500, 64), (2049, 1), (2049, 64)],
)
def test_sketch_recovers_exactly_within_twice_the_information_bound(n, d):
    rng = np.random.default_rng(7 * d + n)
    bound = theory.log2_binomial(n, d)
    for trial in range(3):
        x, y, diff = maps_with_differences(rng, n, d)
        result = proto.sketch(x, y, seed=11, nonce=trial)
        assert np.array_equal(result.found, diff)
        assert result.bits <= 2 * bound, (result.bits, bound)  # parities, cell 0 and the stop bit included
        assert not result.extra["fallback"]


def test_sketch_of_equal_maps_costs_only_the_check():
    x = np.random.default_rng(0).random(4096) < 0.4
    result = proto.sketch(x, x.copy(), seed=1, nonce=0)
    # v = ⌊2 log2 4096⌋ − 12 − 2 = 10 parity bits, cell 0 and the stop bit
    assert result.found.size == 0 and result.bits == 10 + 1 + 1
    # cell 0 is sent as it is (the field has no element 0): a difference there alone costs the same
    y = x.copy()
    y[0] = ~y[0]
    result = proto.sketch(x, y, seed=1, nonce=0)
    assert result.found.tolist() == [0] and (result.alice_bits, result.bob_bits) == (10 + 1, 1)


def test_return_code_length():
    assert proto.return_bits(256, 0) == 9  # count only
    assert proto.return_bits(256, 3) == 9 + math.ceil(math.log2(math.comb(256, 3)))


@pytest.mark.parametrize("candidates", [1, 2, 3, 16, 45, 256, 1000])
def test_the_return_bits_table_is_return_bits_for_every_count_of_found_cells(candidates):
    """What the compiled syncs charge for Bob's way back (they have no big integers for ⌈log2 C(C, d)⌉)."""
    table = proto.return_bits_table(candidates)
    assert table.tolist() == [proto.return_bits(candidates, d) for d in range(candidates + 1)]
    assert table[0] == max(1, candidates.bit_length()) and not table.flags.writeable


# ------------------------------------------------------------------------------------------------ env mechanics
def step_all(env, action_of):
    return env.step({a: action_of.get(a, IDLE) for a in env.agents})


def test_paper_preset_is_figure7():
    env = MapSyncEnv(preset="paper")
    env.reset(seed=0)
    obstacles = {(c % 16, c // 16) for c in np.flatnonzero(env.truth)}
    assert obstacles == set(world.PAPER_OBSTACLES)
    start = MapSyncEnv(preset="paper")
    start.reset(seed=5)
    # Alice and Bob sensed their starts (11, 7) and (3, 7) before the first move
    assert start.stamps[0, 7 * 16 + 11] == 0 and start.stamps[1, 7 * 16 + 3] == 0
    assert env.cfg.max_cycles == 200 and env.cfg.k == 10


def test_equality_action_charges_proposition1_and_the_verdict():
    env = MapSyncEnv(grid_size=16, k=10)
    env.reset(seed=1)
    step_all(env, {"robot_0": EQUALITY})
    assert env.ledger.total_bits.tolist() == [10 * 16, 1]  # n = 256: ⌈log2 25600⌉ = 15, +1 per round


def test_one_sync_when_both_ask():
    both, one = MapSyncEnv(), MapSyncEnv()
    both.reset(seed=4)
    one.reset(seed=4)
    for _ in range(15):
        step_all(both, {})
        step_all(one, {})
    step_all(both, {"robot_0": FULL, "robot_1": FULL})
    step_all(one, {"robot_0": FULL})
    assert both.metrics()["syncs"] == one.metrics()["syncs"] == 1
    assert both.ledger.total_bits.tolist() == one.ledger.total_bits.tolist()
    assert np.array_equal(both.maps, one.maps)


@pytest.mark.parametrize(
    "config",
    [
        {"appear_rate": 0.002, "vanish_rate": 0.02, "max_cycles": 120},  # the shipped training configuration
        {"n_robots": 5, "grid_size": 8, "appear_rate": 0.02, "vanish_rate": 0.05, "max_cycles": 80},
        {"n_robots": 9, "res": 4, "comm_range": 5.0, "link_prob": 0.7, "max_cycles": 80},  # busy peers, broken links
    ],
)
def test_syncs_completed_within_their_step_are_the_sessions_of_a_limited_link(config, monkeypatch):
    """Without ``bits_per_step`` every sync completes in the step it is asked for, and the env takes a shorter way
    than opening sessions and delivering their transcripts (``_sync_within_step``). Both ways give the same episode:
    observations, rewards, infos, bits, detections, metrics, maps and the generator's state."""

    def episode(general: bool) -> list:
        env = MapSyncEnv(**config)
        if general:  # the sessions of a link with a bit budget, which here carries every transcript at once
            monkeypatch.setattr(env, "_sync_within_step", lambda actions, t: _open_and_progress(env, actions, t))
        obs, infos = env.reset_arrays(seed=3)
        rng = np.random.default_rng(3)
        record = [obs.tolist(), sorted((k, v.tolist()) for k, v in infos.items())]
        while env.agents:
            obs, rewards, terminated, truncated, infos = env.step_arrays(rng.integers(0, 5, env.n_agents))
            record += [obs.tolist(), rewards.tolist(), terminated, truncated]
            record += [sorted((k, v.tolist()) for k, v in infos.items()), env.ledger.step_bits.tolist()]
        record += [sorted(env.metrics().items()), list(env.detections), env.maps.tolist(), env.stamps.tolist()]
        return [*record, env.np_random.bit_generator.state]

    def _open_and_progress(env, actions, t):
        env._start_sessions(actions, t)
        env._progress_sessions(t)
        assert not env.sessions  # every session completed (or was aborted) within its step

    fast, general = episode(general=False), episode(general=True)
    assert fast == general
    metrics = dict(fast[-5])  # the record ends with the metrics, detections, maps, stamps and generator state
    assert metrics["syncs"] > 10 and metrics["detections"] > 0 and metrics["corrected_fraction"] > 0


def test_a_full_sync_merges_newest_wins_under_appearing_and_vanishing_obstacles():
    env = MapSyncEnv(grid_size=8, n_obstacles=12, n_robots=3, appear_rate=0.02, vanish_rate=0.1, max_cycles=400)
    env.reset(seed=2)
    rng = np.random.default_rng(0)
    checked = 0
    for t in range(300):
        if t % 7:
            step_all(env, {})
            continue
        a, b = rng.choice(3, 2, replace=False)
        before_maps, before_stamps = env.maps.copy(), env.stamps.copy()
        bits_before = env.ledger.total_bits.sum()
        step_all(env, {f"robot_{a}": FULL})
        sensed_now = env.stamps == env.step_count  # cells sensed after the merge, within this step
        b = next(j for j in range(3) if j != a and env.last_sync[a, j] == env.step_count)
        newer_b = before_stamps[b] > before_stamps[a]
        expected = np.where(newer_b, before_maps[b], before_maps[a])
        for r in (a, b):
            keep = ~sensed_now[r]
            assert np.array_equal(env.maps[r][keep], expected[keep])
            # stamps travel only with the differing cells; elsewhere each robot keeps its own
            differ = before_maps[a] != before_maps[b]
            stamp = np.where(differ, np.maximum(before_stamps[a], before_stamps[b]), before_stamps[r])
            assert np.array_equal(env.stamps[r][keep], stamp[keep])
        # stamps of the differing cells travel both ways: ⌈log2(400 + 2)⌉ = 9 bits each
        d = int((before_maps[a] != before_maps[b]).sum())
        ret = proto.return_bits(64, d)
        assert env.ledger.total_bits.sum() - bits_before == 64 + ret + (2 * 9 * d)
        checked += d
    assert checked > 20  # the world did change and the maps did disagree


def test_gossip_converges_once_the_world_stops_changing():
    env = MapSyncEnv(grid_size=8, n_robots=4, appear_rate=0.03, vanish_rate=0.1, max_cycles=500)
    env.reset(seed=9)
    for _ in range(80):
        step_all(env, {})
    # freeze the world (the merge stays last-writer-wins): the env reads the rates once, at construction
    env.cfg["appear_rate"] = env.cfg["vanish_rate"] = 0.0
    env._changing = False
    env.pos[:] = env.pos[0]  # gather the robots in one cell so that they all sense the same cells from now on
    # and keep them there (the walk reads the neighbour table): no new cells are seen
    env._neighbour_table = np.full((env.n, 4), -1, dtype=np.int64)
    # what gossip must converge to: each cell's newest observation by any robot (the gathering cell and its
    # neighbours are sensed again from now on, and the frozen world is what they see)
    newest = env.stamps.argmax(axis=0)
    expected = env.maps[newest, np.arange(env.n)].copy()
    sensed = world.sensing_table(world.neighbour_table(8))[0][env.pos[0]]
    expected[sensed] = env.truth[sensed]
    assert (env.maps != expected).any(), "nothing to converge: the test would not test anything"
    for _ in range(6):
        step_all(env, {a: SKETCH for a in env.agents})
    assert (env.maps == expected).all(), "gossip did not converge to the newest observations"


def test_latency_is_counted_when_a_sync_exceeds_the_link_budget():
    cap = 64
    env = MapSyncEnv(bits_per_step=cap)
    env.reset(seed=3)
    for _ in range(20):
        step_all(env, {})
    x, y = env.maps[0].copy(), env.maps[1].copy()
    d = int((x != y).sum())
    total = 256 + proto.return_bits(256, d)
    steps = math.ceil(total / cap)
    start = env.step_count
    step_all(env, {"robot_0": FULL})
    for _ in range(steps - 1):
        assert env.session_of[0] >= 0 and env.ledger.step_bits.sum() == cap
        assert env.metrics()["syncs"] == 0
        step_all(env, {"robot_0": FULL, "robot_1": SKETCH})  # busy robots cannot start another sync
    assert env.metrics()["syncs"] == 1 and env.metrics()["sync_latency_steps"] == steps
    assert env.ledger.total_bits.sum() == total
    assert env.step_count - start == steps


def test_a_broken_link_aborts_the_sync():
    env = MapSyncEnv(bits_per_step=8, comm_range=3.0, max_cycles=400)
    env.reset(seed=0)
    for _ in range(400):
        if not env.agents:
            break
        step_all(env, {"robot_0": FULL})
    m = env.metrics()
    assert m["aborted_syncs"] > 0
    assert m["bits_sent"] > 0


# ------------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"grid_size": 1}, "grid_size"),
        ({"k": 0}, "'k'"),
        ({"res": 0}, "'res'"),
        ({"grid_size": 4, "n_obstacles": 16}, "n_obstacles"),
        ({"preset": "paper", "grid_size": 8}, "preset"),
        ({"preset": "fig9"}, "preset"),
        ({"grid_size": 64, "explicit_database": True}, "explicit_database"),
        ({"bits_per_step": 0}, "bits_per_step"),
    ],
)
def test_bad_arguments_raise(kwargs, name):
    with pytest.raises(ValueError, match=name):
        MapSyncEnv(**kwargs)


def test_bad_protocol_inputs_raise():
    rng = np.random.default_rng(0)
    one = np.zeros(1, dtype=bool)
    with pytest.raises(ValueError, match="'n'"):
        proto.full(one, one)
    with pytest.raises(ValueError, match="'n'"):
        SharedStrings(1, 0)
    x = np.zeros(8, dtype=bool)
    with pytest.raises(ValueError, match="'k'"):
        proto.equality(x, x, SharedStrings(8, 0), 0, rng)
    with pytest.raises(ValueError, match="'res'"):
        proto.bisection(x, x, SharedStrings(8, 0), 3, 0, rng)
    with pytest.raises(ValueError, match="'protocol'"):
        proto.check_protocol("telepathy")
    with pytest.raises(ValueError, match="'step4'"):
        proto.equality(x, x, SharedStrings(8, 0), 3, rng, step4="maybe")
    with pytest.raises(ValueError, match="'step4'"):
        proto.bisection(x, x, SharedStrings(8, 0), 3, 1, rng, step4="maybe")


# ------------------------------------------------------------------------------------------------ baselines
def test_case_study_detects_only_at_sync_times_and_never_sends_nothing():
    env = mrcomm_env.make("MapSync-v0", preset="paper")
    run_episode(env, make_policy("MapSync-v0", "periodic_equality_then_bisection"), seed=0)
    assert env.detections and all(step % 10 == 0 for step, *_ in env.detections)
    assert env.metrics()["syncs"] == 19  # steps 10, 20, …, 190
    silent = mrcomm_env.make("MapSync-v0", preset="paper")
    m = run_episode(silent, make_policy("MapSync-v0", "never"), seed=0)
    assert m["bits_sent"] == 0 and m["syncs"] == 0


def test_periodic_sync_lowers_disagreement_and_sketch_sends_fewer_bits_than_full():
    results = {}
    for name in ("never", "periodic_full", "periodic_sketch", "periodic_equality_then_bisection"):
        env = mrcomm_env.make("MapSync-v0", preset="paper")
        results[name] = run_episode(env, make_policy("MapSync-v0", name), seed=3)
    assert results["periodic_full"]["disagreement"] < results["never"]["disagreement"]
    # full and sketch reconcile exactly, so with the same walk they end every sync with the same maps
    assert results["periodic_sketch"]["disagreement"] == results["periodic_full"]["disagreement"]
    assert results["periodic_sketch"]["bits_sent"] < results["periodic_full"]["bits_sent"]


def test_separate_test_variant_runs_bisection_only_after_a_difference():
    env = mrcomm_env.make("MapSync-v0", preset="paper")
    run_episode(env, make_policy("MapSync-v0", "periodic_equality_then_bisection", separate_test=True), seed=0)
    kinds = {(step, kind) for step, _, _, kind in env.detections}
    for step, kind in kinds:
        if kind == "bisection":
            assert (step - 1, "equality") in kinds


# ------------------------------------------------------------------------------------------------ compiled twin
@pytest.mark.parametrize("n", [16, 45, 77, 256, 1024, 4096])
@pytest.mark.parametrize("cached", [False, True])
def test_compiled_inner_products_equal_the_numpy_reference(n, cached):
    kernels = kernels_numba
    rng = np.random.default_rng(n)
    strings = SharedStrings(n, 42, cache=cached)
    maps = [proto.pack(rng.random(n) < 0.5), proto.pack(rng.random(n) < 0.5)]
    index = rng.integers(0, strings.size, (15, 4))
    lo = rng.integers(0, n, 15)
    hi = np.minimum(n - 1, lo + rng.integers(0, n, 15))
    lo[0], hi[0] = 0, n - 1
    database = strings.database if cached and strings.database is not None else np.zeros((1, 1), np.uint32)
    compiled = kernels.inner_products(
        np.stack(maps),
        database,
        strings.database is not None,
        strings.key[0],
        strings.key[1],
        0,
        strings.words_per_string,
        int(strings.last_mask),
        index,
        lo,
        hi,
        proto._FROM_BIT,
        proto._TO_BIT,
    )
    reference = reference_inner_products(maps, strings, index, lo, hi)
    assert all(np.array_equal(c, r) for c, r in zip(compiled, reference))


@pytest.mark.parametrize("domain", [0, 1])
def test_compiled_stream_words_equal_the_numpy_generator(domain):
    """Aligned and unaligned starts, runs shorter and longer than a block, indices up to 2^32 − 1, 64-bit seeds."""
    kernels = kernels_numba
    from mrcomm_env.mapsync.philox import seed_key, stream_words

    rng = np.random.default_rng(31 + domain)
    for _ in range(300):
        rows, n_words = int(rng.integers(1, 12)), int(rng.integers(1, 40))
        key = seed_key(int(rng.integers(0, 2**63)))
        index = rng.integers(0, 2**32, rows).astype(np.uint64)
        first_word = rng.integers(0, 5000, rows) if rng.random() < 0.7 else np.zeros(rows, np.int64)
        want = stream_words(key, index, first_word, n_words, domain)
        got = kernels.stream_words(key[0], key[1], index, first_word, n_words, domain)
        assert got.dtype == want.dtype == np.uint32 and np.array_equal(got, want)


def _use_compiled_bisection(monkeypatch, compiled: bool) -> None:
    """Run Algorithm 1 compiled (the package's) or as its numpy rounds (``reference_bisection``) inside the env."""
    if not compiled:
        monkeypatch.setattr(proto, "bisection", reference_bisection)


def test_compiled_sketch_is_the_reference_step_for_step():
    """The compiled sketch (``kernels_numba.sketch``) and its oracle (``reference_sketch``): the same cells, bits, rounds and record, over maps with
    no, few and more differences than the syndromes can decode (Alice falls back to her map), cell 0 differing or
    not, map sizes off and on word boundaries, and one or two parity bits, so that wrong guesses pass them."""
    rng = np.random.default_rng(21)
    outcomes: dict[str, int] = {}
    for trial in range(600):
        n = int(rng.choice([2, 3, 17, 32, 33, 64, 100, 256, 1000, 1024, 2000]))
        x = rng.random(n) < 0.3
        y = x.copy()
        d = int(rng.choice([0, 1, 2, 3, 5, 9, 40]))
        y[rng.choice(n, size=min(d, n), replace=False)] ^= True
        if trial % 5 == 0:
            y[0] = not x[0]
        verify_bits = None if trial % 3 else int(rng.integers(1, 3))
        strict = bool(trial % 2)
        seed = int(rng.integers(2**63))
        want = reference_sketch(x, y, seed, trial, verify_bits=verify_bits, strict_feedback=strict)
        got = proto.sketch(x, y, seed, trial, verify_bits=verify_bits, strict_feedback=strict)
        assert want.found.dtype == got.found.dtype and want.found.tobytes() == got.found.tobytes()
        assert (want.alice_bits, want.bob_bits, want.rounds, want.candidates, want.detected) == (
            got.alice_bits,
            got.bob_bits,
            got.rounds,
            got.candidates,
            got.detected,
        )
        assert want.extra == got.extra
        kind = "fallback" if want.extra["fallback"] else ("decoded" if want.extra["syndromes"] else "check")
        key = f"{kind}, {'exact' if np.array_equal(np.flatnonzero(x != y), want.found) else 'wrong'}"
        outcomes[key] = outcomes.get(key, 0) + 1
    assert outcomes.get("decoded, exact", 0) > 100 and outcomes.get("fallback, exact", 0) > 20
    assert outcomes.get("decoded, wrong", 0) + outcomes.get("check, wrong", 0) > 5  # wrong guesses passed


@pytest.mark.parametrize("cached", [False, True])
def test_compiled_equality_is_the_reference(cached):
    """Protocol 1 on whole maps (``kernels_numba.equality_counter``) against the numpy rounds on the whole map
    (``protocol1_batch``): the same verdict, counter and generator state afterwards, with few rounds (differences
    missed) and with many, under step 4 fixed and as printed (which never answers "same")."""
    rng = np.random.default_rng(31)
    verdicts = {True: 0, False: 0}
    for trial in range(300):
        n = int(rng.choice([2, 31, 32, 33, 100, 256, 1024]))
        x, y, _ = maps_with_differences(rng, n, int(rng.integers(0, min(n, 6) + 1)))
        strings = SharedStrings(n, int(rng.integers(100)), cache=cached)
        k = int(rng.choice([1, 2, 10, 64]))
        step4 = proto.STEP4_RULES[trial % 3 == 0]
        compiled, reference = np.random.default_rng(trial), np.random.default_rng(trial)
        got = proto.equality(x, y, strings, k, compiled, step4)
        equal, counter = protocol1_batch(proto.pack(x), proto.pack(y), strings, k, 0, n - 1, reference, step4)
        assert type(got.equal) is bool and type(got.counter) is int
        if step4 == "fixed" and np.array_equal(x, y):  # answered without inner products: the counter is known, 0
            assert int(counter[0]) == 0
        assert (got.equal, got.counter) == (bool(equal[0]), int(counter[0]))
        assert compiled.bit_generator.state == reference.bit_generator.state
        if step4 == "fixed":
            verdicts[got.equal and not np.array_equal(x, y)] += 1
        else:
            assert not got.equal
    assert verdicts[True] > 10 and verdicts[False] > 100  # "same" said of differing maps, and the rest


@pytest.mark.parametrize(
    ("n", "res", "k", "d"),
    [(2, 1, 1, 1), (16, 1, 3, 16), (45, 3, 2, 7), (77, 1, 1, 0), (256, 1, 10, 3), (1000, 4, 5, 40), (1024, 1, 7, 1)],
)
@pytest.mark.parametrize("cached", [False, True])
@pytest.mark.parametrize("step4", proto.STEP4_RULES)
@pytest.mark.parametrize("bit_generator", ["PCG64", "MT19937", "Philox"])  # numba draws from any of numpy's
def test_compiled_bisection_equals_the_reference(n, res, k, d, cached, step4, bit_generator):
    """The compiled Algorithm 1 against its numpy rounds: the same cells, bits, rounds, messages, tests (missed ones
    included: small k makes a test say "same" of a differing segment) and the generator's state afterwards."""
    rng = np.random.default_rng(100 * n + d)
    x, y, _ = maps_with_differences(rng, n, d)
    strings = SharedStrings(n, 9, cache=cached)
    runs = []
    for bisection in (reference_bisection, proto.bisection):
        generator = np.random.Generator(getattr(np.random, bit_generator)(d))
        result = bisection(x, y, strings, k, res, generator, step4)
        runs.append((result, pickle.dumps(generator.bit_generator.state)))  # MT19937's state holds an array
    (reference, state), (compiled, compiled_state) = runs
    assert np.array_equal(compiled.found, reference.found) and compiled.found.dtype == reference.found.dtype
    for name in ("alice_bits", "bob_bits", "rounds", "candidates", "detected", "extra"):
        assert getattr(compiled, name) == getattr(reference, name), name
    assert compiled_state == state  # the generator ends where the reference leaves it


def test_compiled_bisection_misses_differences_as_the_reference_does():
    """Small k makes tests err (Proposition 2: "same" said of a differing segment w.p. ≤ 2^−k); the compiled and
    numpy runs must miss the same ones, so the comparison above is not only of runs without errors."""
    rng = np.random.default_rng(7)
    missed = 0
    for trial in range(40):
        n = int(rng.choice([64, 256, 1000]))
        x, y, _ = maps_with_differences(rng, n, int(rng.integers(1, 20)))
        strings = SharedStrings(n, trial)
        got = proto.bisection(x, y, strings, 1, 2, np.random.default_rng(trial))
        want = reference_bisection(x, y, strings, 1, 2, np.random.default_rng(trial))
        assert got.extra == want.extra and np.array_equal(got.found, want.found)
        missed += got.extra["false_equal_tests"]
    assert missed > 0


def test_protocol1_and_algorithm1_on_equal_maps_return_and_draw_what_the_full_run_does():
    """Equal maps are answered without computing inner products (they are known to agree); the results and the
    generator's state afterwards must be those of the full computation, Alice's picks included."""
    rng = np.random.default_rng(5)
    # res ≥ n: the whole map is one EQUALLINEAR segment, sent without a Protocol 1 test or a pick
    for n, res, k in [
        (2, 1, 1),
        (2, 2, 3),
        (16, 16, 2),
        (16, 15, 2),
        (45, 3, 2),
        (256, 1, 10),
        (1000, 4, 5),
        (1024, 2000, 7),
    ]:
        x = rng.random(n) < 0.3
        strings = SharedStrings(n, 9)
        seed = int(rng.integers(2**32))
        shortcut, full = np.random.default_rng(seed), np.random.default_rng(seed)
        verdict = proto.equality(x, x.copy(), strings, k, shortcut)
        equal, counter = protocol1_batch(proto.pack(x), proto.pack(x), strings, k, 0, n - 1, full)
        assert (verdict.equal, verdict.counter) == (bool(equal[0]), int(counter[0]))
        assert verdict.alice_bits == theory.protocol1_bits(n, k) and verdict.bob_bits == 1
        assert shortcut.bit_generator.state == full.bit_generator.state
        got = proto.bisection(x, x.copy(), strings, k, res, shortcut)
        want = reference_bisection(x, x.copy(), strings, k, res, full)
        assert np.array_equal(got.found, want.found) and got.found.dtype == want.found.dtype
        for name in ("protocol", "alice_bits", "bob_bits", "rounds", "candidates", "detected", "extra"):
            assert getattr(got, name) == getattr(want, name), (n, res, name)
        assert shortcut.bit_generator.state == full.bit_generator.state


def test_compiled_walk_and_sense_equals_the_reference():
    """The kernel against the numpy walk and sensing (``random_walk``, ``reference_sense``) from states with stale,
    wrong and unseen bits."""
    kernels = kernels_numba
    env = MapSyncEnv(grid_size=7, n_robots=4, n_obstacles=0)
    env.reset(seed=0)
    n, n_robots = env.n, env.n_agents
    rng = np.random.default_rng(3)
    for trial in range(60):
        env.truth[:] = rng.random(n) < 0.3
        env.pos = rng.integers(0, n, n_robots)
        env.maps[:] = rng.random((n_robots, n)) < 0.3  # disagreeing with the world: stale or wrongly merged
        env.stamps[:] = np.where(rng.random((n_robots, n)) < 0.5, rng.integers(0, 50, (n_robots, n)), -1)
        env.known[:] = rng.integers(0, n, n_robots)
        env.new_cells[:] = rng.integers(0, 9, (n_robots, n_robots)) * (1 - np.eye(n_robots, dtype=np.int64))
        before = [a.copy() for a in (env.pos, env.truth, env.maps, env.stamps, env.known, env.new_cells)]
        pos, truth, maps, stamps, known, new_cells = (a.copy() for a in before)

        env.pos = random_walk(np.random.default_rng(trial), env.pos, env._neighbour_table, env.truth)
        flags = reference_sense(env, 60)
        keys = np.random.default_rng(trial).random((n_robots, 4))  # the keys random_walk drew
        out, twin_flags = kernels.walk_and_sense(
            True, keys, pos, env._neighbour_table, truth, env._sensed, env._sensed_distinct, maps, stamps, known,
            new_cells, 60,
        )  # fmt: skip
        assert np.array_equal(out, env.pos) and twin_flags == flags
        for twin, reference in zip((maps, stamps, known, new_cells), (env.maps, env.stamps, env.known, env.new_cells)):
            assert np.array_equal(twin, reference)


@pytest.mark.parametrize(("grid_size", "n_robots"), [(2, 2), (5, 3), (8, 7), (9, 8), (16, 9), (13, 17), (100, 64)])
def test_compiled_disagreement_equals_the_reference(grid_size, n_robots):
    """The kernel of ``_update_disagreement`` against its numpy oracle, to the last bit: maps of every density, rows
    of distances under and over numpy's 8-way unrolling, pairs past one 128-value block, n not a multiple of 64."""
    kernels = kernels_numba
    env = MapSyncEnv(grid_size=grid_size, n_robots=n_robots, n_obstacles=0)
    env.reset(seed=0)
    rng = np.random.default_rng(grid_size * 100 + n_robots)
    rows, cols = env._pairs
    for _ in range(20):
        density = rng.random(n_robots)[:, None]
        env.maps[:] = rng.random((n_robots, env.n)) < density  # some rows nearly empty, some nearly full
        env.truth[:] = rng.random(env.n) < rng.random()
        want_column, want_mean, want_errors, want_error_mean = reference_disagreement(env)
        column, mean, errors, error_mean = kernels.disagreement(env.maps, env.truth, rows, cols)
        assert np.array_equal(column, want_column) and np.array_equal(errors, want_errors)
        assert mean == want_mean and error_mean == want_error_mean


def test_compiled_change_world_equals_the_reference():
    """``_change_world`` against its numpy oracle from the same generator: the same cells appear and vanish (never
    where a robot stands), the generator ends in the same state (two draws of n keys are one draw of 2n), 'changed'
    is told."""
    env = MapSyncEnv(grid_size=9, n_robots=5, n_obstacles=0, appear_rate=0.1, vanish_rate=0.3)
    env.reset(seed=0)
    rng = np.random.default_rng(5)
    outcomes = set()
    for trial in range(200):
        env.cfg["appear_rate"], env.cfg["vanish_rate"] = [0.0, 1e-3, 0.1, 1.0][trial % 4], [0.0, 0.3, 1.0][trial % 3]
        env.truth[:] = rng.random(env.n) < rng.random()
        env.pos = rng.integers(0, env.n, env.n_agents)
        before = env.truth.copy()
        env.np_random = np.random.default_rng(trial)
        changed = reference_change_world(env)
        reference_truth, reference_state = env.truth.copy(), env.np_random.bit_generator.state
        env.truth[:] = before
        env.np_random = np.random.default_rng(trial)
        twin_changed = env._change_world()
        assert np.array_equal(env.truth, reference_truth) and twin_changed == changed
        assert changed == (not np.array_equal(env.truth, before))
        assert env.np_random.bit_generator.state == reference_state
        appeared = env.truth & ~before
        assert not appeared[env.pos].any()
        if env.cfg.appear_rate == 1.0:  # every free cell nobody stands on
            occupied = np.zeros(env.n, dtype=bool)
            occupied[env.pos] = True
            assert np.array_equal(appeared, ~before & ~occupied)
        outcomes.add(changed)
    assert outcomes == {True, False}


def test_compiled_observation_equals_the_reference_at_every_step():
    """Syncs in flight over a narrow link (progress), links that break, verdicts, a changing world."""
    env = MapSyncEnv(n_robots=5, bits_per_step=30, link_prob=0.6, comm_range=6.0, appear_rate=0.01, vanish_rate=0.05)
    obs, _ = env.reset(seed=4)
    assert np.array_equal(np.stack(list(obs.values())), reference_observation(env))
    rng = np.random.default_rng(1)
    in_flight = 0
    while env.agents:
        obs, *_ = env.step({a: int(rng.integers(1, 5)) if rng.random() < 0.2 else IDLE for a in env.agents})
        in_flight += bool(env.sessions)
        if env.agents:
            assert np.array_equal(np.stack(list(obs.values())), reference_observation(env))
    assert in_flight > 10, "the episode must hold syncs in flight for the progress column to be tested"


@pytest.mark.parametrize(
    ("cfg", "policy"),
    [
        ({"preset": "paper", "max_cycles": 120}, "random"),
        ({}, "periodic_equality_then_bisection"),
        ({"appear_rate": 0.01, "vanish_rate": 0.05, "max_cycles": 80}, "random"),
        ({"n_robots": 9, "grid_size": 10, "appear_rate": 0.02, "max_cycles": 40}, "random"),
        ({"n_robots": 4, "bits_per_step": 40, "comm_range": 6.0, "link_prob": 0.8, "max_cycles": 80}, "random"),
    ],
)
def test_whole_episodes_are_identical_on_both_backends(monkeypatch, cfg, policy):
    _assert_backends_agree(monkeypatch, cfg, policy, seed=17)


@st.composite
def _drawn_configs(draw):
    """MapSync arguments across what the twins branch on: teams past numpy's 8-way unrolled sums, maps of 4 to 256
    cells (not multiples of 64), narrow and unlimited links, links that break, changing worlds, k and res."""
    cfg = {
        "n_robots": draw(st.integers(2, 10)),
        "grid_size": draw(st.integers(2, 16)),
        "k": draw(st.integers(1, 12)),
        "res": draw(st.sampled_from([1, 4, 16])),
        "bits_per_step": draw(st.sampled_from([None, None, 40, 300])),
        "appear_rate": draw(st.sampled_from([0.0, 0.01, 0.2])),
        "vanish_rate": draw(st.sampled_from([0.0, 0.05, 0.5])),
        "link_prob": draw(st.sampled_from([1.0, 0.6])),
        "comm_range": draw(st.sampled_from([None, 3.0])),
        "max_cycles": draw(st.integers(1, 25)),
    }
    cfg["n_obstacles"] = draw(st.integers(0, cfg["grid_size"] ** 2 - 1))
    return cfg


@settings(max_examples=25, deadline=None)
@given(cfg=_drawn_configs(), seed=st.integers(0, 2**16))
def test_whole_episodes_of_drawn_configurations_are_identical_on_both_backends(cfg, seed):
    """The fixed cases above, and drawn ones under random actions (25 per run, the same ones in ``make test``)."""
    with pytest.MonkeyPatch.context() as monkeypatch:
        _assert_backends_agree(monkeypatch, cfg, "random", seed)


def _assert_backends_agree(monkeypatch, cfg, policy, seed):
    """One seeded episode of ``cfg`` under the baseline ``policy`` with the numpy protocols and the numpy oracles of
    the env's kernels (``ReferenceMapSync``), and one compiled: every observation, reward, info and stamp, the
    metrics, detections, maps, world, bits and the generator's final state are the same."""

    def episode(compiled):
        _use_compiled_bisection(monkeypatch, compiled)
        env = (MapSyncEnv if compiled else ReferenceMapSync)(**cfg)
        pol = make_policy("MapSync-v0", policy)
        views = env.local_views()
        obs, infos = env.reset(seed=seed)
        pol.reset(views, seed)
        trace = [(obs, infos)]
        while env.agents:
            obs, rewards, _, _, infos = env.step(pol.act(obs, views))
            trace.append((obs, rewards, infos, env.stamps.copy()))
        world = (env.maps.copy(), env.truth.copy())
        return (
            trace,
            env.metrics(),
            env.detections,
            world,
            env.ledger.total_bits.tolist(),
            env.np_random.bit_generator.state,
        )

    numpy_run, compiled_run = episode(False), episode(True)
    for numpy_step, compiled_step in zip(numpy_run[0], compiled_run[0], strict=True):
        for a, b in zip(numpy_step, compiled_step):
            if isinstance(a, dict):
                assert a.keys() == b.keys()
                assert all(np.array_equal(a[key], b[key]) for key in a)
            else:
                assert np.array_equal(a, b)
    assert numpy_run[1].keys() == compiled_run[1].keys()
    same = lambda a, b: a == b or (math.isnan(a) and math.isnan(b))  # noqa: E731  (nan: e.g. no sync completed)
    assert all(same(numpy_run[1][k], compiled_run[1][k]) for k in numpy_run[1]), (numpy_run[1], compiled_run[1])
    assert numpy_run[2] == compiled_run[2] and numpy_run[4:] == compiled_run[4:]
    assert all(np.array_equal(a, b) for a, b in zip(numpy_run[3], compiled_run[3]))


@pytest.mark.parametrize(
    "cfg",
    [
        {},
        {"n_robots": 3, "bits_per_step": 50},
        {"appear_rate": 0.01, "vanish_rate": 0.05},
        {"n_robots": 4, "comm_range": 5.0, "link_prob": 0.7, "bits_per_step": 30},
    ],
)
def test_cached_infos_and_tracked_maximum_equal_a_full_recompute(cfg):
    """The infos are made anew only when something they show changed, and the recent bits' maximum is tracked without
    a reduction on most steps: both equal what a full recompute gives at every step."""
    env = MapSyncEnv(**cfg)
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    steps = 0
    while env.agents:
        actions = {a: int(rng.integers(1, 5)) if rng.random() < 0.05 else IDLE for a in env.agents}
        _, _, _, _, infos = env.step(actions)
        if not env.agents:
            break
        steps += 1
        assert env._recent_max == env.recent_bits.max()
        env._infos_key = None  # forget the cache
        assert infos == env._infos()
    assert steps > 10


def test_stamps_past_two_to_the_31_steps_stay_step_numbers():
    """max_cycles reaches 2^53: a stamp (the step a cell was sensed) must not wrap or overflow at step 2^31."""
    env = MapSyncEnv(max_cycles=2**40)
    env.reset(seed=0)
    env.step_count = 2**31 + 5  # as if the episode had run that long
    env.step({agent: IDLE for agent in env.agents})
    assert env.stamps.max() == 2**31 + 6
