"""Conformance suite: every registered environment × every configuration it documents.

PettingZoo's own checkers run first; our own checks follow (full-episode determinism with infos,
observation bounds, pickling, long random runs, bad input). The checks users can run on their own env are the
kit's (``mrcomm_env.testing``), called here per configuration; what only our suite checks (the AEC form, the
registry, long runs, the fuzz) is written here.
"""

from __future__ import annotations

import functools
import math
import os
import pickle
import warnings

import numpy as np
import pettingzoo
import pytest
from gymnasium import spaces
from hypothesis import given, settings
from hypothesis import strategies as st
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    render_test,
    seed_test,
    state_test,
)

import mrcomm_env
from mrcomm_env import testing
from mrcomm_env.core.config import Bool, Choice, Int, Optional, Real, validate_config
from mrcomm_env.core.memory import BUDGET_ARGUMENT, GIB
from mrcomm_env.registry import env_class, env_ids, env_module
from mrcomm_env.testing import flat_values, invalid_values, same

ENV_IDS = env_ids()
CASES = [
    pytest.param(env_id, name, id=f"{env_id.split('/')[1]}[{name}]")
    for env_id in ENV_IDS
    for name in env_class(env_id).DOCUMENTED_CONFIGS
]


def config(env_id: str, name: str, **overrides) -> dict:
    return {**env_class(env_id).DOCUMENTED_CONFIGS[name], **overrides}


def short_config(env_id, name, steps=60):
    cfg = config(env_id, name)
    cfg["max_cycles"] = min(cfg.get("max_cycles", env_class(env_id).PARAMS["max_cycles"].default), steps)
    return cfg


def factory(env_id, cfg):
    """What the kit's checks take: the env's constructor with these arguments (a check may add others)."""
    return functools.partial(mrcomm_env.make, env_id, **cfg)


# ------------------------------------------------------------------------------------------------ registry
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_registered_with_pettingzoo(env_id):
    par = pettingzoo.make("parallel", env_id)
    aec = pettingzoo.make("aec", env_id)
    assert par.possible_agents[0] == "robot_0"
    assert aec.possible_agents == par.possible_agents
    short = env_id.split("/", 1)[1]
    assert type(mrcomm_env.make(short)) is type(par)
    module = env_module(env_id)
    for attr in ("parallel_env", "env", "raw_env"):
        assert callable(getattr(module, attr))


def test_unknown_id_lists_valid_ones():
    with pytest.raises(ValueError, match="valid ids are: .*mrcomm/"):
        mrcomm_env.make("NoSuchEnv-v0")


# ------------------------------------------------------------------------------------------------ PettingZoo checkers
@pytest.mark.parametrize(("env_id", "name"), CASES)
def test_parallel_api(env_id, name):
    testing.check_parallel_api(factory(env_id, short_config(env_id, name)), seed=0, steps=60)


@pytest.mark.parametrize(("env_id", "name"), CASES)
def test_parallel_seed(env_id, name):
    testing.check_parallel_seed(factory(env_id, short_config(env_id, name)), seed=0, steps=60)


@pytest.mark.parametrize(("env_id", "name"), CASES)
def test_aec_api(env_id, name):
    api_test(env_module(env_id).env(**short_config(env_id, name, steps=30)), num_cycles=30)


@pytest.mark.parametrize(("env_id", "name"), CASES)
def test_aec_seed(env_id, name):
    shim = env_module(env_id)
    seed_test(lambda: shim.env(**short_config(env_id, name)), num_cycles=20)


@pytest.mark.parametrize(("env_id", "name"), CASES)
def test_state(env_id, name):
    # PettingZoo's state_test drives the AEC form; the parallel form's state() must lie in state_space too
    shim = env_module(env_id)
    state_test(shim.env(**short_config(env_id, name)), shim.parallel_env(**short_config(env_id, name)))
    env = mrcomm_env.make(env_id, **short_config(env_id, name))
    env.reset(seed=1)
    while env.agents:
        assert env.state_space.contains(env.state())
        env.step({a: env.action_space(a).sample() for a in env.agents})


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_max_cycles(env_id):
    # PettingZoo's checker passes max_cycles, our horizon argument, to the shim's constructors directly
    max_cycles_test(env_module(env_id))


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_render(env_id):
    shim = env_module(env_id)
    render_test(lambda render_mode=None: shim.env(render_mode=render_mode, max_cycles=20))


# ------------------------------------------------------------------------------------------------ our own checks
def rollout(env, seed, steps, action_seed=0):
    """A seeded episode with seeded random actions (the kit's): every step's full output, then the metrics."""
    return [*testing.rollout(env, seed, steps, action_seed), env.metrics()]


