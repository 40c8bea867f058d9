"""mrcomm/ChannelAssociation-v0 keeps every promise of its argument ranges (issue 11).

Every value inside a `Param` range either runs — finite observations in [0, 1], finite rewards and
metrics, no RuntimeWarning — or is rejected at construction with a ValueError naming the argument.
The documented maxima (``limits.documented_maxima``) are built and stepped; the i-state budget that
decides which large fields are accepted is checked against a brute-force count of robots in range.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mrcomm_env.channel_association.env import ChannelAssociationEnv
from mrcomm_env.channel_association.limits import FOOTPRINT_BUDGET, field_footprint
from mrcomm_env.core.config import Int, Real

PARAMS = ChannelAssociationEnv.PARAMS
SLOW_MAXIMA = {"largest_field", "largest_stationary_field"}


def run_checked(env: ChannelAssociationEnv, steps: int, seed: int = 0, all_emit_first: bool = False) -> None:
    """Reset and step with coin flips, asserting what every step must give; RuntimeWarnings fail."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for t in range(steps):
            if not env.agents:
                break
            p = 1.0 if (all_emit_first and t == 0) else 0.5
            acts = dict(zip(env.agents, (rng.random(len(env.agents)) < p).astype(int).tolist(), strict=True))
            obs, rewards, *_ = env.step(acts)
            block = np.stack(list(obs.values()))
            assert block.dtype == np.float32 and np.isfinite(block).all()
            assert (block >= 0.0).all() and (block <= 1.0).all()
            assert all(math.isfinite(r) for r in rewards.values())
        metrics = env.metrics()
    assert all(math.isfinite(v) for v in metrics.values()), metrics
    assert 0.0 <= metrics["fraction_matched"] <= 1.0 and 0.0 <= metrics["fraction_wrong"] <= 1.0


# ----------------------------------------------------------------------------- documented maxima
@pytest.mark.parametrize(
    "name",
    [pytest.param(k, marks=pytest.mark.slow) if k in SLOW_MAXIMA else k for k in ChannelAssociationEnv.LIMIT_CONFIGS],
)
def test_documented_maximum_runs(name):
    kwargs = ChannelAssociationEnv.LIMIT_CONFIGS[name]
    env = ChannelAssociationEnv(**kwargs)
    for key, value in kwargs.items():  # the maxima are inside the documented ranges
        assert PARAMS[key].check(key, value) == value
    run_checked(env, steps=3, all_emit_first=True)


def test_documented_maxima_sit_on_the_range_edges():
    maxima = ChannelAssociationEnv.LIMIT_CONFIGS
    assert maxima["largest_field"]["n_robots"] == PARAMS["n_robots"].check.hi
    assert maxima["largest_neighborhood"]["w"] == PARAMS["w"].check.hi == maxima["largest_neighborhood"]["v"]
    for key in ("n_robots", "w", "v", "drop_time", "max_cycles"):
        with pytest.raises(ValueError, match=key):
            ChannelAssociationEnv(**{key: PARAMS[key].check.hi + 1})


# ----------------------------------------------------------------------------- the i-state budget
def robots_in_range(positions: np.ndarray, radius: float) -> np.ndarray:
    """Brute force: per robot, how many others are within ``radius``."""
    d = np.linalg.norm(positions[:, None, :] - positions[None, :, :], axis=2)
    return (d <= radius).sum(1) - 1


@pytest.mark.parametrize(
    "n,separation,wireless,visual", [(400, 4.0, 16.0, 16.0), (900, 3.0, 14.0, 8.0), (300, 6.0, 30.0, 12.0)]
)
def test_footprint_estimate_bounds_the_stationary_istate(n, separation, wireless, visual):
    # Algorithm 1 starts a stationary field with every wireless × visual pair in range: Σ_o k_w(o)·k_v(o)
    env = ChannelAssociationEnv(
        n_robots=n, separation=separation, wireless_range=wireless, visual_range=visual, mobile_fraction=0.0
    )
    est = field_footprint(n, separation, 0.0, 0.0, wireless, visual, 20)
    for seed in range(3):
        env.reset(seed=seed)
        k_w = robots_in_range(env.positions, wireless)
        k_v = robots_in_range(env.positions, visual)
        edges = int(env.filter.stats()[2].sum())
        assert edges == int((k_w * k_v).sum())
        assert edges <= est["edges"]  # boundary robots have fewer neighbours
        # …but not by much: the estimate is the bulk density's disk count (§5.3), not a loose bound
        assert edges >= 0.5 * est["edges"]


