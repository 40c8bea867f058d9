"""What ``mrcomm bench`` measures: env-steps/s against MPE2's ``simple_spread_v3``, training throughput, documented
limits, batches of copies, the sweep runner's backends, env-specific timings (``commands/bench.py`` is the command;
training throughput is :mod:`mrcomm_env.experiments.bench_train`'s).

Speed and memory goals are checked here, by measurement, never by timed unit tests.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import resource
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict
from typing import Any

from tqdm.auto import tqdm

from mrcomm_baselines import default_policy, make_policy
from mrcomm_env.core.memory import BUDGET_ARGUMENT, GIB
from mrcomm_env.experiments.evaluation import run_episode, steps_per_second
from mrcomm_env.experiments.limits import limit_configs, measure_batched, measure_limit
from mrcomm_env.experiments.reproductions import module
from mrcomm_env.experiments.runs import comparison_spec, sb3_algo
from mrcomm_env.experiments.sweep import Runner, Task, one_thread
from mrcomm_env.registry import make

#: what every env's speed is compared with
BENCH_REFERENCE = "mpe2 simple_spread_v3 (N=3, discrete actions, random actions)"


def median_of(measure, label: str, runs: int, warmup: float) -> tuple[float, float]:
    """The medians of ``runs`` timed runs ``measure(k)`` → (env-steps/s, agent-steps/s), after one untimed run of
    ``warmup`` seconds (0: none): caches, lazily built tables and compiled kernels are then loaded, as they are in
    any run longer than a few seconds."""
    if warmup > 0:
        measure(-1, warmup)
    samples = [measure(k) for k in tqdm(range(runs), desc=label, leave=False)]
    return statistics.median(s[0] for s in samples), statistics.median(s[1] for s in samples)


def reference_section(seconds: float, runs: int, warmup: float) -> dict[str, Any]:
    """MPE2's ``simple_spread_v3`` with random actions: the reference every ratio of the bench divides by."""
    from mpe2 import simple_spread_v3  # extra "bench"

    env = simple_spread_v3.parallel_env(N=3, continuous_actions=False)
    space = env.action_space(env.possible_agents[0])
    space.seed(0)
    eps, aps = median_of(
        lambda k, s=seconds: steps_per_second(env, lambda obs: {a: space.sample() for a in obs}, s, seed=k % 10_000),
        "simple_spread_v3",
        runs,
        warmup,
    )
    print(f"reference {BENCH_REFERENCE}: {eps:,.0f} env-steps/s, {aps:,.0f} agent-steps/s")
    return {"name": BENCH_REFERENCE, "env_steps_per_s": eps, "agent_steps_per_s": aps}


def speed_section(
    targets: list[str], params: dict, reference: dict, seconds: float, runs: int, warmup: float
) -> dict[str, Any]:
    """Each env stepped by its paper's algorithm (the default baseline): env-steps/s and agent-steps/s, and their
    ratio to ``reference``'s env-steps/s, per env step and per unit of the env's own time (``STEP_UNIT``)."""
    out = {}
    for env_id in targets:
        env = make(env_id, **params)
        policy_name = default_policy(env_id)
        policy = make_policy(env_id, policy_name)
        views = env.local_views()

        def measure(k, s=seconds, env=env, policy=policy, views=views):
            return steps_per_second(
                env,
                lambda obs: policy.act(obs, views),
                s,
                seed=k % 10_000,
                on_reset=lambda seed: policy.reset(views, seed),
            )

        eps, aps = median_of(measure, env_id, runs, warmup)
        ratio = eps / reference["env_steps_per_s"]
        unit, per = env.STEP_UNIT[0], env.substeps_per_step()
        out[env_id] = {
            "policy": policy_name,
            "params": params,
            "n_agents": env.n_agents,
            "env_steps_per_s": eps,
            "agent_steps_per_s": aps,
            "ratio_to_reference": ratio,
            "unit": unit,
            "units_per_env_step": per,
            "units_per_s": eps * per,
            "ratio_per_unit": eps * per / reference["env_steps_per_s"],
        }
        line = (
            f"{env_id} [{policy_name}, N={env.n_agents}]: {eps:,.1f} env-steps/s, {aps:,.0f} agent-steps/s, "
            f"ratio {ratio:.2f}"
        )
        if per != 1:  # e.g. one env step = one TDMA frame of N slots: compare slots with the reference's steps
            line += f"; {eps * per:,.0f} {unit}s/s, ratio per {unit} {eps * per / reference['env_steps_per_s']:.2f}"
        print(line)
        env.close()
    return out