@pytest.mark.parametrize(("env_id", "name"), CASES)
def test_full_episode_is_deterministic_step_by_step(env_id, name):
    cfg = short_config(env_id, name, steps=120)
    testing.check_deterministic_episodes(factory(env_id, cfg), seed=11, steps=200)
    testing.check_plain_infos(factory(env_id, cfg), seed=11, steps=200)
    t1 = rollout(mrcomm_env.make(env_id, **cfg), seed=11, steps=200)
    assert same(t1, rollout(mrcomm_env.make(env_id, **cfg), seed=11, steps=200))  # the metrics too
    t3 = rollout(mrcomm_env.make(env_id, **cfg), seed=12, steps=200)
    assert not all(same(x, y) for x, y in zip(t1, t3)), "a different seed gave the very same episode"


@pytest.mark.parametrize(("env_id", "name"), CASES)
def test_observations_in_space_and_pickle_roundtrip(env_id, name):
    env = mrcomm_env.make(env_id, **short_config(env_id, name, steps=80))
    obs, infos = env.reset(seed=3)
    space = env.observation_space("robot_0")
    assert all(env.observation_space(a) is space for a in env.possible_agents), "spaces must be shared"
    assert all(env.action_space(a) is env.action_space("robot_0") for a in env.possible_agents)
    assert set(infos) == set(env.agents) and all("bits_sent" in i for i in infos.values())
    act = env.action_space("robot_0")
    act.seed(5)
    for step in range(20):
        if not env.agents:  # stationary scenes may finish early
            env.reset(seed=100 + step)
        obs, *_ = env.step({a: act.sample() for a in env.agents})
        assert all(space.contains(o) for o in obs.values())
    if not env.agents:
        env.reset(seed=99)
    clone = pickle.loads(pickle.dumps(env))
    actions = {a: act.sample() for a in env.agents}
    assert same(env.step(actions), clone.step(actions))


def batch_sampler(space, rng):
    """Uniform random actions for many agents at once (space.sample() per agent dominates large envs)."""
    if isinstance(space, spaces.MultiBinary):
        return lambda agents: dict(zip(agents, rng.integers(0, 2, (len(agents), *space.shape), dtype=np.int8)))
    if isinstance(space, spaces.Discrete):
        return lambda agents: dict(zip(agents, (rng.integers(0, space.n, len(agents)) + space.start).tolist()))
    if hasattr(space, "high"):

        def sample(agents):
            draws = rng.uniform(space.low, space.high, size=(len(agents), *space.shape)).astype(space.dtype)
            return dict(zip(agents, draws))

        return sample
    return lambda agents: {a: space.sample() for a in agents}


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_ten_thousand_random_steps_stay_finite(env_id):
    env = mrcomm_env.make(env_id)
    sample = batch_sampler(env.action_space("robot_0"), np.random.default_rng(0))
    obs_space = env.observation_space("robot_0")
    env.reset(seed=0)
    for step in range(10_000):
        if not env.agents:
            assert all(math.isfinite(v) for v in env.metrics().values() if not math.isnan(v))
            env.reset(seed=step)
        obs, rewards, _, _, infos = env.step(sample(env.agents))
        values = [*rewards.values(), *(v for info in infos.values() for v in info.values())]
        assert np.all(np.isfinite(values)), f"non-finite reward or info at step {step}"
        stacked = np.stack(list(obs.values()))
        assert np.all(np.isfinite(stacked)) and np.all(stacked >= obs_space.low) and np.all(stacked <= obs_space.high)


# ------------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_invalid_arguments_raise_value_error_naming_them(env_id):
    cls = env_class(env_id)
    testing.check_bad_arguments(factory(env_id, {}), seed=0, steps=0)
    assert sum(len(invalid_values(spec.check)) for spec in cls.PARAMS.values()) >= len(cls.PARAMS) // 2


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_invalid_actions_and_agents_raise_value_error(env_id):
    env = mrcomm_env.make(env_id)
    with pytest.raises(ValueError, match="robot_"):
        env.observation_space("robot_99999")
    testing.check_bad_actions(factory(env_id, {}), seed=0, steps=0)


# ------------------------------------------------------------------------------------------------ property tests
#: for a range without an upper bound, the fuzz also draws this large finite value (every range is a promise)
HUGE = 1e300


def _real_edges(v: Real) -> list[float]:
    """The documented edges of a real range: closed ends themselves, open ends one ulp inside (and, at an
    open 0, also 1e-300), and a huge finite value where the range has no upper bound."""
    edges = []
    if v.lo is not None:
        if v.lo_open:
            edges.append(math.nextafter(v.lo, math.inf))
            edges.append(v.lo + 1e-300 if v.lo == 0.0 else math.nextafter(v.lo, math.inf))
        else:
            edges.append(float(v.lo))
    if v.hi is not None:
        edges.append(math.nextafter(v.hi, -math.inf) if v.hi_open else float(v.hi))
    else:
        edges.append(HUGE)
        if v.allow_inf:
            edges.append(math.inf)
    return sorted(set(edges))


