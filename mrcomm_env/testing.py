"""The conformance kit: our checks, for anyone's PettingZoo parallel env (``check_env``).

    from mrcomm_env.testing import check_env
    check_env(MyEnv)                                   # a class, or any factory taking the env's keyword arguments
    check_env(functools.partial(mrcomm_env.make, "MapSync-v0"))

Every check runs on any ``pettingzoo.ParallelEnv`` factory; the checks driven by declarations run where the env
subclasses :class:`~mrcomm_env.core.base.MrcommParallelEnv` (its ``PARAMS``, ``METRICS``, ``DOCUMENTED_CONFIGS``
and memory estimate). A failed check raises ``AssertionError`` naming it, with what it found; an exception the env
raises inside a check is reported the same way, chained. ``check_env`` returns the names of the checks it ran.

The generic checks (``GENERIC_CHECKS``):

- ``parallel_api``, ``parallel_seed``: PettingZoo's own ``parallel_api_test`` and ``parallel_seed_test``;
- ``shared_spaces``: every agent has the same observation and action space (one policy can serve the team);
- ``deterministic_episodes``: ``reset(seed=s)`` then seeded random actions give the same episode twice, every
  observation, reward, end flag and info included;
- ``plain_infos``: infos hold plain numbers with the same keys at reset and at every step (TorchRL builds its
  specs from the reset infos);
- ``finite_in_space``: observations lie in their space and are finite, rewards and infos are finite;
- ``state_in_space``: where the env has ``state()``, it lies in ``state_space``.

The checks driven by declarations (``DECLARED_CHECKS``, mrcomm envs):

- ``bad_arguments``: an unknown argument, and out-of-range values of each documented argument, raise
  ``ValueError`` naming the argument;
- ``bad_actions``: invalid actions and unknown or missing agents raise ``ValueError``, and the env steps on;
- ``documented_configs``: each of ``DOCUMENTED_CONFIGS`` builds and runs a short episode whose metrics are the
  declared ``METRICS``, each finite or NaN;
- ``memory_budget``: the memory estimate does not grow with ``max_cycles`` alone, and arguments whose estimate is
  over the budget are refused at construction, naming the budget.
"""

from __future__ import annotations

import functools
import math
import pickle
from collections.abc import Callable, Iterator
from numbers import Real
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo.test import parallel_api_test, parallel_seed_test

from mrcomm_env.core.base import MrcommParallelEnv
from mrcomm_env.core.config import Bool, Choice, Int, Optional, validate_config
from mrcomm_env.core.config import Real as RealRange
from mrcomm_env.core.memory import BUDGET_ARGUMENT, GIB

#: steps of the short episodes the checks run
STEPS = 40
#: the ``max_cycles`` the memory check compares with 1 where the env gives no upper bound (the estimate must not
#: depend on it)
LONG_HORIZON = 10**9


def check_env(make_env: Callable[..., Any], seed: int = 0, steps: int = STEPS) -> list[str]:
    """Run the conformance checks on the env that ``make_env(**kwargs)`` builds (see the module docstring).

    :param make_env: a ``ParallelEnv`` class or factory; called without arguments for the generic checks, and with
        the env's keyword arguments for the checks its declarations drive.
    :param seed: the episode seed of the checks (the determinism check runs it twice).
    :param steps: the most steps an episode of a check runs.
    :returns: the names of the checks that ran (all passed).
    :raises AssertionError: naming the first check that failed.
    """
    probe = make_env()
    checks = dict(GENERIC_CHECKS)
    if isinstance(probe, MrcommParallelEnv):
        checks.update(DECLARED_CHECKS)
    ran = []
    for name, check in checks.items():
        try:
            check(make_env, seed, steps)
        except AssertionError as error:
            raise AssertionError(f"check '{name}' failed: {error}") from error
        except Exception as error:  # noqa: BLE001 - whatever the env raised, reported as that check's failure
            raise AssertionError(f"check '{name}' failed: the env raised {type(error).__name__}: {error}") from error
        ran.append(name)
    return ran


# ----------------------------------------------------------------------------------------------- episodes
def random_actions(env, action_seed: int) -> Callable[[list[str]], dict[str, Any]]:
    """Seeded uniform actions for the live agents (one space for all: the shared-spaces check comes first)."""
    space = env.action_space(env.possible_agents[0])
    space.seed(action_seed)
    return lambda agents: {agent: space.sample() for agent in agents}


def rollout(env, seed: int, steps: int, action_seed: int = 0) -> list[tuple]:
    """``reset(seed=seed)`` and at most ``steps`` seeded random steps: every output, reset's first."""
    trace: list[tuple] = [env.reset(seed=seed)]
    act = random_actions(env, action_seed)
    for _ in range(steps):
        if not env.agents:
            break
        trace.append(env.step(act(list(env.agents))))
    return trace


