"""RendezvousMapping's Figs 8–10 in the paper's own setup (paper 004, §VI-B): the spread start, C on the map the
vehicles plan with, the loitering the text asks for at C = 0, and the verdicts with bootstrap intervals."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from mrcomm_env.experiments.reproductions import rendezvous_mapping as rv
from mrcomm_env.rendezvous import world
from mrcomm_env.rendezvous.env import RendezvousMappingEnv


def test_vehicles_start_at_one_point_by_default_and_spread_around_it_with_start_spread():
    together = RendezvousMappingEnv(max_cycles=2)
    together.reset(seed=3)
    positions = np.array(together.local_views().team("position"))
    assert np.all(positions == positions[0])
    spread = 12.0
    # a large area, so that reflection at the borders barely narrows the spread
    env = RendezvousMappingEnv(max_cycles=2, area=1e6, n_landmarks=20, start_spread=spread)
    offsets = []
    for seed in range(200):
        env.reset(seed=seed)
        positions = np.array(env.local_views().team("position"))
        assert np.all((positions >= 0) & (positions <= env.side))
        offsets.append(positions - positions.mean(axis=0))
    offsets = np.concatenate(offsets)
    # deviations from the team's own mean have variance σ²(n−1)/n; 4,000 of them pin the std to about 1.1 %
    n = env.cfg.n_vehicles
    measured = float(np.sqrt((offsets**2).mean()))
    assert measured == pytest.approx(spread * math.sqrt((n - 1) / n), rel=0.06)


def test_the_default_start_draws_nothing_more():
    # start_spread = 0 keeps every draw of the episode: the same landmarks, prior map and launch point as passing
    # nothing, and a spread start changes only where the vehicles stand
    a, b = RendezvousMappingEnv(max_cycles=3), RendezvousMappingEnv(max_cycles=3, start_spread=8.0)
    a.reset(seed=11)
    b.reset(seed=11)
    assert np.array_equal(a.landmarks, b.landmarks) and np.array_equal(a.prior_mean, b.prior_mean)
    assert not np.array_equal(np.array(a.local_views().team("position")), np.array(b.local_views().team("position")))


def test_the_grid_has_c_zero_on_the_map_the_vehicles_plan_with_at_the_setups_prior_error():
    """64 landmarks 12.5 m apart, d_max = 15: the grid's neighbours along rows and columns are linked, its
    diagonals (17.7 m) are not, so no triangle. A prior error σ₀ = 0.5 m moves a diagonal by far less than the
    2.7 m that would link it; σ₀ = 5 m links many, and the map the vehicles plan with has C > 0."""
    kwargs = dict(rv.SETUP, sigma=0.0, d_comms=math.inf, t_window=15.0, max_cycles=2)
    assert world.grid_shape(kwargs["n_landmarks"]) == (8, 8)
    for seed in range(5):
        env = RendezvousMappingEnv(**kwargs)
        env.reset(seed=seed)
        assert env.clustering(env.d_max) == 0.0 and env.planned_clustering(env.d_max) == 0.0
    noisy = []
    for seed in range(5):
        env = RendezvousMappingEnv(**{**kwargs, "prior_sigma": 5.0})
        env.reset(seed=seed)
        assert env.clustering(env.d_max) == 0.0
        noisy.append(env.planned_clustering(env.d_max))
    assert min(noisy) > 0.1
    # with an exact prior the two layouts are one
    env = RendezvousMappingEnv(**{**kwargs, "prior_sigma": 1e-3, "sigma": 6.0})
    env.reset(seed=0)
    assert env.planned_clustering(15.0) == pytest.approx(env.clustering(15.0), abs=0.02)


def test_vehicles_loiter_at_c_zero_in_the_setup():
    """§VI-B.2: “the vehicles are loitering even when C = 0”: on the grid, windows in which a vehicle neither
    travels nor observes for part of the time, waiting for the next decision phase."""
    for budget in (rv.SETUP["obs_per_landmark"], 2):
        times: list[float] = []
        kwargs = {"d_comms": math.inf, "t_window": 15.0, **rv.SETUP, "obs_per_landmark": budget, "sigma": 0.0}
        env, _ = rv.episode_to_cap(kwargs, "paper_protocol", 1, 12, times)
        # one entry per vehicle and window until the fused map held half the information
        assert len(times) == env.cfg.n_vehicles * int(env.half_phase)
        times = np.array(times)
        assert np.all((times >= 0) & (times <= 15.0))
        assert np.mean(times >= 1.0) > 0.1, (budget, times)


def rows_of(phases_of_sigma, draws=20, seed=0, planners=("paper_protocol",)):
    """Synthetic sweep rows: C grows with σ, phases from ``phases_of_sigma(σ, C, rng)``."""
    rng = np.random.default_rng(seed)
    rows = []
    for sigma in (0.0, 1.0, 2.0, 3.0, 6.0, 12.0, 50.0):
        for draw in range(draws):
            c = min(0.55, sigma / 20) + 0.02 * rng.random()
            for planner in planners:
                rows.append(
                    {
                        "sigma": sigma,
                        "clumping": 0.0,
                        "draw": draw,
                        "planner": planner,
                        "C": c,
                        "phases_to_half": float(phases_of_sigma(sigma, c, rng)),
                    }
                )
    return rows


def test_a_verdict_holds_fails_or_is_inconclusive_by_where_its_interval_lies():
    rising = rows_of(lambda s, c, rng: 10 + 20 * c + rng.normal(0, 1))
    falling = rows_of(lambda s, c, rng: 30 - 20 * c + rng.normal(0, 1))
    noise = rows_of(lambda s, c, rng: 10 + rng.normal(0, 3), draws=6)
    verdicts = {}
    for name, rows in (("rising", rising), ("falling", falling), ("noise", noise)):
        interval = rv.bootstrap_interval(rows, rv.rho_of, seed=1, resamples=300)
        assert interval[1] <= interval[0] <= interval[2]
        verdicts[name] = rv.side_of(interval, 0.0, "above")
    assert verdicts == {"rising": "holds", "falling": "fails", "noise": "inconclusive"}
    assert rv.both("holds", "inconclusive") == "inconclusive" and rv.both("holds", "fails") == "fails"
    assert rv.both("holds", "holds") == "holds" and rv.both("holds", None) is None


def test_the_bootstrap_is_reproducible_and_resamples_draws_with_their_planners():
    rows = rows_of(lambda s, c, rng: 10 + 5 * c + rng.normal(0, 2), planners=("paper_protocol", "greedy"))
    first = rv.bootstrap_interval(rows, rv.rho_of, seed=4, resamples=200)
    assert rv.bootstrap_interval(rows, rv.rho_of, seed=4, resamples=200) == first
    seen = []

    def statistic(sample):
        seen.append(sample)
        return 0.0

    rv.bootstrap_interval(rows, statistic, seed=0, resamples=5)
    for sample in seen[1:]:  # the first call is the estimate on the rows themselves
        assert len(sample) == len(rows)
        planners_of = {}
        for r in sample:
            planners_of.setdefault((r["sigma"], r["draw"]), []).append(r["planner"])
        # a draw drawn k times brings both planners k times
        assert all(p.count("paper_protocol") == p.count("greedy") for p in planners_of.values())


def test_the_relative_drop_and_the_flat_change_measure_the_layout_medians():
    rows = rows_of(lambda s, c, rng: {0.0: 12, 1.0: 12, 2.0: 11, 3.0: 15, 6.0: 10, 12.0: 9, 50.0: 8}[s], draws=3)
    assert rv.relative_drop(rows) == pytest.approx(1 - 8 / 12)
    # the layouts with mean C < 0.3 are σ = 0 … 3 (C = σ/20 + at most 0.02) and σ = 6 (0.30–0.32) is not
    sigmas = rv.low_clustering_sigmas(rows)
    assert sigmas == [0.0, 1.0, 2.0, 3.0]
    assert rv.flat_change(rows, sigmas) == pytest.approx(15 / 12 - 1)
    assert rv.within((0.0, -0.1, 0.15), 0.2) == "holds" and rv.within((0.3, 0.25, 0.4), 0.2) == "fails"
    assert rv.within((0.1, -0.1, 0.3), 0.2) == "inconclusive"


def test_the_setup_table_names_every_setting_the_issue_lists():
    settings = " ".join(row[0] for row in rv.SETUP_TABLE)
    for name in ("landmark layouts", "σ values", "prior map error", "sensor budget", "start", "information", "borders"):
        assert name in settings, name
    for variant in rv.VARIANTS.values():
        assert set(variant) <= set(rv.SETUP)  # a variant flips a setting of the setup, never adds one


def test_the_report_carries_the_setup_the_verdicts_and_the_sensitivity(tmp_path):
    from mrcomm_env.experiments.cli import main

    out = tmp_path / "results"
    assert main(["reproduce", "RendezvousMapping-v0", "--tiny", "--workers", "1", "--out", str(out)]) == 0
    report = (out / "REPORT.md").read_text()
    for setting, ours, _paper in rv.SETUP_TABLE:
        assert f"| {setting} | {ours} |" in report, setting
    results = json.loads((out / "RendezvousMapping-v0" / "results.json").read_text())
    assert [c["key"] for c in results["claims"]] == [
        "fig8_less_efficient",
        "fig8_flat_to_0.3",
        "fig9_shines",
        "fig9_flat_to_0.3",
        "fig10_vastly",
    ]  # the tiny run has no no_partition runs in the main setup: Fig. 8's module statement is not testable
    assert set(results["sensitivity"]) == {"main", next(iter(rv.VARIANTS))}
    header = next(line for line in report.splitlines() if line.startswith("| statement |"))
    assert "main" in header and next(iter(rv.VARIANTS)) in header
    rows = list(csv.DictReader((out / "RendezvousMapping-v0" / "figs8_10_sweeps.csv").open()))
    assert {r["setup"] for r in rows} == {"main", next(iter(rv.VARIANTS))}
    assert all(float(r["idle_s"]) >= 0 and 0 <= float(r["C"]) <= 1 for r in rows)