#: agent slots of ``mrcomm bench --train`` by default: 4 copies of the 3-agent reference, one copy of most of ours
TRAIN_SLOTS = 12


def shipped_training(env_id: str) -> tuple[str, dict[str, Any], int]:
    """The algorithm, env arguments and copies (``n_envs``) of the env's shipped SB3 training configuration
    (``agents/configs/<Name>-v0.json``: the one ``mrcomm reproduce-learning`` trains, or its ``ppo`` section where
    that trains the batched trainer, :func:`~mrcomm_env.experiments.runs.sb3_algo`)."""
    spec = comparison_spec(env_id)
    algo = sb3_algo(spec)
    block = spec["settings"].get(algo, {})
    return algo, dict(block.get("env_kwargs", {})), int(block.get("n_envs", 1))


#: ``mrcomm bench --train --algo``: SB3's PPO through the agent-slot VecEnv, or the batched trainer
BATCHED_BENCH_ALGORITHMS = ("ippo", "mappo")


def limits_section(targets: list[str], seconds: float) -> dict[str, Any]:
    """Steps/s and peak memory of every documented maximum (``LIMIT_CONFIGS``), each in a fresh process."""

    out = {}
    for env_id in targets:
        for name, config in limit_configs(env_id).items():
            result = measure_limit(env_id, config, seconds=seconds)
            out[f"{env_id}:{name}"] = {"config": config, **result}
            print(
                f"limit  {env_id} {name}: {result.get('steps_per_s', float('nan')):,.2f} steps/s, "
                f"peak {result.get('peak_rss_mb', float('nan')):,.0f} MB"
            )
    return out


#: the batch sizes ``mrcomm bench --batched`` steps (#24's goal: M = 1,024 at ≥ 10× the agent-steps/s of M = 1)
BATCHED_COPIES = (1, 64, 1024)