def flat_values(obj) -> Iterator:
    """Every value inside nested dicts, lists, tuples and arrays of an env's output."""
    if isinstance(obj, dict):
        for value in obj.values():
            yield from flat_values(value)
    elif isinstance(obj, (list, tuple)):
        for value in obj:
            yield from flat_values(value)
    elif isinstance(obj, np.ndarray):
        yield from obj.ravel().tolist()
    else:
        yield obj


def same(a, b) -> bool:
    """Equal value for value (NaN equals NaN), and the same dict keys in the same places."""
    if isinstance(a, dict) or isinstance(b, dict):
        return isinstance(a, dict) and isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    va, vb = list(flat_values(a)), list(flat_values(b))
    return len(va) == len(vb) and all(x == y or (x != x and y != y) for x, y in zip(va, vb))


# ----------------------------------------------------------------------------------------------- generic checks
def check_parallel_api(make_env, seed: int, steps: int) -> None:
    parallel_api_test(make_env(), num_cycles=steps)


def check_parallel_seed(make_env, seed: int, steps: int) -> None:
    parallel_seed_test(make_env, num_cycles=steps)


def check_shared_spaces(make_env, seed: int, steps: int) -> None:
    env = make_env()
    first = env.possible_agents[0]
    for agent in env.possible_agents:
        assert env.observation_space(agent) == env.observation_space(first), f"{agent}'s observation space differs"
        assert env.action_space(agent) == env.action_space(first), f"{agent}'s action space differs"


def check_deterministic_episodes(make_env, seed: int, steps: int) -> None:
    first = rollout(make_env(), seed, steps)
    second = rollout(make_env(), seed, steps)
    assert len(first) == len(second), f"episodes of seed {seed} lasted {len(first) - 1} and {len(second) - 1} steps"
    for k, (a, b) in enumerate(zip(first, second)):
        assert same(a, b), f"{'reset' if k == 0 else f'step {k}'} of seed {seed} differs between two runs"


def check_plain_infos(make_env, seed: int, steps: int) -> None:
    trace = rollout(make_env(), seed, steps)
    reset_infos = trace[0][1]
    keys = {agent: set(info) for agent, info in reset_infos.items()}
    for k, out in enumerate(trace):
        for agent, info in out[-1].items():
            where = f"{'reset' if k == 0 else f'step {k}'}, {agent}"
            assert set(info) == keys.get(agent, set(info)), (
                f"{where}: info keys {sorted(info)} differ from the reset's {sorted(keys.get(agent, ()))}"
            )
            for key, value in info.items():
                assert isinstance(value, (Real, np.number)) and not isinstance(value, (bool, np.bool_)), (
                    f"{where}: info '{key}' is {type(value).__name__}, not a plain number"
                )


def check_finite_in_space(make_env, seed: int, steps: int) -> None:
    env = make_env()
    trace = rollout(env, seed, steps)
    for k, out in enumerate(trace):
        observations = out[0]
        for agent, obs in observations.items():
            space = env.observation_space(agent)
            assert space.contains(obs), f"step {k}: {agent}'s observation is outside {space}"
            values = np.asarray(list(flat_values(obs)), dtype=float)
            assert np.isfinite(values).all(), f"step {k}: {agent}'s observation is not finite"
        if k:
            rewards = np.asarray(list(out[1].values()), dtype=float)
            assert np.isfinite(rewards).all(), f"step {k}: a reward is not finite: {out[1]}"
        infos = np.asarray([v for info in out[-1].values() for v in flat_values(info)], dtype=float)
        assert np.isfinite(infos).all(), f"step {k}: an info is not finite"


def check_state_in_space(make_env, seed: int, steps: int) -> None:
    env = make_env()
    if not callable(getattr(env, "state", None)) or getattr(env, "state_space", None) is None:
        return  # no global state: nothing to check
    env.reset(seed=seed)
    act = random_actions(env, 0)
    for k in range(steps):
        assert env.state_space.contains(env.state()), f"step {k}: state() is outside state_space"
        if not env.agents:
            break
        env.step(act(list(env.agents)))


GENERIC_CHECKS: dict[str, Callable[[Any, int, int], None]] = {
    "parallel_api": check_parallel_api,
    "parallel_seed": check_parallel_seed,
    "shared_spaces": check_shared_spaces,
    "deterministic_episodes": check_deterministic_episodes,
    "plain_infos": check_plain_infos,
    "finite_in_space": check_finite_in_space,
    "state_in_space": check_state_in_space,
}