def _strategy(validator):
    """Values of one argument: its cheap ``fuzz`` range plus the edges of its documented range.

    Integer upper bounds are sizes (robots, history, slots) whose cost grows with the value; they run, with
    their memory measured, in tests/core/test_limits.py (each env's ``LIMIT_CONFIGS``) rather than here."""
    if isinstance(validator, Optional):
        inner = _strategy(validator.inner)
        return None if inner is None else st.one_of(st.none(), inner)
    if isinstance(validator, Int) and validator.fuzz:
        edges = [validator.lo] if validator.lo is not None else []
        return (
            st.one_of(st.integers(*validator.fuzz), st.sampled_from(edges)) if edges else st.integers(*validator.fuzz)
        )
    if isinstance(validator, Real) and validator.fuzz:
        return st.one_of(st.floats(*validator.fuzz, allow_nan=False), st.sampled_from(_real_edges(validator)))
    if isinstance(validator, Choice):
        return st.sampled_from(validator.options)
    if isinstance(validator, Bool):
        return st.booleans()
    return None


def _config_strategy(env_id):
    fields = {
        arg: s
        for arg, spec in env_class(env_id).PARAMS.items()
        if arg != BUDGET_ARGUMENT and (s := _strategy(spec.check)) is not None
    }
    return st.fixed_dictionaries({}, optional=fields)


FUZZ_STEPS = 12
#: the memory budget the fuzz builds envs under: two xdist workers each running one well inside their address-space
#: cap (tests/conftest.py); argument sets over it must be refused at construction, before they allocate
FUZZ_BUDGET_GIB = 0.5
#: examples per env: a fixed, derandomized 25 in ``make test``; the ``fuzz`` profile's 1,000 fresh ones in ``make fuzz``
FUZZ_EXAMPLES = settings.default.max_examples if os.environ.get("HYPOTHESIS_PROFILE") == "fuzz" else 25


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_random_valid_configurations_run(env_id):
    """Random arguments, edges of every range included, either build an env whose short episode stays finite
    and in its spaces without a single RuntimeWarning, or are rejected at construction naming an argument. Sets
    whose memory estimate is over the budget are refused before they allocate anything."""
    cls = env_class(env_id)
    params = cls.PARAMS
    outcomes = {"ran": 0, "over the memory budget": 0, "refused naming an argument": 0}

    @settings(max_examples=FUZZ_EXAMPLES)
    @given(cfg=_config_strategy(env_id), seed=st.integers(0, 2**16))
    def check(cfg, seed):
        cfg = {
            **cfg,
            "max_cycles": min(cfg.get("max_cycles", FUZZ_STEPS), FUZZ_STEPS),
            BUDGET_ARGUMENT: FUZZ_BUDGET_GIB,
        }
        estimate = cls.memory_estimate(validate_config(params, cfg))
        if estimate > FUZZ_BUDGET_GIB * GIB:
            with pytest.raises(ValueError, match=BUDGET_ARGUMENT):
                mrcomm_env.make(env_id, **cfg)
            outcomes["over the memory budget"] += 1
            return
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            try:
                env = mrcomm_env.make(env_id, **cfg)
            except ValueError as exc:  # arguments that constrain each other must say which
                assert any(f"'{arg}'" in str(exc) for arg in params), str(exc)
                outcomes["refused naming an argument"] += 1
                return
            rollout_obs_space = env.observation_space("robot_0")
            trace = rollout(env, seed=seed, steps=FUZZ_STEPS)
        for out in trace[1:-1]:
            obs = out[0]
            assert all(rollout_obs_space.contains(o) for o in obs.values())
            assert np.all(np.isfinite(np.fromiter(flat_values([out[1], out[4]]), dtype=float)))
        assert all(math.isfinite(v) for v in trace[-1].values() if not math.isnan(v)), trace[-1]
        outcomes["ran"] += 1

    check()
    print(f"{env_id}: {sum(outcomes.values())} examples: " + ", ".join(f"{n} {k}" for k, n in outcomes.items()))
    assert sum(outcomes.values()) >= FUZZ_EXAMPLES and outcomes["ran"] > 0, outcomes


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_fuzz_reaches_the_edges_of_every_real_range(env_id):
    """The strategy above can draw each documented edge (a range edge the fuzz never draws is no promise)."""
    for arg, spec in env_class(env_id).PARAMS.items():
        check = spec.check.inner if isinstance(spec.check, Optional) else spec.check
        if isinstance(check, Real) and check.fuzz:
            for edge in _real_edges(check):
                assert check(arg, edge) == edge  # every edge is itself a valid value