def test_fields_beyond_the_budget_are_rejected_at_construction():
    hi = PARAMS["n_robots"].check.hi
    for kwargs in (
        {"n_robots": hi, "wireless_range": 1e6, "visual_range": 1e6},
        {"n_robots": hi, "separation": 1.0},
        {"n_robots": 5000, "wireless_range": 200.0, "visual_range": 200.0},
    ):
        est = field_footprint(
            kwargs["n_robots"],
            kwargs.get("separation", 4.0),
            0.1,
            1.4,
            kwargs.get("wireless_range", 16.0),
            kwargs.get("visual_range", 16.0),
            20,
        )
        assert est["edges"] > FOOTPRINT_BUDGET
        with pytest.raises(ValueError, match="n_robots"):
            ChannelAssociationEnv(**kwargs)
    # slot-per-robot fields (≤ 64 robots) hold at most 64³ cells whatever the ranges: always accepted
    ChannelAssociationEnv(n_robots=ChannelAssociationEnv.DENSE_MAX_N, wireless_range=1e6, visual_range=1e6)


# ----------------------------------------------------------------------------- fast robots bounce
def test_robots_faster_than_the_arena_stay_inside_it():
    env = ChannelAssociationEnv(n_robots=30, mobile_fraction=1.0, speed=1e4, separation=1.0)
    env.reset(seed=2)
    for _ in range(5):
        env.step(dict.fromkeys(env.agents, 1))
        assert (env.positions >= 0.0).all() and (env.positions <= env.size).all()
    # speed is kept: a bounce only flips the sign of a velocity component
    assert np.allclose(np.hypot(*env.vel.T), 1e4)


# ----------------------------------------------------------------------------- every range edge
def edges_of(name: str) -> list:
    """The smallest and largest allowed values of a numeric range and their neighbours inside it."""
    check = PARAMS[name].check
    if isinstance(check, Int):
        lo, hi = check.lo, check.hi
        if name == "n_robots":  # the top is run by test_documented_maximum_runs
            hi = ChannelAssociationEnv.DENSE_MAX_N + 1
        return sorted({lo, lo + 1, hi - 1, hi})
    assert isinstance(check, Real)
    lo = float(np.nextafter(check.lo, np.inf)) if check.lo_open else check.lo
    hi = float(np.nextafter(check.hi, -np.inf)) if check.hi_open else check.hi
    return sorted(
        {lo, float(np.nextafter(lo, np.inf)), 1e-300 if lo < 1e-300 else lo, hi, float(np.nextafter(hi, -np.inf))}
    )


NUMERIC = [k for k, p in PARAMS.items() if isinstance(p.check, (Int, Real))]


@st.composite
def edge_configs(draw):
    """A few arguments at the edges of their ranges, the rest at their fuzz ranges or defaults."""
    kwargs = {"scene": draw(st.sampled_from(("neighborhood", "field")))}
    for name in draw(st.lists(st.sampled_from(NUMERIC), min_size=1, max_size=5, unique=True)):
        kwargs[name] = draw(st.sampled_from(edges_of(name)))
    kwargs["max_cycles"] = kwargs.get("max_cycles", 8)
    return kwargs


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(edge_configs(), st.integers(0, 2**16))
def test_range_edges_run_or_are_rejected_at_construction(kwargs, seed):
    try:
        env = ChannelAssociationEnv(**kwargs)
    except ValueError as exc:
        # only the cross-argument rules may reject values inside the ranges: v ≤ w, visual ≤ wireless
        # range (Property 2) and the i-state budget
        assert any(f"'{name}'" in str(exc) for name in ("v", "visual_range", "n_robots")), exc
        return
    run_checked(env, steps=6, seed=seed)
