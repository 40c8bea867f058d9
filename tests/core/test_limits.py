"""Every documented limit runs: each env at its documented maxima, and the values that used to crash or give NaN.

An env class lists configurations at its documented maxima in ``LIMIT_CONFIGS`` (the hook
``mrcomm_env.experiments.limits`` reads); each runs a few steps in a fresh process with finite outputs and a
peak resident memory within a budget that leaves room for the other processes of the 24 GiB CI machine.
"""

from __future__ import annotations

import math
import subprocess
import sys
import warnings

import numpy as np
import pytest
from helpers.numerics import tolerance

import mrcomm_env
from mrcomm_env.core.config import Int, Optional
from mrcomm_env.experiments.limits import limit_configs, measure_limit
from mrcomm_env.multihop import protocol as proto
from mrcomm_env.multihop.env import AGE_SCALE_FRAMES
from mrcomm_env.registry import env_class, env_ids

#: a sixth of the CI machine's 24 GiB: one env at its largest documented size next to a full test run
MEMORY_BUDGET_MB = 4096.0

LIMIT_CASES = [
    pytest.param(env_id, name, id=f"{env_id.split('/')[1]}[{name}]")
    for env_id in env_ids()
    for name in limit_configs(env_id)
]


def _int_upper_bound(validator):
    inner = validator.inner if isinstance(validator, Optional) else validator
    return inner.hi if isinstance(inner, Int) else None


@pytest.mark.slow
@pytest.mark.parametrize(("env_id", "name"), LIMIT_CASES)
def test_documented_maximum_runs_in_bounded_memory(env_id, name):
    result = measure_limit(env_id, limit_configs(env_id)[name], seconds=0.0, min_steps=3, timeout=600)
    assert result["steps"] == 3
    assert result["finite"], f"{name}: a non-finite observation, reward or info"
    assert result["peak_rss_mb"] < MEMORY_BUDGET_MB, result


