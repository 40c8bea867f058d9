"""The shared comm model and config validation, checked against brute force and probability theory."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.numerics import assert_close_conditioned, tolerance
from scipy import stats

from mrcomm_env.core import (
    BitLedger,
    Choice,
    Int,
    ListOf,
    Optional,
    Param,
    Real,
    TDMASchedule,
    apply_packet_loss,
    bernoulli_links,
    combined_links,
    disk_links,
    disk_pairs,
    fit_to_budget,
    grid_links,
    mean_ci95,
    validate_config,
)


def test_bernoulli_links_symmetric_and_rate_matches_p():
    rng = np.random.default_rng(0)
    n, p, trials = 12, 0.3, 400
    ups = 0
    for _ in range(trials):
        adj = bernoulli_links(rng, n, p)
        assert np.array_equal(adj, adj.T) and not adj.diagonal().any()
        ups += np.triu(adj, 1).sum()
    pairs = trials * n * (n - 1) // 2
    # two-sided binomial test at 1e-4: a wrong rate (e.g. p² or 2p) fails by many sigmas
    assert stats.binomtest(int(ups), pairs, p).pvalue > 1e-4


@pytest.mark.parametrize("n", [5, 40, 300])
def test_disk_links_match_brute_force(n):
    rng = np.random.default_rng(n)
    pos = rng.uniform(0, 10, size=(n, 2))
    r = 2.5
    brute = np.array([[i != j and math.dist(pos[i], pos[j]) <= r for j in range(n)] for i in range(n)])
    assert np.array_equal(disk_links(pos, r), brute)
    pairs = disk_pairs(pos, r)
    assert len(pairs) == brute.sum() // 2


def test_grid_links_degrees():
    adj = grid_links(10)
    deg = adj.sum(1).reshape(10, 10)
    assert deg[0, 0] == 2 and deg[0, 5] == 3 and deg[5, 5] == 4
    assert np.array_equal(adj, adj.T) and adj.sum() == 2 * (2 * 10 * 9)
    assert adj[0, 1] and adj[0, 10] and not adj[0, 11]


def test_combined_links_are_intersection():
    rng = np.random.default_rng(1)
    pos = rng.uniform(0, 5, size=(30, 2))
    adj = combined_links(np.random.default_rng(2), pos, 1.5, 0.5)
    assert not (adj & ~disk_links(pos, 1.5)).any()
    assert np.array_equal(adj, disk_links(pos, 1.5) & bernoulli_links(np.random.default_rng(2), 30, 0.5))


def test_packet_loss_drops_directed_deliveries_at_rate():
    rng = np.random.default_rng(3)
    full = ~np.eye(50, dtype=bool)
    kept = apply_packet_loss(rng, full, 0.2)
    assert not (kept & ~full).any()
    assert stats.binomtest(int(kept.sum()), int(full.sum()), 0.8).pvalue > 1e-4
    assert apply_packet_loss(rng, full, 0.0) is full


def test_tdma_each_robot_once_per_frame():
    sched = TDMASchedule(7, np.random.default_rng(4))
    frame = [sched.owner(s) for s in range(7)]
    assert sorted(frame) == list(range(7))
    assert [sched.owner(s) for s in range(7, 14)] == frame
    assert all(sched.slot_of[sched.owner(s)] == s for s in range(7))


def test_fit_to_budget_takes_prefix_that_fits():
    sizes = np.array([100, 50, 200, 10])
    assert fit_to_budget(sizes, None) == 4
    assert fit_to_budget(sizes, 149) == 1
    assert fit_to_budget(sizes, 150) == 2
    assert fit_to_budget(sizes, 10_000) == 4
    assert fit_to_budget(sizes, 0) == 0


def test_bit_ledger_accumulates_exactly():
    ledger = BitLedger(3)
    ledger.begin_step()
    ledger.add(np.array([0, 2, 0]), np.array([10.0, 5.0, 1.0]), messages=3)
    assert ledger.step_bits.tolist() == [11.0, 0.0, 5.0]
    ledger.begin_step()
    ledger.add(1, 7.0)
    assert ledger.step_bits.tolist() == [0.0, 7.0, 0.0]
    assert ledger.total_bits.tolist() == [11.0, 7.0, 5.0] and ledger.messages == 4
    ledger.record(np.array([1.0, 2.0, 3.0]), messages=2)  # a whole step at once replaces the step's bits
    assert ledger.step_bits.tolist() == [1.0, 2.0, 3.0]
    assert ledger.total_bits.tolist() == [12.0, 9.0, 8.0] and ledger.messages == 6


def test_validators_name_argument_and_range():
    params = {
        "n": Param(3, "count", Int(2, 10)),
        "p": Param(0.5, "prob", Real(0, 1)),
        "r": Param(1.0, "radius", Real(0, None, lo_open=True, allow_inf=True)),
        "mode": Param("a", "mode", Choice(("a", "b"))),
        "budget": Param(None, "bits", Optional(Int(1))),
        "modes": Param(("a",), "modes", ListOf(Choice(("a", "b")))),
    }
    cfg = validate_config(params, {"r": "inf", "budget": 64, "modes": ["b", "a"]})
    assert cfg.n == 3 and cfg.r == math.inf and cfg.budget == 64 and cfg.modes == ("b", "a")
    for bad, match in [
        ({"n": 1}, r"'n' must be an integer in \[2, 10\]"),
        ({"p": 1.5}, r"'p' must be a number in \[0, 1\]"),
        ({"r": 0.0}, r"'r'"),
        ({"mode": "c"}, r"'mode' must be one of 'a', 'b'"),
        ({"budget": 0}, r"'budget'"),
        ({"modes": ["a", "a"]}, r"'modes'"),
        ({"modes": ["z"]}, r"'modes'"),
        ({"bogus": 1}, r"unknown argument.*'bogus'.*valid arguments are: budget, mode, modes, n, p, r"),
    ]:
        with pytest.raises(ValueError, match=match):
            validate_config(params, bad)


def test_mean_ci95_matches_t_interval():
    x = [1.0, 2.0, 3.0, 4.0]
    mean, half = mean_ci95(x)
    lo, hi = stats.t.interval(0.95, 3, loc=2.5, scale=stats.sem(x))
    # scipy's (hi − lo)/2 subtracts two numbers of size |mean| + half; the t quantile on either side is a special
    # function good to some tens of ulps: ~32 roundings of |mean| + half between the two computations
    assert mean == 2.5
    assert_close_conditioned(half, (hi - lo) / 2, tolerance(2.5 + half, 32), err_msg="CI half-width")
    assert mean_ci95([5.0]) == (5.0, 0.0)


def test_local_views_are_read_only_and_follow_every_step_and_reset():
    import mrcomm_env

    env = mrcomm_env.make("MultiHop-v0", grid_side=3, slot_size=3, max_cycles=4)
    env.reset(seed=0)
    views = env.local_views()
    before = views.team("stamps").copy()
    with pytest.raises(ValueError):
        views.team("stamps")[0, 0] = 1.0  # read-only: a policy cannot write into the env
    env.step({a: np.ones(8, dtype=np.int8) for a in env.agents})
    after = views.team("stamps")
    assert not np.array_equal(before, after), "the view kept the state of the previous step"
    np.testing.assert_array_equal(after, env.stamps)
    env.reset(seed=1)
    np.testing.assert_array_equal(views.team("stamps"), env.stamps)
    assert views["robot_2"]["slot"] == env.tdma.slot_of[2]


def test_iqm_is_the_quarter_trimmed_mean_with_a_reproducible_bootstrap_interval():
    from mrcomm_env.experiments.comparison import iqm_ci95

    # 5 runs: a quarter of 5 rounds down to 1 run cut at each end, so the IQM is the mean of 2, 3, 4 = 3, and the
    # outlier 100 moves it not at all
    iqm, low, high = iqm_ci95([4.0, 1.0, 100.0, 3.0, 2.0])
    assert iqm == 3.0
    assert 1.0 <= low <= iqm <= high <= 100.0
    assert iqm_ci95([4.0, 1.0, 100.0, 3.0, 2.0]) == (iqm, low, high)  # seeded: the page is the same on a rerun
    # 3 runs: nothing is cut, the IQM is the mean; equal runs have a zero-width interval; NaNs are ignored
    assert iqm_ci95([1.0, 2.0, 6.0])[0] == 3.0
    assert iqm_ci95([5.0, 5.0, float("nan")]) == (5.0, 5.0, 5.0)