def batched_section(
    targets: list[str], params: dict, copies: tuple[int, ...] = BATCHED_COPIES, seconds: float = 3.0, runs: int = 1
) -> dict[str, Any]:
    """Raw stepping of ``BatchedEnv`` under random actions at each batch size in ``copies``, every one in a fresh
    process: agent-steps/s (median of ``runs``), the speed-up over the smallest batch and the peak memory.

    A batch is refused at construction when its copies together need more than the memory budget by the env's own
    estimate (``batch_memory_estimate``); to measure, the bench raises ``memory_budget_gib`` to that
    estimate unless ``params`` sets it, and records both beside the measured peak."""

    out: dict[str, Any] = {}
    for env_id in targets:
        env = make(env_id, **params)
        env.close()
        out[env_id] = {}
        for m in copies:
            estimate = env.batch_memory_estimate(env.cfg, m)
            config = dict(params)
            config.setdefault(BUDGET_ARGUMENT, max(float(env.cfg[BUDGET_ARGUMENT]), estimate / GIB))
            samples = [measure_batched(env_id, config, m, seconds=seconds) for _ in range(runs)]
            result = dict(samples[len(samples) // 2])
            result["agent_steps_per_s"] = statistics.median(r["agent_steps_per_s"] for r in samples)
            result["env_steps_per_s"] = statistics.median(r["env_steps_per_s"] for r in samples)
            result["peak_rss_mb"] = max(r["peak_rss_mb"] for r in samples)
            result["batch_rss_mb"] = statistics.median(r["rss_after_mb"] - r["rss_before_mb"] for r in samples)
            result["estimate_gib"] = estimate / GIB
            result[BUDGET_ARGUMENT] = config[BUDGET_ARGUMENT]
            result["runs"] = runs
            base = out[env_id][str(copies[0])]["agent_steps_per_s"] if out[env_id] else result["agent_steps_per_s"]
            result["speedup_over_smallest"] = result["agent_steps_per_s"] / base
            out[env_id][str(m)] = result
            path = "one copy-axis world" if result["copy_axis_world"] else "copies in turn"
            print(
                f"batch  {env_id} M={m} ({path}, {result['steps']} steps timed): "
                f"{result['agent_steps_per_s']:,.0f} agent-steps/s "
                f"({result['speedup_over_smallest']:.2f}× M={copies[0]}), the batch holds {result['batch_rss_mb']:,.0f} MB "
                f"(estimate {result['estimate_gib']:.2f} GiB), process peak {result['peak_rss_mb']:,.0f} MB"
            )
    return out


def extras_section(targets: list[str]) -> dict[str, Any]:
    """Env-specific timings a reproduction module offers as ``benchmarks() -> {name: value}``."""

    out = {}
    for env_id in targets:
        measure = getattr(module(env_id), "benchmarks", None)
        if measure is None:
            continue
        out[env_id] = measure()
        for name, value in out[env_id].items():
            print(
                f"extra  {env_id} {name}: {value:.6g}"
                if isinstance(value, float)
                else f"extra  {env_id} {name}: {value}"
            )
    return out


# ------------------------------------------------------------------------------------------ the sweep runner
#: the benchmark sweep: seeded episodes of one env's default scripted policy, about 0.5–1 s each on one core,
#: as many as a reproduction's Monte-Carlo loop runs for one point of a figure
SWEEP_ENV = "mrcomm/AsyncCL-v0"
SWEEP_TASKS = 16
#: CPUs of the local Ray instance the benchmark starts: the two cores of the reference machine
RAY_CPUS = 2


def scripted_episode(env_id: str, policy: str, seed: int, params: dict | None = None) -> dict[str, float]:
    """The metrics of one seeded episode of a scripted baseline: a sweep task (importable by name on a worker)."""

    env = make(env_id, **(params or {}))
    try:
        return run_episode(env, make_policy(env_id, policy), seed)
    finally:
        env.close()


def no_op(index: int) -> int:
    """A task that does nothing: a sweep of these measures what a backend costs beyond the work itself."""
    return index


def episode_tasks(env_id: str = SWEEP_ENV, n_tasks: int = SWEEP_TASKS, params: dict | None = None) -> list:
    """``n_tasks`` seeded episodes (seeds 0, 1, …) of ``env_id``'s default scripted policy."""

    policy = default_policy(env_id)
    return [
        Task(
            f"{__name__}:scripted_episode",
            {"env_id": env_id, "policy": policy, "seed": s, "params": params or {}},
            f"seed={s}",
        )
        for s in range(n_tasks)
    ]


def sweep_section(
    env_id: str = SWEEP_ENV, n_tasks: int = SWEEP_TASKS, runs: int = 1, params: dict | None = None
) -> dict[str, Any]:
    """Wall time of one sweep (``n_tasks`` seeded episodes of ``env_id``) on ``--workers 1``, ``--workers 2`` and a
    local Ray instance with 2 CPUs, with the speed-up over ``--workers 1``; and each backend's overhead: the wall
    time of as many no-op tasks on a fresh backend (process or Ray worker start-up included). Ray's own start
    (``ray.init``, once per cluster) is reported apart. Each time is the median of ``runs``; every backend must
    return exactly the serial results.

    ``--workers 1`` runs in a fresh process, as the command does, so that it pays its imports once as every
    worker process does. The backends take turns within each run, so that a load that comes and goes on a
    shared machine falls on all of them alike; and for the local backends ``cores`` says how many cores the sweep got (CPU time of this
    process and its workers over wall time: 2 for two workers on two free cores, less when others compete)."""

    tasks = episode_tasks(env_id, n_tasks, params)
    no_ops = [Task(f"{__name__}:no_op", {"index": i}, f"no-op {i}") for i in range(n_tasks)]

    def cpu_seconds() -> float:
        # this process and its finished children (a process pool's workers are joined when its sweep ends)
        own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime

    def timed(runner: Runner, sweep: list) -> tuple[float, list, float]:
        cpu, start = cpu_seconds(), time.perf_counter()
        results = runner.map(sweep, desc=runner.backend)
        wall = time.perf_counter() - start
        return wall, results, (cpu_seconds() - cpu) / wall

    out: dict[str, Any] = {
        "env_id": env_id,
        "policy": tasks[0].kwargs["policy"],
        "params": params or {},
        "tasks": n_tasks,
        "runs": runs,
        # the machine's load when the benchmark began and ended: other processes on the same cores slow every
        # backend, and the parallel ones most
        "load_average_1min": os.getloadavg()[0],
        "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
    }
    # serially in a fresh process, as `mrcomm … --workers 1` runs: in this process, every run after the first
    # would find the env's modules imported, which the workers of a process pool never do
    local: dict[str, Any] = {"workers 1": _FreshSerial(), "workers 2": Runner(workers=2, progress=False)}
    samples: dict[str, dict[str, list]] = {name: {"sweep": [], "overhead": [], "cores": []} for name in local}
    results: dict[str, list] = {}
    ray_runs: list[dict] = []
    for _ in range(runs):
        for name, runner in local.items():  # a fresh process pool per map: the no-op sweep pays its start too
            samples[name]["overhead"].append(timed(runner, no_ops)[0])
            seconds, results[name], cores = timed(runner, tasks)
            samples[name]["sweep"].append(seconds)
            samples[name]["cores"].append(cores)
        ray_runs.append(_ray_run(tasks, no_ops, timed))
    serial = results["workers 1"]
    backends: dict[str, dict[str, Any]] = {}
    for name, sample in samples.items():
        backends[name] = {
            "sweep_s": statistics.median(sample["sweep"]),
            "overhead_s": statistics.median(sample["overhead"]),
            "cores": statistics.median(sample["cores"]),
            "identical_to_serial": _same(results[name], serial),
        }
    skipped = next((r["skipped"] for r in ray_runs if "skipped" in r), None)
    if skipped is not None:
        backends[f"ray {RAY_CPUS} CPUs"] = {"skipped": skipped}
    else:
        backends[f"ray {RAY_CPUS} CPUs"] = {
            "sweep_s": statistics.median(r["sweep_s"] for r in ray_runs),
            "overhead_s": statistics.median(r["overhead_s"] for r in ray_runs),
            "start_s": statistics.median(r["start_s"] for r in ray_runs),
            "identical_to_serial": all(_same(r["results"], serial) for r in ray_runs),
            "ray_version": ray_runs[0]["ray_version"],
        }
    out["backends"] = backends
    out["load_average_1min_end"] = os.getloadavg()[0]
    base = backends["workers 1"]["sweep_s"]
    for name, result in backends.items():
        if "sweep_s" in result:
            result["speedup"] = base / result["sweep_s"]
            print(
                f"sweep  {name}: {result['sweep_s']:.2f} s for {n_tasks} episodes of {env_id}, "
                f"speed-up {result['speedup']:.2f}, overhead {result['overhead_s']:.2f} s"
                + (f", {result['cores']:.2f} cores used" if "cores" in result else "")
                + (f" (+ {result['start_s']:.2f} s to start Ray)" if "start_s" in result else "")
                + ("" if result["identical_to_serial"] else "; RESULTS DIFFER FROM THE SERIAL RUN")
            )
        else:
            print(f"sweep  {name}: skipped ({result['skipped']})")
    print(
        f"sweep  load average (1 min): {out['load_average_1min']:.2f} at the start, {out['load_average_1min_end']:.2f} at the end"
    )
    return out


def _same(a: list, b: list) -> bool:
    """Identical numbers, compared as the JSON text they are written as: NaN equals NaN there, and -0.0 is not 0.0."""

    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def _serially(tasks: list[dict]) -> list:

    return Runner(workers=1, progress=False).map([Task(**task) for task in tasks])


class _FreshSerial:
    """``Runner(workers=1)`` in a new process for each sweep (spawned like a process pool's workers)."""

    backend = "serial"

    def map(self, tasks: list, desc: str = "tasks") -> list:

        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(1, mp_context=context, initializer=one_thread) as pool:
            return pool.submit(_serially, [asdict(task) for task in tasks]).result()


def _ray_run(tasks: list, no_ops: list, timed) -> dict[str, Any]:
    """One run of the Ray column of :func:`sweep_section`: a fresh local instance for each of the two sweeps, so
    that both start their worker processes as the first sweep of a command on a cluster does."""

    try:
        import ray
    except ImportError:
        return {"skipped": "ray is not installed (pip install 'mrcomm-env[ray]')"}
    if ray.is_initialized():
        return {"skipped": "a Ray session is already open in this process"}

    def fresh_ray() -> float:
        start = time.perf_counter()
        # address="local": a new instance of our own, never a cluster someone else runs on this machine; on
        # loopback; one BLAS thread per task as the runner asks of any cluster it connects to
        ray.init(
            address="local",
            num_cpus=RAY_CPUS,
            include_dashboard=False,
            _node_ip_address="127.0.0.1",
            log_to_driver=False,
            runtime_env={"env_vars": {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}},
        )
        return time.perf_counter() - start

    runner = Runner(ray="local", progress=False)  # uses the session fresh_ray opened
    try:
        start_s = fresh_ray()
        overhead_s = timed(runner, no_ops)[0]
        ray.shutdown()
        fresh_ray()
        sweep_s, results, _ = timed(runner, tasks)  # Ray's workers are not our children: no CPU count
    except Exception as exc:  # noqa: BLE001 — a benchmark reports a backend it cannot start, and goes on
        return {"skipped": f"Ray failed: {type(exc).__name__}: {exc}"}
    finally:
        if ray.is_initialized():
            ray.shutdown()
    return {
        "sweep_s": sweep_s,
        "overhead_s": overhead_s,
        "start_s": start_s,
        "results": results,
        "ray_version": ray.__version__,
    }