# ----------------------------------------------------------------------------------------------- declared checks
def invalid_values(validator) -> list:
    """Values a documented argument's validator must refuse: wrong types, and just past each end of its range."""
    if isinstance(validator, Optional):
        return invalid_values(validator.inner)
    if isinstance(validator, (Int, RealRange)):
        integer = isinstance(validator, Int)
        bad: list = ["three", 2.5, True] if integer else ["x", float("nan")]
        one = 1 if integer else 1.0
        bad += [end for end in (_shifted(validator.lo, -one), _shifted(validator.hi, one)) if end is not None]
        return bad
    if isinstance(validator, Choice):
        return ["no-such-option"]
    if isinstance(validator, Bool):
        return ["yes"]
    return []


def _shifted(end, by):
    """A range's end moved out of the range by ``by`` (None: no end)."""
    return None if end is None else end + by


def _raises_value_error(build: Callable[[], Any], naming: str, what: str) -> None:
    try:
        build()
    except ValueError as error:
        assert naming in str(error), f"{what}: the ValueError does not name {naming}: {error}"
        return
    raise AssertionError(f"{what} was accepted")


def check_bad_arguments(make_env, seed: int, steps: int) -> None:
    cls = type(make_env())
    _raises_value_error(lambda: make_env(no_such_argument=1), "no_such_argument", "an unknown argument")
    for name, param in cls.PARAMS.items():
        for bad in invalid_values(param.check):
            build = functools.partial(make_env, **{name: bad})
            _raises_value_error(build, f"'{name}'", f"argument {name}={bad!r}")


def check_bad_actions(make_env, seed: int, steps: int) -> None:
    env = make_env()
    env.reset(seed=seed)
    first = env.possible_agents[0]
    space = env.action_space(first)
    good = random_actions(env, 0)(list(env.agents))
    _raises_value_error(lambda: env.step({**good, "robot_99999": space.sample()}), "", "an unknown agent's action")
    _raises_value_error(lambda: env.step({a: v for a, v in good.items() if a != first}), "", "a missing action")
    if isinstance(space, spaces.MultiBinary):
        bad_values: list = [np.full(space.shape, 2), np.zeros(space.shape[0] + 1, dtype=np.int8), 0.5]
    elif isinstance(space, spaces.Discrete):
        bad_values = [int(space.start + space.n), int(space.start) - 1, 0.5]
    elif isinstance(space, spaces.Box):
        bad_values = [space.high + 1.0, np.full(space.shape, np.nan, dtype=space.dtype), np.zeros(space.shape[0] + 1)]
    else:
        bad_values = []
    for bad in bad_values:
        _raises_value_error(functools.partial(env.step, {**good, first: bad}), first, f"action {bad!r} of {first}")
    env.step(good)  # still usable after the refusals


def check_documented_configs(make_env, seed: int, steps: int) -> None:
    cls = type(make_env())
    for name, kwargs in cls.DOCUMENTED_CONFIGS.items():
        default_cycles = cls.PARAMS["max_cycles"].default
        env = make_env(**{**kwargs, "max_cycles": min(kwargs.get("max_cycles", default_cycles), steps)})
        rollout(env, seed, steps)
        metrics = env.metrics()
        assert set(metrics) == set(cls.METRICS), (
            f"configuration '{name}': metrics {sorted(metrics)} are not the declared {sorted(cls.METRICS)}"
        )
        bad = {k: v for k, v in metrics.items() if not (isinstance(v, float) and (math.isfinite(v) or v != v))}
        assert not bad, f"configuration '{name}': metrics neither finite floats nor NaN: {bad}"
        pickle.loads(pickle.dumps(env))  # an env in an episode pickles (vector envs send copies to workers)


def check_memory_budget(make_env, seed: int, steps: int) -> None:
    env = make_env()
    cls, cfg = type(env), env.cfg
    horizon = getattr(cls.PARAMS["max_cycles"].check, "hi", None) or LONG_HORIZON  # the longest documented
    short = cls.memory_estimate(validate_config(cls.PARAMS, {**cfg, "max_cycles": 1}))
    long = cls.memory_estimate(validate_config(cls.PARAMS, {**cfg, "max_cycles": horizon}))
    assert long == short, (
        f"the memory estimate grows with max_cycles alone ({short:.3g} B at 1, {long:.3g} B at {horizon:g})"
    )
    tiny = short / GIB / 2.0  # half the default arguments' own estimate
    if tiny > 0.0:
        _raises_value_error(lambda: make_env(**{BUDGET_ARGUMENT: tiny}), BUDGET_ARGUMENT, "a budget below the estimate")


DECLARED_CHECKS: dict[str, Callable[[Any, int, int], None]] = {
    "bad_arguments": check_bad_arguments,
    "bad_actions": check_bad_actions,
    "documented_configs": check_documented_configs,
    "memory_budget": check_memory_budget,
}
