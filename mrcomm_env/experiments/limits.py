"""Speed and peak memory of an environment at its documented maxima (for ``mrcomm bench`` and the limit tests).

Every ``Param`` range is a promise: an env class lists, in ``LIMIT_CONFIGS``, named configurations at the
largest values its documentation allows (team size, history, slot size, …). :func:`measure_limit` builds
one of them in a fresh Python process, runs random actions for a while and reports env-steps/s and that
process's peak resident memory, so each configuration's peak is its own and not the largest seen so far.

    >>> from mrcomm_env.experiments.limits import limit_configs, measure_limit
    >>> for name, cfg in limit_configs("AsyncCL-v0").items():
    ...     print(name, measure_limit("AsyncCL-v0", cfg, seconds=5.0))

Run as a module it measures one configuration and prints one JSON line (that is what the parent reads).
"""

from __future__ import annotations

import importlib
import json
import math
import os
import resource
import subprocess
import sys
import time
import tracemalloc
from typing import Any

import numpy as np

from mrcomm_env.core.batched import BatchedEnv, sample_actions
from mrcomm_env.registry import entry, env_class

#: the hook name; until ``MrcommParallelEnv`` declares it, a class without it has no documented maxima
LIMIT_ATTRIBUTE = "LIMIT_CONFIGS"


def limit_configs(env_id: str) -> dict[str, dict[str, Any]]:
    """Named configurations of ``env_id`` at its documented maxima (empty when the class lists none)."""
    return dict(getattr(env_class(env_id), LIMIT_ATTRIBUTE, {}))


def measure_limit(
    env_id: str,
    config: dict[str, Any],
    seconds: float = 10.0,
    min_steps: int = 3,
    max_steps: int | None = None,
    seed: int = 0,
    timeout: float | None = None,
    env_vars: dict[str, str] | None = None,
    trace_memory: bool = False,
    warmup_steps: int = 0,
) -> dict[str, Any]:
    """Run ``env_id`` with ``config`` in a fresh process under random actions.

    It steps for ``seconds`` of wall time, but at least ``min_steps`` and at most ``max_steps`` steps
    (episodes restart when they end). Returns ``steps_per_s`` (over the timed steps, construction and the
    first reset excluded), ``peak_rss_mb`` (the child's peak resident set, interpreter included), ``steps``,
    ``build_s`` and ``reset_s`` (seconds to construct and to reset), ``finite`` (every observation, reward
    and info seen was finite) and ``n_agents``. A child that fails raises ``RuntimeError`` with its last
    error line; ``timeout`` (seconds) bounds the child. With ``trace_memory`` the child also reports
    ``traced_peak_mb``: the peak of what Python and numpy allocated from construction to the last step
    (``tracemalloc``, which slows the run down), the env's own memory without the interpreter's. With
    ``warmup_steps``, another env of the same arguments first runs that many steps of the same random play, before
    anything is timed or traced: what the process pays once (numba compiling, or loading from its cache, a kernel
    on its first call) is then not counted as the measured env's.
    """
    if not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and seconds >= 0):
        raise ValueError(f"argument 'seconds' must be a finite number ≥ 0, got {seconds!r}")
    if isinstance(min_steps, bool) or not isinstance(min_steps, int) or min_steps < 1:
        raise ValueError(f"argument 'min_steps' must be an integer ≥ 1, got {min_steps!r}")
    if isinstance(warmup_steps, bool) or not isinstance(warmup_steps, int) or warmup_steps < 0:
        raise ValueError(f"argument 'warmup_steps' must be an integer ≥ 0, got {warmup_steps!r}")
    if max_steps is not None and (
        isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < min_steps
    ):
        raise ValueError(
            f"argument 'max_steps' must be None or an integer ≥ min_steps = {min_steps}, got {max_steps!r}"
        )
    job = {
        "env_id": env_id,
        # the child builds the env from its shim module, so an env registered at run time (register()) is found
        "env_module": entry(env_id).env,
        "config": config,
        "seconds": seconds,
        "min_steps": min_steps,
        "max_steps": max_steps,
        "seed": seed,
        "trace_memory": bool(trace_memory),
        "warmup_steps": warmup_steps,
    }
    return _in_child(job, timeout, {**os.environ, **(env_vars or {})}, f"{env_id} {config}")