def test_the_measured_peak_is_the_measuring_process_own_not_its_parents():
    """Linux carries ``ru_maxrss`` over ``exec``: a child of a large process used to report the parent's size."""
    from mrcomm_env.experiments.limits import measure_batched

    held_mb = 1024
    ballast = np.ones(held_mb * 2**20 // 8)  # resident in this (the parent) process while the children run
    config = {"max_cycles": 2}
    limit = measure_limit("MapSync-v0", config, seconds=0.0, min_steps=1, timeout=300)
    batched = measure_batched("MapSync-v0", config, 2, seconds=0.0, min_steps=1, timeout=300)
    assert float(ballast.sum()) == len(ballast)  # still held
    # an env of 2 MiB and the interpreter with numpy, scipy and numba: a few hundred MB at most
    assert 0 < limit["peak_rss_mb"] < held_mb / 2 and 0 < batched["peak_rss_mb"] < held_mb / 2
    assert batched["rss_before_mb"] <= batched["peak_rss_mb"]


def test_a_measured_batch_says_whether_it_stepped_as_one_copy_axis_world():
    from mrcomm_env.experiments.limits import measure_batched

    config = {"grid_side": 3, "max_cycles": 3}
    assert measure_batched("MultiHop-v0", config, 2, seconds=0.0, min_steps=1, timeout=300)["copy_axis_world"]
    assert not measure_batched("MultiHop-v0", config, 1, seconds=0.0, min_steps=1, timeout=300)["copy_axis_world"]


@pytest.mark.parametrize("env_id", env_ids())
def test_every_documented_size_limit_is_exercised(env_id):
    """Integer upper bounds (team sizes, histories, slot sizes) are what cost memory and time: each one must
    appear at its maximum in some limit configuration, which must itself be a valid configuration."""
    params = env_class(env_id).PARAMS
    configs = limit_configs(env_id)
    assert configs, f"{env_id} lists no LIMIT_CONFIGS"
    for cfg in configs.values():
        mrcomm_env.make(env_id, **cfg)  # construction validates every argument and every combination
    for arg, spec in params.items():
        hi = _int_upper_bound(spec.check)
        if hi is not None:
            assert any(cfg.get(arg) == hi or _implied(env_id, arg, cfg) == hi for cfg in configs.values()), (
                f"{arg} = {hi} is documented but no LIMIT_CONFIGS entry runs it"
            )


def _implied(env_id, arg, cfg):
    """MultiHop's grid scene derives n_robots from grid_side when it is not given."""
    if arg == "n_robots" and cfg.get("scene", "grid") == "grid" and "grid_side" in cfg and "n_robots" not in cfg:
        return cfg["grid_side"] ** 2
    return None


# ------------------------------------------------------------------------------------------ constrained combinations
def test_asynccl_estimation_limits_team_size_naming_both_arguments():
    from mrcomm_env.asynccl.env import MAX_ROBOTS, MAX_ROBOTS_ESTIMATING

    mrcomm_env.make("AsyncCL-v0", n_robots=MAX_ROBOTS_ESTIMATING)
    mrcomm_env.make("AsyncCL-v0", n_robots=MAX_ROBOTS, estimation=False)
    with pytest.raises(ValueError, match="'n_robots'.*'estimation'"):
        mrcomm_env.make("AsyncCL-v0", n_robots=MAX_ROBOTS_ESTIMATING + 1)


def test_multihop_coverage_limits_team_size_naming_both_arguments():
    from mrcomm_env.multihop.env import MAX_COVERAGE_ROBOTS

    mrcomm_env.make("MultiHop-v0", scene="coverage", n_robots=MAX_COVERAGE_ROBOTS)
    mrcomm_env.make("MultiHop-v0", scene="field", n_robots=MAX_COVERAGE_ROBOTS + 1)
    with pytest.raises(ValueError, match="'n_robots'.*'scene'"):
        mrcomm_env.make("MultiHop-v0", scene="coverage", n_robots=MAX_COVERAGE_ROBOTS + 1)


# ------------------------------------------------------------------------------------------ values that crashed
@pytest.mark.parametrize(
    ("env_id", "kwargs", "argument"),
    [
        ("AsyncCL-v0", {"initial_sigma": 1e-50}, "initial_sigma"),  # was a LinAlgError
        ("AsyncCL-v0", {"modes": ["scheme2_q" + "9" * 25]}, "modes"),  # was an OverflowError
        ("AsyncCL-v0", {"modes": ["scheme2_q²"]}, "modes"),  # str.isdigit() accepts it, int() does not
        ("AsyncCL-v0", {"lam": 1e308}, "lam"),  # was −inf rewards
        ("MultiHop-v0", {"baud": 1e-308}, "baud"),  # was NaN observations (infinite slots)
        ("MultiHop-v0", {"scene": "field", "arena_size": 1e308}, "arena_size"),  # was NaN (squared distances)
        ("MultiHop-v0", {"bits_per_estimate": 10**400}, "bits_per_estimate"),  # int too large for a float
        ("MultiHop-v0", {"alpha": 1e308}, "alpha"),
        ("MapSync-v0", {"res": 1e300}, "res"),  # was a numba TypingError inside the compiled kernel
        ("MapSync-v0", {"lam": 1e306}, "lam"),  # was a NaN (or −inf) episode_return
        ("MapSync-v0", {"max_cycles": 2**63}, "max_cycles"),  # was NaN observations or an IndexError
    ],
)
def test_values_that_crashed_are_rejected_at_construction(env_id, kwargs, argument):
    with pytest.raises(ValueError, match=f"'{argument}'"):
        mrcomm_env.make(env_id, **kwargs)


def _run(env_id, steps, **kwargs):
    env = mrcomm_env.make(env_id, max_cycles=steps, **kwargs)
    env.reset(seed=4)
    space = env.action_space("robot_0")
    space.seed(4)
    rewards = []
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        while env.agents:
            obs, rew, _, _, infos = env.step({a: space.sample() for a in env.agents})
            assert np.all(np.isfinite(np.stack(list(obs.values()))))
            assert all(math.isfinite(v) for info in infos.values() for v in info.values())
            rewards.append(next(iter(rew.values())))
    return env, rewards


def test_multihop_field_with_steep_importance_in_a_small_arena_stays_finite():
    # d^-200 at the 1 mm clamp overflowed to inf and the weighted reward became inf/inf = NaN
    env, rewards = _run("MultiHop-v0", 4, scene="field", alpha=200.0, n_robots=50, arena_size=1.0)
    assert all(math.isfinite(r) and r < 0.0 for r in rewards)


def test_multihop_coverage_reward_at_steep_importance_is_the_nearest_pairs_age():
    """At α = 300, d^-α underflowed to 0 for every pair and the reward was −0.0 every step. Eq. (1)'s weighted
    mean of ages is then the mean age of the nearest pair's two estimates, up to the other pairs' weights."""
    alpha = 300.0
    env, rewards = _run("MultiHop-v0", 3, scene="coverage", alpha=alpha)
    pos, ages, n = env.pos, env.ages(), env.n_agents
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    d[np.eye(n, dtype=bool)] = np.inf
    i, j = np.unravel_index(np.argmin(d), d.shape)
    nearest = d[i, j]
    others = np.sort(d[np.isfinite(d)])[2:]  # every ordered pair but (i, j) and (j, i)
    rest = float(np.sum((np.maximum(others, proto.MIN_DIST) / max(nearest, proto.MIN_DIST)) ** -alpha))
    expected = (ages[i, j] + ages[j, i]) / 2.0
    # the other pairs' total weight, relative to the nearest pair's 2, can move the mean by at most this
    bound = rest / 2.0 * float(ages.max()) + 1e-12 * expected
    assert rewards[-1] < 0.0
    # the reward is the weighted age in units of AGE_SCALE_FRAMES frames (lam = 0): back to seconds
    weighted_age = -rewards[-1] * AGE_SCALE_FRAMES * env.frame_dur
    assert abs(weighted_age - expected) <= bound + tolerance(expected, 8)


def test_importance_is_eq1_scaled_per_row_and_finite_for_steep_alpha():
    rng = np.random.default_rng(3)
    dist = rng.uniform(0.5, 80.0, (4, 9))
    dist[np.arange(4), np.arange(4)] = 0.0  # own estimates
    known = rng.random((4, 9)) < 0.8
    known[np.arange(4), np.arange(4)] = True
    alpha = 1.3
    f = proto.importance(dist, known, alpha)
    raw = np.maximum(dist, proto.MIN_DIST) ** -alpha
    for b in range(4):
        others = known[b] & (dist[b] > 0)
        scale = raw[b][others].max()
        # log-then-exp loses about |α ln d| ulps: relative error ε · α · max|ln d|
        tol = 8 * np.finfo(float).eps * alpha * np.abs(np.log(np.maximum(dist[b], proto.MIN_DIST))).max()
        np.testing.assert_allclose(f[b][others], raw[b][others] / scale, rtol=tol)
        assert np.all(f[b][~known[b]] == 0.0)
    steep = proto.importance(dist, known, 1000.0)
    assert np.all(np.isfinite(steep))
    for b in range(4):
        others = known[b] & (dist[b] > 0)
        assert steep[b][others].max() == 1.0  # the nearest other robot, not 0 as raw d^-1000 would give


def test_asynccl_at_the_noise_floor_prior_runs():
    from mrcomm_env.asynccl.env import SIGMA_FLOOR

    _, rewards = _run(
        "AsyncCL-v0", 20, initial_sigma=SIGMA_FLOOR, sigma_v=0.0, sigma_d=0.0, sigma_omega_deg=0.0, sigma_theta_deg=0.0
    )
    assert all(math.isfinite(r) for r in rewards)


# ------------------------------------------------------------------------------------------ AsyncCL budget at scale
def _truncate_packet_by_packet(tables, lo, hi, gain, header, budget):
    """The budget rule spelled out: per link, header first, then the offered packets in (column, row id)
    order while the running total fits; a link whose header alone does not fit sends nothing."""
    W = tables.W
    new_hi, sent = lo.copy(), np.zeros(len(lo))
    for e in range(len(lo)):
        room = budget - header[e]
        if room < 0:
            continue
        packets = sorted((k, v) for v in np.flatnonzero(gain[e]) for k in range(lo[e, v] + 1, hi[e, v] + 1))
        total = 0.0
        for k, v in packets:
            size = tables.pkt_bits[v, (k + 1) % W]
            if total + size > room:
                break
            total += size
            new_hi[e, v] = k
        sent[e] = header[e] + total
    return new_hi, sent


def test_asynccl_vectorised_budget_truncation_is_the_packet_by_packet_rule():
    from mrcomm_env.asynccl.table import QINF, SCHEME1, SILENT, InfoTables
    from mrcomm_env.core.comm import apply_packet_loss, bernoulli_links

    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(6):
        n, hist = int(rng.integers(2, 9)), int(rng.integers(4, 25))
        tables = InfoTables(n, hist, "paper")
        tables.reset(rng.integers(100, 400, n).astype(float))
        for step in range(40):
            modes = rng.choice(np.array([SILENT, SCHEME1, 1, 3, QINF]), n)
            adj = bernoulli_links(rng, n, 0.15 if step % 5 else 0.9)  # long silences, then bursts to truncate
            sending = modes != SILENT
            recv, send = np.nonzero((adj & sending[:, None]).T)
            if recv.size:
                lo = tables.latest[recv]
                hi = tables._offers(modes)[send]
                header = rng.integers(50, 300, recv.size).astype(float)  # bit counts: integers
                budget = float(rng.choice([100.0, 400.0, 1500.0, 6000.0]))
                got_hi, got_gain, got_sent = tables._truncate(recv, send, lo, hi, hi > lo, header, budget)
                want_hi, want_sent = _truncate_packet_by_packet(tables, lo, hi, hi > lo, header, budget)
                np.testing.assert_array_equal(got_hi, want_hi)
                np.testing.assert_array_equal(got_gain, want_hi > lo)
                np.testing.assert_array_equal(got_sent, want_sent)  # integer bits: sums are exact
                checked += int((want_hi < np.where(hi > lo, hi, lo)).any())
            tables.exchange(modes, adj, apply_packet_loss(rng, adj, 0.1), 2000.0)
            tables.new_step(rng.integers(100, 400, n).astype(float))
    assert checked > 20  # many links were actually cut by the budget


@pytest.mark.parametrize(
    ("env_id", "argument", "value"),
    [("MapSync-v0", "res", "1e300"), ("MapSync-v0", "lam", "1e306"), ("MapSync-v0", "max_cycles", str(2**63))],
)
def test_the_cli_refuses_values_that_crashed_in_one_line(env_id, argument, value):
    proc = subprocess.run(
        [sys.executable, "-m", "mrcomm_env.experiments.cli", "evaluate", env_id, "--episodes", "1"]
        + ["--policy", "periodic_equality_then_bisection", "--param", f"{argument}={value}"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and f"'{argument}'" in lines[0] and "Traceback" not in proc.stderr, proc.stderr


@pytest.mark.parametrize("warmup_steps", [-1, 1.5, True])
def test_a_warm_up_that_is_no_count_of_steps_is_refused_naming_it(warmup_steps):
    with pytest.raises(ValueError, match="argument 'warmup_steps' must be an integer ≥ 0"):
        measure_limit("MapSync-v0", {}, seconds=0.0, min_steps=1, warmup_steps=warmup_steps)
