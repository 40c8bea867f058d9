"""Every environment knows its own peak memory (``memory_estimate``) and refuses arguments over its budget.

The estimate is held to the measured peak within a factor of 2 at three sizes per env (``MEMORY_PROBES``). The
peak is what Python and numpy allocate from construction through reset and a few steps (``tracemalloc`` in a
fresh process). Compiled kernels hold their state in arrays the env allocates in numpy; what they allocate inside a
call (RendezvousMapping's window: its legs and the observations it keeps, bounded by the team and the sensor floor)
``tracemalloc`` does not see, and their memory models say why it is small.
"""

from __future__ import annotations

import pytest

import mrcomm_env
from mrcomm_env.core.config import validate_config
from mrcomm_env.core.memory import BUDGET_ARGUMENT, DEFAULT_MEMORY_BUDGET_GIB, GIB
from mrcomm_env.experiments.limits import limit_configs, measure_limit
from mrcomm_env.registry import env_class, env_ids

PROBES = [
    pytest.param(env_id, name, id=f"{env_id.split('/')[1]}[{name}]")
    for env_id in env_ids()
    for name in env_class(env_id).MEMORY_PROBES
]


def _estimate(env_id, config):
    cls = env_class(env_id)
    return cls.memory_estimate(validate_config(cls.PARAMS, config))


@pytest.mark.parametrize("env_id", env_ids())
def test_every_env_states_its_memory(env_id):
    cls = env_class(env_id)
    assert cls.MEMORY_FORMULA and cls.MEMORY_ARGS, f"{env_id} states no memory formula"
    assert set(cls.MEMORY_ARGS) <= set(cls.PARAMS), "MEMORY_ARGS must name arguments"
    assert len(cls.MEMORY_PROBES) >= 3, f"{env_id} needs three sizes at which its estimate is measured"
    estimates = [_estimate(env_id, cfg) for cfg in cls.MEMORY_PROBES.values()]
    assert estimates == sorted(estimates), "the probes must grow"
    assert estimates[-1] >= 4 * estimates[0], "the probes must span a range of sizes"


@pytest.mark.slow
@pytest.mark.parametrize(("env_id", "name"), PROBES)
def test_estimate_within_a_factor_of_two_of_the_measured_peak(env_id, name):
    _assert_estimate_near_the_peak(env_id, env_class(env_id).MEMORY_PROBES[name])


def _assert_estimate_near_the_peak(env_id, config):
    estimate_mb = _estimate(env_id, config) / 2**20
    result = measure_limit(env_id, config, seconds=0.0, min_steps=3, trace_memory=True, timeout=600)
    measured_mb = result["traced_peak_mb"]
    assert measured_mb / 2 <= estimate_mb <= measured_mb * 2, (
        f"{env_id} {config}: estimate {estimate_mb:.1f} MB, measured peak {measured_mb:.1f} MB"
    )


@pytest.mark.parametrize("env_id", env_ids())
def test_documented_maxima_fit_the_default_budget(env_id):
    """Each argument's documented maximum runs by default (tests/core/test_limits.py runs them): the budget only
    refuses combinations."""
    for name, config in limit_configs(env_id).items():
        if BUDGET_ARGUMENT not in config:
            assert _estimate(env_id, config) <= DEFAULT_MEMORY_BUDGET_GIB * GIB, name


@pytest.mark.parametrize("env_id", env_ids())
def test_arguments_over_the_budget_are_refused_naming_them(env_id):
    cls = env_class(env_id)
    config = list(cls.MEMORY_PROBES.values())[-1]
    needed_gib = _estimate(env_id, config) / GIB
    budget = needed_gib / 2
    with pytest.raises(ValueError, match=BUDGET_ARGUMENT) as info:
        mrcomm_env.make(env_id, **config, **{BUDGET_ARGUMENT: budget})
    assert any(f"'{arg}'" in str(info.value) for arg in cls.MEMORY_ARGS), str(info.value)
    # the same arguments run when the budget is raised to the estimate
    mrcomm_env.make(env_id, **config, **{BUDGET_ARGUMENT: needed_gib * 1.01}).close()


@pytest.mark.parametrize("env_id", env_ids())
def test_metrics_and_state_before_reset_say_to_reset(env_id):
    env = mrcomm_env.make(env_id)
    for method in (env.metrics, env.state, lambda: env.step({})):
        with pytest.raises(RuntimeError, match=r"reset\(\)"):
            method()


def _horizon(env_id, cycles):
    check = env_class(env_id).PARAMS["max_cycles"].check
    return cycles if check.hi is None else min(cycles, check.hi)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", env_ids())
def test_memory_does_not_grow_with_the_horizon(env_id):
    """A horizon of a billion steps costs what ten do: nothing is sized by ``max_cycles`` (MapSync's observation
    once tabulated every possible age, 16 GB at 2e9)."""
    short, long = {"max_cycles": 10}, {"max_cycles": _horizon(env_id, 10**9)}
    assert _estimate(env_id, short) == _estimate(env_id, long)
    peaks = [
        measure_limit(env_id, cfg, seconds=0.0, min_steps=3, trace_memory=True, timeout=600)["traced_peak_mb"]
        for cfg in (short, long)
    ]
    assert peaks[1] <= peaks[0] + 1.0, f"{env_id}: {peaks[0]:.1f} MB at 10 steps, {peaks[1]:.1f} MB at 1e9"


#: arguments under which an env's episode runs on for thousands of steps (RendezvousMapping's default sensor
#: floor is exhausted within a few hundred phases, and the episode ends)
LONG_EPISODE_ARGS = {"mrcomm/RendezvousMapping-v0": {"obs_per_landmark": 10_000}}


@pytest.mark.slow
@pytest.mark.parametrize("env_id", env_ids())
def test_memory_does_not_grow_over_a_long_episode(env_id):
    """What an env holds follows its arguments, not how long it has run: the traced peak over 1,200 random steps
    of one episode is the peak over 150, within 1 MB (RendezvousMapping once kept every packet for the whole
    episode, 6.7 MB more per 1,000 phases at these arguments). Both runs follow 1,200 untraced steps of the same
    play by another env, so that a kernel numba compiles or loads on its first call after step 150 is the process's
    one-time cost, paid before either is traced, not growth (MapSync, whose kernels are all compiled: 15.6 MB after
    150 steps and 21.5 MB after 1,200 without the warm-up in a fresh clone's make test; 0.05 MB both with it)."""
    config = {"max_cycles": _horizon(env_id, 10**9), **LONG_EPISODE_ARGS.get(env_id, {})}
    peaks = [
        measure_limit(
            env_id,
            config,
            seconds=0.0,
            min_steps=steps,
            trace_memory=True,
            timeout=600,
            warmup_steps=1200,
        )["traced_peak_mb"]
        for steps in (150, 1200)
    ]
    assert peaks[1] <= peaks[0] + 1.0, f"{env_id}: {peaks[0]:.2f} MB after 150 steps, {peaks[1]:.2f} MB after 1,200"