def _in_child(job: dict[str, Any], timeout: float | None, env: Any, what: str) -> dict[str, Any]:
    """Run ``job`` in ``python -m`` this module and return the JSON line it prints."""
    proc = subprocess.run(
        [sys.executable, "-m", __name__, json.dumps(job)], capture_output=True, text=True, timeout=timeout, env=env
    )
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"{what}: the measuring process failed ({proc.returncode}): {last}")
    return json.loads(lines[-1])


def measure_batched(
    env_id: str,
    config: dict[str, Any],
    n_copies: int,
    seconds: float = 3.0,
    min_steps: int = 2,
    seed: int = 0,
    timeout: float | None = None,
) -> dict[str, Any]:
    """Step a :class:`~mrcomm_env.core.batched.BatchedEnv` of ``n_copies`` copies of ``env_id`` with ``config`` in
    a fresh process under uniformly random actions, for ``seconds`` of wall time and at least ``min_steps`` batch
    steps (copies reset on their own). Returns ``agent_steps_per_s`` and ``env_steps_per_s`` (every copy's agents
    and steps, over the timed steps; drawing the actions, construction and the first reset excluded),
    ``peak_rss_mb`` (the child's peak resident set, interpreter included), ``rss_before_mb`` and ``rss_after_mb``
    (the resident set before the batch was built, with the env's modules imported, and after the last step: their
    difference is what the batch holds), ``steps``, ``build_s``, ``reset_s``, ``finite`` and ``n_agents``.
    """
    if isinstance(n_copies, bool) or not isinstance(n_copies, int) or n_copies < 1:
        raise ValueError(f"argument 'n_copies' must be an integer ≥ 1, got {n_copies!r}")
    job = {
        "kind": "batched",
        "env_id": env_id,
        "env_module": entry(env_id).env,
        "config": config,
        "n_copies": n_copies,
        "seconds": seconds,
        "min_steps": min_steps,
        "seed": seed,
    }
    return _in_child(job, timeout, os.environ, f"{env_id} {config} × {n_copies} copies")


def _run(job: dict[str, Any]) -> dict[str, Any]:

    make_env = importlib.import_module(job["env_module"]).parallel_env  # importing is not the env's memory
    if job.get("warmup_steps"):
        _random_play(make_env(**job["config"]), job["seed"], job["warmup_steps"])
    if job.get("trace_memory"):
        tracemalloc.start()
    start = time.perf_counter()
    env = make_env(**job["config"])
    built = time.perf_counter()
    obs, infos = env.reset(seed=job["seed"])
    reset_done = time.perf_counter()
    space = env.action_space(env.possible_agents[0])
    space.seed(job["seed"])
    finite = _all_finite(np, obs.values(), infos)
    steps, episodes = 0, 0
    deadline = reset_done + job["seconds"]
    max_steps = job["max_steps"]
    timed = 0.0
    while steps < job["min_steps"] or (time.perf_counter() < deadline and (max_steps is None or steps < max_steps)):
        if not env.agents:
            episodes += 1
            env.reset(seed=job["seed"] + episodes)
        actions = {a: space.sample() for a in env.agents}
        t0 = time.perf_counter()
        obs, rewards, _, _, infos = env.step(actions)
        timed += time.perf_counter() - t0
        steps += 1
        finite = finite and _all_finite(np, obs.values(), infos, rewards.values())
    peak_mb = _peak_rss_mb()
    traced = {}
    if job.get("trace_memory"):
        traced = {"traced_peak_mb": tracemalloc.get_traced_memory()[1] / 2**20}
    return {
        **traced,
        "env_id": job["env_id"],
        "n_agents": env.n_agents,
        "steps": steps,
        "steps_per_s": steps / timed if timed > 0 else math.inf,
        "peak_rss_mb": peak_mb,
        "build_s": built - start,
        "reset_s": reset_done - built,
        "finite": bool(finite),
    }


