"""The parts of ``mrcomm bench`` beyond env-steps/s: training throughput, documented limits, env-specific timings.

Speed and memory goals are checked here, by measurement, never by timed unit tests.
"""

from __future__ import annotations

from typing import Any

from mrcomm_env.registry import make


def train_section(targets: list[str], params: dict, timesteps: int, progress: bool = True) -> dict[str, Any]:
    """PPO agent-steps/s through the agent-slot VecEnv on every target and on mpe2's ``simple_spread_v3``, with
    the share of wall time spent in ``env.step`` (the goal: our envs train at least as fast as the reference)."""
    from tqdm.auto import tqdm

    from mrcomm_env.experiments.learning import train_throughput

    def reference():
        from mpe2 import simple_spread_v3

        return simple_spread_v3.parallel_env(N=3, continuous_actions=False)

    out = {"timesteps": timesteps, "reference": train_throughput([reference] * 4, timesteps)}
    print(f"train  reference simple_spread_v3: {_train_line(out['reference'])}")
    slots = out["reference"]["slots"]
    out["envs"] = {}
    for env_id in tqdm(targets, desc="PPO throughput", leave=False, disable=not progress):
        # about as many agent slots as the reference, so the policy's batch (and its cost per agent-step) match
        copies = max(1, round(slots / make(env_id, **params).n_agents))
        result = train_throughput([lambda env_id=env_id: make(env_id, **params)] * copies, timesteps)
        result["ratio_to_reference"] = result["agent_steps_per_s"] / out["reference"]["agent_steps_per_s"]
        out["envs"][env_id] = result
        print(f"train  {env_id}: {_train_line(result)}, ratio {result['ratio_to_reference']:.2f}")
    return out


def _train_line(result: dict) -> str:
    return (
        f"{result['agent_steps_per_s']:,.0f} PPO agent-steps/s ({result['slots']} slots), "
        f"{100 * result['env_step_share']:.0f} % of wall time in env.step"
    )


def limits_section(targets: list[str], seconds: float) -> dict[str, Any]:
    """Steps/s and peak memory of every documented maximum (``LIMIT_CONFIGS``), each in a fresh process."""
    from mrcomm_env.experiments.limits import limit_configs, measure_limit

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


def extras_section(targets: list[str]) -> dict[str, Any]:
    """Env-specific timings a reproduction module offers as ``benchmarks() -> {name: value}``."""
    from mrcomm_env.experiments.reproductions import module

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
    from baselines import make_policy
    from mrcomm_env.experiments.evaluation import run_episode

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
    from baselines import default_policy
    from mrcomm_env.experiments.sweep import Task

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
    return exactly the serial results."""
    import os
    import statistics
    import time

    from mrcomm_env.core import backend
    from mrcomm_env.experiments.sweep import Runner, Task

    tasks = episode_tasks(env_id, n_tasks, params)
    no_ops = [Task(f"{__name__}:no_op", {"index": i}, f"no-op {i}") for i in range(n_tasks)]

    def timed(runner: Runner, sweep: list) -> tuple[float, list]:
        start = time.perf_counter()
        results = runner.map(sweep, desc=runner.backend)
        return time.perf_counter() - start, results

    out: dict[str, Any] = {
        "env_id": env_id,
        "policy": tasks[0].kwargs["policy"],
        "params": params or {},
        "tasks": n_tasks,
        "runs": runs,
        "compiled_backend": backend.name(),
        # the machine's load when the benchmark began: other processes on the same cores slow every backend
        "load_average_1min": os.getloadavg()[0],
        "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "backends": {},
    }
    serial_results = None
    for workers in (1, 2):
        runner = Runner(workers=workers, progress=False)
        # a fresh process pool per map: the no-op sweep pays the pool's start as a real sweep does
        overheads, times = [], []
        for _ in range(runs):
            overheads.append(timed(runner, no_ops)[0])
            seconds, results = timed(runner, tasks)
            times.append(seconds)
        serial_results = results if workers == 1 else serial_results
        out["backends"][f"workers {workers}"] = {
            "sweep_s": statistics.median(times),
            "overhead_s": statistics.median(overheads),
            "identical_to_serial": results == serial_results,
        }
    out["backends"][f"ray {RAY_CPUS} CPUs"] = _ray_sweep(tasks, no_ops, runs, timed, serial_results)
    base = out["backends"]["workers 1"]["sweep_s"]
    for name, result in out["backends"].items():
        if "sweep_s" in result:
            result["speedup"] = base / result["sweep_s"]
            print(
                f"sweep  {name}: {result['sweep_s']:.2f} s for {n_tasks} episodes of {env_id}, "
                f"speed-up {result['speedup']:.2f}, overhead {result['overhead_s']:.2f} s"
                + (f" (+ {result['start_s']:.2f} s to start Ray)" if "start_s" in result else "")
                + ("" if result["identical_to_serial"] else "; RESULTS DIFFER FROM THE SERIAL RUN")
            )
        else:
            print(f"sweep  {name}: skipped ({result['skipped']})")
    return out


def _ray_sweep(tasks: list, no_ops: list, runs: int, timed, serial_results: list) -> dict[str, Any]:
    """The Ray column of :func:`sweep_section`: a fresh local instance for each measurement, so that both the
    no-op and the real sweep start their worker processes as the first sweep on a cluster does."""
    import statistics
    import time

    from mrcomm_env.experiments.sweep import Runner

    try:
        import ray
    except ImportError:
        return {"skipped": "ray is not installed (pip install 'mrcomm-env[ray]')"}

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

    if ray.is_initialized():
        return {"skipped": "a Ray session is already open in this process"}
    runner = Runner(ray="local", progress=False)  # uses the session fresh_ray opened
    starts, overheads, times = [], [], []
    try:
        for _ in range(runs):
            starts.append(fresh_ray())
            overheads.append(timed(runner, no_ops)[0])
            ray.shutdown()
            starts.append(fresh_ray())
            seconds, results = timed(runner, tasks)
            times.append(seconds)
            ray.shutdown()
    except Exception as exc:  # noqa: BLE001 — a benchmark reports a backend it cannot start, and goes on
        return {"skipped": f"Ray failed: {type(exc).__name__}: {exc}"}
    finally:
        if ray.is_initialized():
            ray.shutdown()
    return {
        "sweep_s": statistics.median(times),
        "overhead_s": statistics.median(overheads),
        "start_s": statistics.median(starts),
        "identical_to_serial": results == serial_results,
        "ray_version": ray.__version__,
    }