def _random_play(env, seed: int, steps: int) -> None:
    """``steps`` steps of ``env`` under the random actions :func:`_run` plays (episodes restart when they end)."""
    env.reset(seed=seed)
    space = env.action_space(env.possible_agents[0])
    space.seed(seed)
    episodes = 0
    for _ in range(steps):
        if not env.agents:
            episodes += 1
            env.reset(seed=seed + episodes)
        env.step({a: space.sample() for a in env.agents})
    env.close()


def _run_batched(job: dict[str, Any]) -> dict[str, Any]:
    env_cls = importlib.import_module(job["env_module"]).parallel_env  # importing is not the batch's memory
    rss_before_mb = _current_rss_mb()
    start = time.perf_counter()
    # the batch's own observation buffer, not a copy per step: how the training VecEnv steps it (copy=False)
    batch = BatchedEnv(lambda: env_cls(**job["config"]), job["n_copies"], copy=False)
    built = time.perf_counter()
    obs, infos = batch.reset(seed=job["seed"])
    reset_done = time.perf_counter()
    finite = bool(np.isfinite(obs).all()) and all(bool(np.isfinite(v).all()) for v in infos.values())
    rng = np.random.default_rng(job["seed"])
    leading = (batch.n_copies, batch.n_agents)
    steps, timed = 0, 0.0
    deadline = reset_done + job["seconds"]
    while steps < job["min_steps"] or time.perf_counter() < deadline:
        actions = sample_actions(batch.action_space, rng, leading)
        t0 = time.perf_counter()
        out = batch.step(actions)
        timed += time.perf_counter() - t0
        steps += 1
        finite = finite and bool(np.isfinite(out.observations).all() and np.isfinite(out.rewards).all())
        finite = finite and all(bool(np.isfinite(v).all()) for v in out.infos.values())
    peak_mb = _peak_rss_mb()
    copies_steps = steps * batch.n_copies
    return {
        "env_id": job["env_id"],
        "n_copies": batch.n_copies,
        "n_agents": batch.n_agents,
        # the copies stepped as one copy-axis world (BatchedEnv.world), or each env object in turn
        "copy_axis_world": batch.world is not None,
        "steps": steps,
        "env_steps_per_s": copies_steps / timed if timed > 0 else math.inf,
        "agent_steps_per_s": copies_steps * batch.n_agents / timed if timed > 0 else math.inf,
        "peak_rss_mb": peak_mb,
        "rss_before_mb": rss_before_mb,
        "rss_after_mb": _current_rss_mb(),
        "build_s": built - start,
        "reset_s": reset_done - built,
        "finite": finite,
    }


def _peak_rss_mb() -> float:
    """This process's own peak resident set (Linux ``VmHWM``). Not ``getrusage``'s ``ru_maxrss``: Linux carries it
    over ``exec``, so a child started by a process of 460 MB reported at least 460 MB whatever it used itself."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0  # kB
    except (OSError, ValueError, IndexError):
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux; elsewhere the best there is


def _current_rss_mb() -> float:
    """This process's resident set now (Linux ``/proc``; the peak where it cannot be read)."""
    try:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _all_finite(np, observations, infos, rewards=()) -> bool:
    values = [np.asarray(o, dtype=float).ravel() for o in observations]
    values.append(np.asarray(list(rewards), dtype=float))
    values.append(np.asarray([v for info in infos.values() for v in info.values()], dtype=float))
    return all(bool(np.all(np.isfinite(v))) for v in values)


if __name__ == "__main__":
    _job = json.loads(sys.argv[1])
    print(json.dumps(_run_batched(_job) if _job.get("kind") == "batched" else _run(_job)))
