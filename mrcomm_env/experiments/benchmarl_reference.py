"""Reference results on every mrcomm task from BenchMARL's own runner, and the page that shows them.

    make benchmark         # runs what is missing of the plan into docs/benchmark/runs/ (resumable, one run at a time)
    make benchmark-page    # docs/benchmark.md, its figures and the merged marl-eval JSON, from the runs' files
    python -m mrcomm_env.experiments.benchmarl_reference run --tasks MAPSYNC --algorithms ippo --seeds 0 1 2

**The plan.** IPPO and MAPPO on every task, IQL where the task acts in a Discrete space (every task but MultiHop,
whose BenchMARL layout acts in a Box), seeds 0, 1 and 2, each run 1,000,000 frames (``FRAMES``; one frame: one step
of one copy, all robots). The experiments are BenchMARL's ``Benchmark(...).get_experiments()`` with its default
algorithm, MLP model and experiment configs, changed only where this module says (``experiment_config``): the
budget, 100 copies per batch (``NUM_ENVS``, as one batched env of ``MrcommTask``; BenchMARL's default of 10 is sized
for VMAS on a GPU), an evaluation every tenth of the budget on 10 episodes (``EVAL_EPISODES``), the csv logger and
marl-eval's JSON, no rendering, and for the on-policy algorithms BenchMARL's own checkpoints (below).

**Resuming.** ``Benchmark.run_sequential`` runs every experiment in one go and keeps nothing of a run it did not
finish. Here each experiment of the benchmark runs on its own and, when it finishes, leaves two files in
``runs/<task>/<algorithm>/``: BenchMARL's marl-eval JSON of the run, verbatim (``seed_<s>.marl-eval.json``), and
this module's record of it (``seed_<s>.json``: frames, BenchMARL's and the wall clock's seconds, and the final
policy's held-out evaluation). Both are written atomically, the record last, so a run counts as done only when both
are whole. Each run is locked while it runs (``seed_<s>.lock``), so processes started together (``--jobs``, or a
second ``make benchmark``) share the plan without running a run twice.

A run killed midway (``kill -9``, Ctrl-C, the end of a working session) leaves its scratch folder. An on-policy run
(IPPO, MAPPO) writes a BenchMARL checkpoint there every twentieth of its budget (``CHECKPOINTS``: its networks,
optimizers, collector and counters; not the rollout buffer, which the next batch refills), keeping the newest two:
one of MultiHop's runs takes 7–10 hours here. The next invocation goes on from the newest checkpoint that loads
(``torch.load`` with ``weights_only``: a checkpoint is tensors and numbers, and nothing in it runs), with the
evaluations logged before it put back into the run's marl-eval JSON; its episodes then restart from the run's seed
(BenchMARL's checkpoint holds no env generator), so a resumed run is not the one an unbroken run would have been,
and its record says where it resumed (``resumed_at_frames``). An IQL run, and an on-policy run without a checkpoint,
starts again: IQL's replay buffer (up to 1,000,000 frames) would have to be saved with it, and those
runs took 19 to 102 minutes here (their records' ``wall_seconds``).

**Held-out evaluation.** BenchMARL's own evaluations (the curves) draw their episodes at random. The final policy of
each run, and the two references (``random`` and the paper's algorithm, the env's default baseline), also play 10
episodes seeded 100,000, 100,001, … (``HELDOUT_SEED``) that no run trained on: the return as BenchMARL counts it
(the robots' mean reward, summed over the episode), the paper's metric (the learned-against-scripted comparison's,
``agents/configs``) and the bits sent per robot. The normalised score is ``(return − random's) / (paper's −
random's)``: 0 is ``random``, 1 the paper's algorithm. When an env changes revision (its ``VERSION_HISTORY``, so
its episodes may differ), its references are played again and the earlier revision's are kept: a run is normalised
against the references of the revision it ran at (its record's ``env_revision``).

**The page.** rliable's interquartile mean of the normalised final scores across tasks and seeds, with stratified-
bootstrap 95 % intervals, its performance profile, the sample-efficiency curves from BenchMARL's evaluations, the
per-task table and the wall time of every run."""

from __future__ import annotations

import argparse
import fcntl
import json
import math
import multiprocessing
import os
import shutil
import sys
import time
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D
from rliable import library as rly
from rliable import metrics as rly_metrics
from rliable import plot_utils

from mrcomm_baselines import default_policy, make_policy
from mrcomm_env.core.sharded import WORKERS_VARIABLE
from mrcomm_env.core.stats import mean_ci95
from mrcomm_env.experiments.evaluation import evaluate_policy
from mrcomm_env.experiments.io import atomic_savefig, atomic_write_json, atomic_write_text
from mrcomm_env.experiments.runs import comparison_spec
from mrcomm_env.integrations import require
from mrcomm_env.integrations.benchmarl import ENV_ID_OF_TASK, MrcommTask
from mrcomm_env.integrations.torchrl_batched import GROUP, BatchedTorchRLEnv
from mrcomm_env.registry import env_class, env_revision

EXTRA = "benchmarl"
torch = require("torch", EXTRA)
_algorithms = require("benchmarl.algorithms", EXTRA)
_benchmark = require("benchmarl.benchmark", EXTRA)
_eval_results = require("benchmarl.eval_results", EXTRA)
_experiment = require("benchmarl.experiment", EXTRA)
_models = require("benchmarl.models", EXTRA)
_envs = require("torchrl.envs", EXTRA)

#: the algorithms of the plan: BenchMARL's configs by its own names
ALGORITHMS = {"ippo": "IppoConfig", "mappo": "MappoConfig", "iql": "IqlConfig"}
#: algorithms that need a Discrete action space
DISCRETE_ONLY = ("iql",)
SEEDS = (0, 1, 2)
#: frames per run: the issue's 1,000,000
FRAMES = 1_000_000
#: copies stepped as one batched env, for collection and (``evaluation_episodes`` of them) for evaluation
NUM_ENVS = 100
#: BenchMARL's evaluations per run: after the first batch, then every tenth of the budget (the curves' points)
EVALUATIONS = 10
EVAL_EPISODES = 10
#: an on-policy run's checkpoints over its budget: a killed run loses at most a twentieth of it (two twentieths where
#: the kill cut the newest checkpoint short)
CHECKPOINTS = 20
#: checkpoints kept: the newest may be cut short by a kill while it is written; the one before it then serves
KEEP_CHECKPOINTS = 2
#: the scratch folder's note of the arguments its checkpoints were made with (a changed plan starts afresh)
SCRATCH_PLAN = "plan.json"
#: the first held-out episode seed: above every seed a BenchMARL run or a tuning of ours drew
HELDOUT_SEED = 100_000
#: rliable's bootstrap repetitions and the seed of its generator (the page is the same on every machine)
BOOTSTRAP_REPS = 2_000
BOOTSTRAP_SEED = 0

OUT = Path("docs/benchmark")
PAGE = Path("docs/benchmark.md")
RUNS = "runs"
REFERENCES = "references.json"
MERGED = "marl-eval.json"
COST = "cost.json"


# ---------------------------------------------------------------------------------------------------- the plan
def algorithm_config(name: str):
    return getattr(_algorithms, ALGORITHMS[name]).get_from_yaml()


def plan(tasks: Sequence[str], algorithms: Sequence[str], seeds: Iterable[int]) -> list[tuple[str, str, int]]:
    """(task, algorithm, seed) of every run: IQL only where the task's actions are Discrete."""
    runs: list[tuple[str, str, int]] = []
    for task in tasks:
        discrete = MrcommTask[task].get_from_yaml().supports_discrete_actions()
        for algorithm in algorithms:
            if algorithm in DISCRETE_ONLY and not discrete:
                continue
            runs.extend((task, algorithm, int(seed)) for seed in seeds)
    return runs


def experiment_config(
    frames: int, frames_per_batch: int, num_envs: int, eval_episodes: int, folder: Path, checkpoints: bool = False
):
    """BenchMARL's default experiment config with the budget and this module's changes (module docstring); with
    ``checkpoints``, about :data:`CHECKPOINTS` of them over the budget, at whole batches."""
    config = _experiment.ExperimentConfig.get_from_yaml()
    config.max_n_frames = frames
    for kind in ("on_policy", "off_policy"):
        setattr(config, f"{kind}_collected_frames_per_batch", frames_per_batch)
        setattr(config, f"{kind}_n_envs_per_worker", num_envs)
    # evaluations at whole batches, about EVALUATIONS of them
    config.evaluation_interval = frames_per_batch * max(1, round(frames / frames_per_batch / EVALUATIONS))
    config.evaluation_episodes = eval_episodes
    config.render = False
    config.loggers = ["csv"]
    config.create_json = True
    config.checkpoint_interval = (
        frames_per_batch * max(1, round(frames / frames_per_batch / CHECKPOINTS)) if checkpoints else 0
    )
    config.keep_checkpoints_num = KEEP_CHECKPOINTS
    config.exclude_buffer_from_checkpoint = True  # on-policy: the next batch refills it
    config.checkpoint_at_end = False
    config.save_folder = str(folder)
    return config


def the_experiment(task: str, algorithm: str, seed: int, config):
    """The experiment of BenchMARL's ``Benchmark`` for one task, algorithm and seed (its MLP for policy and critic)."""
    benchmark = _benchmark.Benchmark(
        algorithm_configs=[algorithm_config(algorithm)],
        tasks=[MrcommTask[task].get_from_yaml()],
        seeds={seed},
        experiment_config=config,
        model_config=_models.MlpConfig.get_from_yaml(),
        critic_model_config=_models.MlpConfig.get_from_yaml(),
    )
    return next(benchmark.get_experiments())


# ---------------------------------------------------------------------------------------------------- evaluation
def paper_spec(env_id: str) -> dict:
    """The paper's metric as the learned-against-scripted comparison reads it (its name, its direction, bits per step
    or per episode)."""
    spec = comparison_spec(env_id)
    # not the comparison's "unfinished" value: it is the comparison's own horizon (e.g. 40 steps), and a task's
    # episodes may be longer; a time never reached counts as the episode's length (``counted_time``)
    return {key: spec[key] for key in ("metric", "lower_is_better", "bits_per") if key in spec}


def evaluate_benchmarl_policy(experiment, task: str, episodes: int) -> dict[str, list[float]]:
    """The experiment's final policy, acting deterministically, on the held-out episodes: per episode the return
    (the robots' mean reward summed), the paper's metric and the bits per robot (``evaluate_policy``'s keys)."""
    yaml_task = MrcommTask[task].get_from_yaml()
    env_id = ENV_ID_OF_TASK[task]
    spec = paper_spec(env_id)
    env = BatchedTorchRLEnv(env_id, episodes, seed=HELDOUT_SEED, **yaml_task.config)
    unreached_times = env_class(env_id).UNREACHED_TIMES
    returns = np.zeros(episodes)
    steps = np.zeros(episodes, dtype=int)
    finals: dict[int, dict[str, float]] = {}
    td = env.reset()
    with torch.no_grad(), _envs.set_exploration_type(_envs.ExplorationType.DETERMINISTIC):
        while len(finals) < episodes:
            td = experiment.policy(td)
            td, next_td = env.step_and_maybe_reset(td)
            running = np.array([i not in finals for i in range(episodes)])
            rewards = td.get(("next", GROUP, "reward")).squeeze(-1).mean(-1).numpy()
            returns[running] += rewards[running]
            steps[running] += 1
            for i, metrics in env.last_final_metrics.items():
                finals.setdefault(i, metrics)
            td = next_td
    env.close()
    out: dict[str, list[float]] = {"metric": [], "bits": [], "return": []}
    for i in range(episodes):
        value = float(finals[i][spec["metric"]])
        if spec["metric"] in unreached_times and not value >= 0:
            value = float(steps[i])  # never reached: the episode's length, as counted_time counts it
        out["metric"].append(value)
        per = max(int(steps[i]), 1) if spec.get("bits_per", "step") == "step" else 1
        out["bits"].append(float(finals[i]["bits_sent"]) / (env.n_agents * per))
        out["return"].append(float(returns[i]))
    return out


def reference_results(task: str, episodes: int) -> dict[str, dict[str, list[float]]]:
    """``random`` and the paper's algorithm on the held-out episodes of ``task``'s configuration."""
    env_id = ENV_ID_OF_TASK[task]
    config = dict(MrcommTask[task].get_from_yaml().config)
    seeds = list(range(HELDOUT_SEED, HELDOUT_SEED + episodes))
    spec = paper_spec(env_id)
    return {
        name: evaluate_policy(env_id, config, make_policy(env_id, name), seeds, spec)
        for name in ("random", default_policy(env_id))
    }


# ---------------------------------------------------------------------------------------------------- running
class RunLock:
    """``flock`` on a file holding the holder's pid. ``acquire(wait=False)`` returns False while another process
    holds it; the lock goes with the process, so a run killed with ``kill -9`` frees it."""

    def __init__(self, path: Path):
        self.path = path
        self.fd: int | None = None

    def acquire(self, wait: bool = False) -> bool:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            os.close(fd)
            return False
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        self.fd = fd
        return True

    def holder(self) -> str:
        try:
            return self.path.read_text().strip() or "?"
        except OSError:
            return "?"

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)  # closing releases the flock; the file stays (unlinking it would race a waiter)
            self.fd = None


def timer_rows(folder: Path, timer: str) -> list[float]:
    """BenchMARL's ``timers/<timer>_time`` of each iteration that logged it (its csv logger's file), in iteration
    order. A resumed run appends to the file and logs again the iterations its killed attempt made after its last
    checkpoint: each iteration counts once, as its last row gives it (the one the finished run is made of)."""
    by_step: dict[int, float] = {}
    for path in folder.glob(f"**/scalars/timers_{timer}_time.csv"):
        for line in path.read_text().splitlines():
            if "," in line:
                step, value = line.split(",")[:2]
                by_step[int(float(step))] = float(value)
    return [by_step[step] for step in sorted(by_step)]


def _timer_total(folder: Path, timer: str) -> float:
    """BenchMARL's ``timers/<timer>_time`` summed over the run's iterations."""
    return float(sum(timer_rows(folder, timer)))


def run_paths(out: Path, task: str, algorithm: str, seed: int) -> tuple[Path, Path]:
    """(record, marl-eval JSON) of one run."""
    folder = out / RUNS / task.lower() / algorithm
    return folder / f"seed_{seed}.json", folder / f"seed_{seed}.marl-eval.json"


def loadable_checkpoint(scratch: Path) -> Path | None:
    """The newest BenchMARL checkpoint in ``scratch`` that loads as tensors and numbers alone (``weights_only``), or
    None; the others are deleted (a damaged one, and older ones BenchMARL no longer rotates after a resume)."""
    checkpoints = sorted(scratch.glob("*/checkpoints/checkpoint_*.pt"), key=lambda p: int(p.stem.split("_")[-1]))
    chosen = None
    for path in reversed(checkpoints):
        try:
            torch.load(path, map_location="cpu", weights_only=True)
        except Exception as error:  # noqa: BLE001 - cut short by a kill: any unpickling or reading error
            print(f"benchmark: {path.name} does not load ({type(error).__name__}); trying the one before", flush=True)
            continue
        chosen = path
        break
    for path in checkpoints:
        if path != chosen:
            path.unlink()
    return chosen


def earlier_evaluations(checkpoint: Path) -> dict | None:
    """The marl-eval JSON that the attempt which wrote ``checkpoint`` kept beside it (BenchMARL's
    ``<experiment>/<experiment>.json``), or None where it is missing or cut short by a kill (BenchMARL writes it in
    place): without it the run's earlier curve points would be lost, so the run starts afresh."""
    folder = checkpoint.parent.parent
    try:
        return json.loads((folder / f"{folder.name}.json").read_text())
    except (OSError, ValueError):
        return None


def restore_evaluations(experiment, earlier: dict) -> None:
    """Put the evaluations an earlier attempt logged up to the restored checkpoint (``earlier``, its marl-eval JSON)
    back into the experiment's marl-eval writer: BenchMARL starts it empty and rewrites the whole file at its next
    evaluation."""
    writer = experiment.logger.json_writer
    runs = earlier[experiment.environment_name][experiment.task_name][experiment.algorithm_name]
    run = runs[f"seed_{experiment.seed}"]
    kept = {k: v for k, v in run.items() if k.startswith("step_") and v["step_count"] <= experiment.total_frames}
    writer.run_data.update(kept)
    best = writer.run_data["absolute_metrics"]
    for step in kept.values():
        for metric, values in step.items():
            if metric != "step_count" and len(values):
                best[metric] = [max([max(values), *best.get(metric, [])])]


def scratch_for(scratch: Path, plan_args: dict, resumable: bool) -> tuple[Path | None, dict, list[int]]:
    """(the checkpoint to go on from in ``scratch``, the marl-eval JSON logged before it, the frames at which earlier
    attempts resumed), or (None, {}, []) after clearing the folder for a fresh start: a scratch folder is resumed only
    when its checkpoints were made with the same arguments (its :data:`SCRATCH_PLAN` note)."""
    note_path = scratch / SCRATCH_PLAN
    note = json.loads(note_path.read_text()) if resumable and note_path.exists() else {}
    checkpoint = loadable_checkpoint(scratch) if note.get("plan") == plan_args else None
    earlier = earlier_evaluations(checkpoint) if checkpoint is not None else None
    if checkpoint is None or earlier is None:
        shutil.rmtree(scratch, ignore_errors=True)  # what a killed attempt left
        scratch.mkdir(parents=True)
        atomic_write_json(note_path, {"plan": plan_args, "resumed_at_frames": []})
        return None, {}, []
    return checkpoint, earlier, list(note["resumed_at_frames"])


def run_one(
    out: Path, task: str, algorithm: str, seed: int, frames: int, frames_per_batch: int, num_envs: int, episodes: int
) -> dict:
    """Run one experiment of the benchmark in a scratch folder, from its newest checkpoint if a killed attempt left
    one (module docstring), evaluate its final policy on the held-out episodes and keep its two files; returns the
    record."""
    record_path, json_path = run_paths(out, task, algorithm, seed)
    scratch = record_path.with_suffix(".scratch")
    resumable = bool(algorithm_config(algorithm).on_policy())
    plan_args = {"frames": frames, "frames_per_batch": frames_per_batch, "num_envs": num_envs, "episodes": episodes}
    checkpoint, earlier, resumed_at = scratch_for(scratch, plan_args, resumable)
    config = experiment_config(frames, frames_per_batch, num_envs, episodes, scratch, checkpoints=resumable)
    config.restore_file = None if checkpoint is None else str(checkpoint)
    experiment = the_experiment(task, algorithm, seed, config)
    if checkpoint is not None:
        restore_evaluations(experiment, earlier)
        resumed_at.append(int(experiment.total_frames))
        atomic_write_json(scratch / SCRATCH_PLAN, {"plan": plan_args, "resumed_at_frames": resumed_at})
        print(f"benchmark: {task} {algorithm} seed {seed} goes on from {checkpoint.name}", flush=True)
    # the iterations kept from earlier attempts, as BenchMARL timed them (0 on a fresh start)
    restored_seconds = float(experiment.total_time)
    start = time.perf_counter()
    experiment.run()
    wall = time.perf_counter() - start + restored_seconds
    marl_eval = json.loads((experiment.folder_name / f"{experiment.name}.json").read_text())
    heldout = evaluate_benchmarl_policy(experiment, task, episodes)
    record = {
        "task": task,
        "env_id": ENV_ID_OF_TASK[task],
        "env_config": dict(MrcommTask[task].get_from_yaml().config),
        "algorithm": algorithm,
        "seed": seed,
        "frames": int(experiment.total_frames),
        "frames_per_batch": frames_per_batch,
        "num_envs": num_envs,
        "iterations": int(experiment.n_iters_performed),
        # a resumed run: this attempt's wall clock plus BenchMARL's own time of the iterations it went on from
        "wall_seconds": wall,
        "resumed_at_frames": resumed_at,
        "benchmarl_seconds": float(experiment.total_time),
        **{f"{timer}_seconds": _timer_total(scratch, timer) for timer in ("collection", "training", "evaluation")},
        "torch_threads": torch.get_num_threads(),
        "heldout_seed": HELDOUT_SEED,
        "heldout": heldout,
        "env_revision": env_revision(ENV_ID_OF_TASK[task]),  # the page flags runs the env has changed since
    }
    json_path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(json_path, marl_eval, indent=1)
    atomic_write_json(record_path, record, indent=1)  # last: the run counts as done from here
    shutil.rmtree(scratch, ignore_errors=True)
    return record


def ensure_references(out: Path, tasks: Sequence[str], episodes: int) -> dict:
    """``references.json``: ``random`` and the paper's algorithm on each task's held-out episodes, computed for the
    tasks that lack them or whose env has changed revision since (one process at a time).

    A task's record is its env's current revision; the records of earlier revisions stay under ``"earlier"``
    (revision → record), since runs recorded at a revision are scored against that revision's references
    (:func:`reference_of`). A record that names no revision is computed again: which episodes it played is unknown."""
    lock = RunLock(out / "references.lock")
    lock.acquire(wait=True)
    try:
        path = out / REFERENCES
        references = json.loads(path.read_text()) if path.exists() else {}
        for task in tasks:
            env_id = ENV_ID_OF_TASK[task]
            revision = env_revision(env_id)
            old = references.get(task)
            if old is not None and old["episodes"] == episodes and old.get("env_revision") == revision:
                continue
            earlier = dict(old.get("earlier", {})) if old is not None else {}
            if old is not None and old.get("env_revision") not in (None, revision):
                earlier[old["env_revision"]] = {key: value for key, value in old.items() if key != "earlier"}
            references[task] = {
                "episodes": episodes,
                "heldout_seed": HELDOUT_SEED,
                "env_revision": revision,
                **paper_spec(env_id),
                "paper_policy": default_policy(env_id),
                "policies": reference_results(task, episodes),
                **({"earlier": earlier} if earlier else {}),
            }
            atomic_write_json(path, references, indent=1)
        return references
    finally:
        lock.release()


def run_plan(
    out: Path,
    tasks: Sequence[str],
    algorithms: Sequence[str],
    seeds: Sequence[int],
    frames: int,
    frames_per_batch: int,
    num_envs: int,
    episodes: int,
) -> list[tuple[str, str, int]]:
    """Every run of the plan that has no record yet and that no other process is running, in order, after the
    references; returns the runs made. Several processes may work through one plan at once (``--jobs``)."""
    ensure_references(out, tasks, episodes)
    made = []
    todo = [run for run in plan(tasks, algorithms, seeds) if not run_paths(out, *run)[0].exists()]
    for k, (task, algorithm, seed) in enumerate(todo):
        record_path = run_paths(out, task, algorithm, seed)[0]
        lock = RunLock(record_path.with_suffix(".lock"))
        if not lock.acquire():
            print(f"benchmark: {task} {algorithm} seed {seed} is being run by pid {lock.holder()}", flush=True)
            continue
        try:
            if record_path.exists():  # another process finished it since the list was made
                continue
            print(f"benchmark: run {k + 1}/{len(todo)}: {task} {algorithm} seed {seed}", flush=True)
            record = run_one(out, task, algorithm, seed, frames, frames_per_batch, num_envs, episodes)
            print(
                f"benchmark: {task} {algorithm} seed {seed}: {record['frames']:,} frames in"
                f" {record['wall_seconds']:.0f} s, held-out return {np.mean(record['heldout']['return']):.4g}",
                flush=True,
            )
            made.append((task, algorithm, seed))
        finally:
            lock.release()
    return made


def measure_cost(
    out: Path, tasks: Sequence[str], algorithms: Sequence[str], frames_per_batch: int, num_envs: int, episodes: int
) -> dict:
    """What one run of each (task, algorithm) of the plan costs here: two iterations of the real experiment (its
    configs, ``frames_per_batch`` and ``num_envs``), the second one's collection and training (the first warms the
    compiled kernels), and BenchMARL's evaluation; projected to ``FRAMES`` frames with ``EVALUATIONS``
    evaluations. Written to ``cost.json`` (the page's "What the plan costs")."""
    cost: dict = {}
    for task, algorithm, _ in plan(tasks, algorithms, [0]):
        scratch = out / f"cost_{task.lower()}_{algorithm}.scratch"
        shutil.rmtree(scratch, ignore_errors=True)
        scratch.mkdir(parents=True)
        config = experiment_config(2 * frames_per_batch, frames_per_batch, num_envs, episodes, scratch)
        experiment = the_experiment(task, algorithm, 0, config)
        start = time.perf_counter()
        experiment.run()
        wall = time.perf_counter() - start
        timers = {timer: timer_rows(scratch, timer) for timer in ("collection", "training", "evaluation")}
        iteration = timers["collection"][-1] + timers["training"][-1]
        evaluation = float(np.mean(timers["evaluation"]))
        iterations = math.ceil(FRAMES / frames_per_batch)
        cost.setdefault(task, {})[algorithm] = entry = {
            "frames_per_batch": frames_per_batch,
            "num_envs": num_envs,
            "iteration_seconds": iteration,
            "collection_seconds": timers["collection"][-1],
            "training_seconds": timers["training"][-1],
            "evaluation_seconds": evaluation,
            "probe_wall_seconds": wall,
            "projected_run_hours": (iterations * iteration + EVALUATIONS * evaluation) / 3600,
            "torch_threads": torch.get_num_threads(),
        }
        _merge_cost(out, task, algorithm, entry)
        shutil.rmtree(scratch, ignore_errors=True)
        print(
            f"benchmark cost: {task} {algorithm}: {iteration:.1f} s per iteration, "
            f"{cost[task][algorithm]['projected_run_hours']:.2f} h per run of {FRAMES:,} frames",
            flush=True,
        )
    return cost


def _merge_cost(out: Path, task: str, algorithm: str, entry: dict) -> None:
    """Add one measurement to ``cost.json``, under a lock: two ``cost`` processes may measure different tasks."""
    lock = RunLock(out / "cost.lock")
    lock.acquire(wait=True)
    try:
        path = out / COST
        cost = json.loads(path.read_text()) if path.exists() else {}
        cost.setdefault(task, {})[algorithm] = entry
        atomic_write_json(path, cost, indent=1)
    finally:
        lock.release()


def run_jobs(jobs: int, *args) -> list[tuple[str, str, int]]:
    """``run_plan(*args)`` in ``jobs`` processes at once (one torch thread each), which share the plan's runs."""
    if jobs == 1:
        return run_plan(*args)
    context = multiprocessing.get_context("spawn")  # a fresh interpreter each: no torch state forked
    with ProcessPoolExecutor(jobs, mp_context=context, initializer=_one_thread) as pool:
        futures = [pool.submit(run_plan, *args) for _ in range(jobs)]
        return [run for future in futures for run in future.result()]


def _one_thread() -> None:
    os.environ["OMP_NUM_THREADS"] = "1"
    os.environ[WORKERS_VARIABLE] = "1"  # the jobs share the cores: each steps its copies itself (core.sharded)
    torch.set_num_threads(1)


# ---------------------------------------------------------------------------------------------------- the page
def load_runs(out: Path) -> list[dict]:
    """Every finished run's record, with its marl-eval JSON under ``"marl_eval"``. Each names the env revision it
    was recorded at (``env_revision``), by which it is scored: a record without one is refused, naming it."""
    records = []
    for record_path in sorted((out / RUNS).glob("*/*/seed_*[0-9].json")):
        record = json.loads(record_path.read_text())
        if "env_revision" not in record:
            raise ValueError(f"{record_path}: the run record names no 'env_revision' (the env revision it ran at)")
        record["marl_eval"] = json.loads(record_path.with_suffix(".marl-eval.json").read_text())
        records.append(record)
    return records


def normalised(value: float | np.ndarray, random_return: float, paper_return: float):
    """0 at ``random``'s return, 1 at the paper's algorithm's."""
    return (np.asarray(value, dtype=float) - random_return) / (paper_return - random_return)


def reference_of(references: dict, task: str, revision: str) -> dict:
    """``task``'s references at its env's ``revision``: the current record, or the one of an earlier revision that
    ``ensure_references`` kept. A run recorded at a revision with no record gets the current one (the page names
    such runs, ``_revision_note``)."""
    current = references[task]
    if current["env_revision"] == revision:
        return current
    return current.get("earlier", {}).get(revision, current)


def reference_returns(references: dict, task: str, revision: str) -> tuple[float, float]:
    """The mean held-out returns of ``random`` and of the paper's algorithm on ``task`` at ``revision``."""
    reference = reference_of(references, task, revision)
    policies = reference["policies"]
    paper = policies[reference["paper_policy"]]
    return float(np.mean(policies["random"]["return"])), float(np.mean(paper["return"]))


def run_score(record: dict, references: dict, values=None):
    """A run's held-out mean return (or ``values``), normalised by the references of the revision it ran at."""
    random_return, paper_return = reference_returns(references, record["task"], record["env_revision"])
    value = np.mean(record["heldout"]["return"]) if values is None else values
    return normalised(value, random_return, paper_return)


def curve(record: dict) -> tuple[np.ndarray, np.ndarray]:
    """(frames, mean evaluation return) of BenchMARL's evaluations in the run's marl-eval JSON."""
    run = next(iter(next(iter(next(iter(record["marl_eval"].values())).values())).values()))
    run = next(iter(run.values()))
    steps = sorted((k for k in run if k.startswith("step_")), key=lambda k: int(k.split("_")[1]))
    return (
        np.array([run[k]["step_count"] for k in steps], dtype=float),
        np.array([np.mean(run[k]["return"]) for k in steps], dtype=float),
    )


def score_matrices(records: list[dict], references: dict) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
    """algorithm → (seeds × tasks) normalised held-out final scores, and algorithm → those tasks.

    rliable's stratified bootstrap needs the same runs on every task, so each algorithm takes one set of seeds and
    the tasks that have all of them: of the seed sets its tasks have, the one that keeps the most runs (more seeds
    first on a tie). A task with fewer of its seeds is left out of that algorithm's matrix (:func:`left_out`) rather
    than cutting every task down to its seeds, which reduced IQL to one run a task and a zero-width interval."""
    by_algorithm: dict[str, dict[str, dict[int, float]]] = {}
    for record in records:
        score = float(run_score(record, references))
        by_algorithm.setdefault(record["algorithm"], {}).setdefault(record["task"], {})[record["seed"]] = score
    matrices, tasks_of = {}, {}
    for algorithm, per_task in by_algorithm.items():
        seed_sets = {frozenset(scores) for scores in per_task.values()}
        covering = {s: sorted(t for t, scores in per_task.items() if s <= scores.keys()) for s in seed_sets}
        seeds, tasks = max(covering.items(), key=lambda c: (len(c[0]) * len(c[1]), len(c[0]), sorted(c[0])))
        matrices[algorithm] = np.array([[per_task[t][s] for t in tasks] for s in sorted(seeds)])
        tasks_of[algorithm] = tasks
    return matrices, tasks_of


def left_out(records: list[dict], tasks_of: dict[str, list[str]]) -> dict[str, list[str]]:
    """algorithm → the tasks it has runs on that its score matrix leaves out (too few of its seeds yet)."""
    ran: dict[str, set[str]] = {}
    for record in records:
        ran.setdefault(record["algorithm"], set()).add(record["task"])
    return {a: sorted(ran[a] - set(tasks_of.get(a, []))) for a in ran if ran[a] - set(tasks_of.get(a, []))}


def _fmt(values: Sequence[float], digits: int = 4) -> str:
    mean, half = mean_ci95(list(values))
    if len(values) < 2 or not math.isfinite(half):
        return f"{mean:.{digits}g}"
    if len(set(values)) == 1:
        return f"{mean:.{digits}g} ± 0"  # equal values: the interval is 0, not the rounding noise of its sum
    return f"{mean:.{digits}g} ± {half:.2g}"


def write_page(out: Path = OUT, page: Path = PAGE) -> Path:
    """docs/benchmark.md, its figures (beside the runs) and the merged marl-eval JSON, from the runs' files."""
    matplotlib.use("Agg")

    records = load_runs(out)
    references = json.loads((out / REFERENCES).read_text()) if (out / REFERENCES).exists() else {}
    merged = _eval_results.load_and_merge_json_dicts(
        [str(p) for p in sorted((out / RUNS).glob("*/*/seed_*.marl-eval.json"))]
    )
    atomic_write_json(out / MERGED, merged, indent=1)
    figures_link = Path(os.path.relpath(out, page.parent))  # the figures sit beside the runs, linked from the page
    lines = [
        "# Reference results: BenchMARL on every task",
        "",
        "<!-- generated by `make benchmark-page` (mrcomm_env/experiments/benchmarl_reference.py); do not edit -->",
        "",
        _docstring_section(),
        "",
        "Rerun what is missing: `make benchmark`. Regenerate this page from the committed JSON: `make benchmark-page`.",
        f"The runs' files are `{out}/{RUNS}/`; BenchMARL's marl-eval JSON of all of them, merged: `{out}/{MERGED}`.",
        "",
    ]
    expected = plan(list(ENV_ID_OF_TASK), list(ALGORITHMS), SEEDS)
    done = {(r["task"], r["algorithm"], r["seed"]) for r in records}
    missing = [run for run in expected if run not in done]
    lines += [f"**Runs:** {len(done)} of the plan's {len(expected)} have finished."]
    if missing:
        lines[-1] += (
            f" Missing: {', '.join(f'{t.lower()}/{a}/seed {s}' for t, a, s in missing)}. Every figure below is over"
            " the finished runs only."
        )
    lines += [""]
    lines += _cost_section(out, done)
    if records:
        lines += _task_tables(records, references)
        lines += _aggregate_section(records, references, out, figures_link)
        lines += _curves_section(records, references, out, figures_link)
        lines += _wall_time_table(records)
    atomic_write_text(page, "\n".join(lines) + "\n")
    return page


def _cost_section(out: Path, done: set[tuple[str, str, int]]) -> list[str]:
    """The plan's cost on this machine, from ``cost.json`` (``benchmarl_reference cost``), when it was measured."""
    if not (out / COST).exists():
        return []
    cost = json.loads((out / COST).read_text())
    lines = [
        "## What the plan costs",
        "",
        f"Measured here by `python -m mrcomm_env.experiments.benchmarl_reference cost` (in `.venv-benchmarl`, one"
        " process with one torch thread, nothing else running): two iterations of each run's experiment, the second"
        " one's collection and"
        f" training, and BenchMARL's evaluation; projected to {FRAMES:,} frames and {EVALUATIONS} evaluations a"
        " run. Training is BenchMARL's default update: on-policy, 45 passes over each 6,000-frame batch in minibatches"
        " of 400 frames (675 optimizer steps); IQL, 1,000 optimizer steps of 128 frames per batch; a 256 × 256 MLP."
        " A frame holds every robot, so the on-policy update's rows grow with the team.",
        "",
        "| task | algorithm | collection (s/iteration) | training (s/iteration) | evaluation (s) | hours per run"
        " | runs left | hours left |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    total = 0.0
    for task, per_algorithm in cost.items():
        for algorithm, c in per_algorithm.items():
            left = sum((task, algorithm, seed) not in done for seed in SEEDS)
            total += left * c["projected_run_hours"]
            lines.append(
                f"| {task.lower()} | {algorithm} | {c['collection_seconds']:.1f} | {c['training_seconds']:.1f}"
                f" | {c['evaluation_seconds']:.1f} | {c['projected_run_hours']:.2f} | {left}"
                f" | {left * c['projected_run_hours']:.1f} |"
            )
    unmeasured = sorted(
        {(t, a) for t, a, _ in plan(list(ENV_ID_OF_TASK), list(ALGORITHMS), SEEDS)}
        - {(t, a) for t, per_algorithm in cost.items() for a in per_algorithm}
    )
    lines += [
        "",
        f"**Left to run: {total:.0f} hours** of one process on this machine for the runs measured above, about half"
        " that with `--jobs 2` where memory allows.",
    ]
    if unmeasured:
        lines[-1] += " Not measured yet: " + ", ".join(f"{t.lower()}/{a}" for t, a in unmeasured) + "."
    lines += [""]
    return lines


def _tasks_and_algorithms(records: list[dict]) -> tuple[list[str], list[str]]:
    tasks = sorted({r["task"] for r in records}, key=list(ENV_ID_OF_TASK).index)
    return tasks, [a for a in ALGORITHMS if any(r["algorithm"] == a for r in records)]


def _task_tables(records: list[dict], references: dict) -> list[str]:
    lines = [
        "## Per task",
        "",
        f"Held-out episodes (seeds from {HELDOUT_SEED:,}): the return as BenchMARL counts it, normalised (0 = `random`,"
        " 1 = the paper's algorithm), the paper's metric and the bits per robot; mean ± 95 % interval over training"
        " seeds (over episodes for the scripted rows). Wall time: one run on this machine (2 cores, one torch thread"
        " per run), BenchMARL's evaluations included.",
        "",
    ]
    tasks, algorithms = _tasks_and_algorithms(records)
    for task in tasks:
        ref = references[task]
        arrow = "lower is better" if ref.get("lower_is_better") else "higher is better"
        config = next(r for r in records if r["task"] == task)["env_config"]
        lines += [
            f"### {ENV_ID_OF_TASK[task]}",
            "",
            f"Config: `{json.dumps(config)}`. Paper metric: `{ref['metric']}` ({arrow}).",
            "",
            f"| policy | seeds | return | normalised | `{ref['metric']}` | bits per robot | frames | wall time per run |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |",
        ]
        # the scripted rows of the current revision, then of each earlier one that some run was recorded at
        shown = [ref] + [
            ref["earlier"][revision]
            for revision in sorted({r["env_revision"] for r in records if r["task"] == task})
            if revision in ref.get("earlier", {})
        ]
        for reference in shown:
            for name in ("random", reference["paper_policy"]):
                values = reference["policies"][name]
                notes = ["paper"] if name == reference["paper_policy"] else []
                notes += [] if reference is ref else [reference["env_revision"]]
                label = f"`{name}`" + (f" ({', '.join(notes)})" if notes else "")
                random_and_paper = reference_returns({task: reference}, task, reference["env_revision"])
                score = float(normalised(np.mean(values["return"]), *random_and_paper))
                lines.append(
                    f"| {label} | – | {_fmt(values['return'])} | {score:.3g} | {_fmt(values['metric'])}"
                    f" | {_fmt(values['bits'])} | – | – |"
                )
        for algorithm in algorithms:
            runs = [r for r in records if r["task"] == task and r["algorithm"] == algorithm]
            if not runs:
                continue
            returns = [float(np.mean(r["heldout"]["return"])) for r in runs]
            scores = [float(run_score(r, references)) for r in runs]
            lines.append(
                f"| {algorithm.upper()} (BenchMARL) | {len(runs)} | {_fmt(returns)} | {_fmt(scores, 3)}"
                f" | {_fmt([float(np.mean(r['heldout']['metric'])) for r in runs])}"
                f" | {_fmt([float(np.mean(r['heldout']['bits'])) for r in runs])}"
                f" | {runs[0]['frames']:,} | {_fmt([r['wall_seconds'] / 60 for r in runs], 3)} min |"
            )
        runs = [r for r in records if r["task"] == task]
        lines += _revision_note(task, runs, ref)
        if len(runs) > 1 and all(r["heldout"] == runs[0]["heldout"] for r in runs):
            lines += [
                "",
                f"All {len(runs)} runs' final policies play the {len(runs[0]['heldout']['return'])} held-out episodes"
                " identically (the same return, metric and bits in every episode): whatever the algorithm and seed,"
                " training ended at the same deterministic behaviour on them.",
            ]
        lines += [""]
    return lines


def _revision_note(task: str, runs: list[dict], reference: dict) -> list[str]:
    """A task's runs and scripted rows recorded at an earlier revision of its env (their ``env_revision``): which,
    and at which revision, since they played other episodes."""
    env_id = ENV_ID_OF_TASK[task]
    current = env_revision(env_id)
    earlier: dict[str, list[str]] = {}
    for run in runs:
        if run["env_revision"] != current:
            earlier.setdefault(run["env_revision"], []).append(f"{run['algorithm'].upper()} seed {run['seed']}")
    if reference["env_revision"] != current:
        earlier.setdefault(reference["env_revision"], []).append("the `random` and paper rows")
    if not earlier:
        return []
    parts = "; ".join(f"{', '.join(names)} at {revision}" for revision, names in sorted(earlier.items()))
    note = (
        f"Recorded before {env_id}'s {current} (CHANGELOG): {parts}. Where the revisions' episodes differ, these rows"
        " played other episodes than a run at the current revision would."
    )
    kept = sorted(set(earlier) & set(reference.get("earlier", {})))
    if kept:
        note += (
            f" Their scripted rows at {', '.join(kept)} are kept (labelled with it above), and a run recorded there is"
            " normalised against them: `random` and the paper's algorithm on that revision's episodes."
        )
    return ["", note]


def _aggregate_section(records: list[dict], references: dict, out: Path, figures_link: Path) -> list[str]:
    matrices, tasks_of = score_matrices(records, references)
    rng = np.random.RandomState(BOOTSTRAP_SEED)
    point, interval = rly.get_interval_estimates(
        matrices, lambda scores: np.array([rly_metrics.aggregate_iqm(scores)]), reps=BOOTSTRAP_REPS, random_state=rng
    )
    lines = [
        "## Across tasks",
        "",
        "rliable's interquartile mean (IQM) of the normalised held-out final scores over every run (seeds × tasks),"
        f" with stratified-bootstrap 95 % intervals ({BOOTSTRAP_REPS:,} repetitions, seed {BOOTSTRAP_SEED}).",
        "",
        "| algorithm | tasks | runs | IQM | 95 % interval |",
        "| --- | --- | --- | --- | --- |",
    ]
    for algorithm, matrix in matrices.items():
        low, high = interval[algorithm][:, 0]
        lines.append(
            f"| {algorithm.upper()} | {', '.join(t.lower() for t in tasks_of[algorithm])} | {matrix.size}"
            f" | {point[algorithm][0]:.3g} | [{low:.3g}, {high:.3g}] |"
        )
    missing = left_out(records, tasks_of)
    if missing:
        lines += [
            "",
            "Each algorithm's runs are one set of seeds on every task it counts (the stratified bootstrap resamples "
            "runs within each task). Left out until they have those seeds: "
            + "; ".join(f"{a.upper()} on {', '.join(t.lower() for t in ts)}" for a, ts in missing.items())
            + ".",
        ]
    all_scores = np.concatenate([m.ravel() for m in matrices.values()])
    taus = np.linspace(min(0.0, float(all_scores.min())), max(1.5, float(all_scores.max())), 101)
    np.random.seed(BOOTSTRAP_SEED)  # create_performance_profile bootstraps with numpy's global generator
    profiles, profile_cis = rly.create_performance_profile(matrices, taus, reps=BOOTSTRAP_REPS)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    colors = dict(zip(profiles, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    plot_utils.plot_performance_profiles(profiles, taus, performance_profile_cis=profile_cis, ax=ax, colors=colors)
    ax.axvline(1.0, color="grey", lw=0.8, ls="--")
    ax.legend(
        handles=[Line2D([], [], color=colors[a], label=a.upper()) for a in profiles], loc="upper right", fontsize=9
    )
    fig.tight_layout()
    atomic_savefig(fig, out / "profile.png", dpi=110)
    plt.close(fig)
    return lines + [
        "",
        "Performance profile: the fraction of runs whose normalised score exceeds τ (bands: 95 % bootstrap"
        " intervals; dashed: the paper's algorithm).",
        "",
        f"![performance profile]({figures_link / 'profile.png'})",
        "",
    ]


def _curves_section(records: list[dict], references: dict, out: Path, figures_link: Path) -> list[str]:
    tasks, algorithms = _tasks_and_algorithms(records)
    fig, axes = plt.subplots(1, len(tasks), figsize=(3.2 * len(tasks), 3.0), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        for algorithm in algorithms:
            runs = [r for r in records if r["task"] == task and r["algorithm"] == algorithm]
            if not runs:
                continue
            curves = [curve(r) for r in runs]
            length = min(len(c[0]) for c in curves)
            frames = curves[0][0][:length]
            scores = np.array([run_score(r, references, c[1][:length]) for r, c in zip(runs, curves, strict=True)])
            ax.plot(frames, scores.mean(0), label=algorithm.upper())
            ax.fill_between(frames, scores.min(0), scores.max(0), alpha=0.2)
        ax.axhline(1.0, color="grey", lw=0.8, ls="--")
        ax.axhline(0.0, color="grey", lw=0.8, ls=":")
        ax.set_title(ENV_ID_OF_TASK[task], fontsize=9)
        ax.set_xlabel("frames")
    axes[0][0].set_ylabel("normalised return")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    atomic_savefig(fig, out / "curves.png", dpi=110)
    plt.close(fig)
    return [
        "## Sample efficiency",
        "",
        "BenchMARL's own evaluations during training (random episodes, its `evaluation_episodes`), normalised by the"
        " held-out references: the mean over seeds, the band from the lowest to the highest seed; dashed: the"
        " paper's algorithm, dotted: `random`.",
        "",
        f"![sample-efficiency curves]({figures_link / 'curves.png'})",
        "",
    ]


def _wall_time_table(records: list[dict]) -> list[str]:
    lines = [
        "## Wall time",
        "",
        "Seconds per run on this machine: the wall clock around `Experiment.run()`, and BenchMARL's own timers summed"
        " over the run's iterations (collection, training, its evaluations). A run killed midway and resumed from a"
        " checkpoint counts its last attempt's wall clock plus BenchMARL's own time of the iterations it went on from;"
        " the last column says at which frames it resumed.",
        "",
        "| task | algorithm | seed | frames | wall (s) | collection (s) | training (s) | evaluation (s) | frames/s"
        " | resumed at (frames) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in sorted(records, key=lambda r: (list(ENV_ID_OF_TASK).index(r["task"]), r["algorithm"], r["seed"])):
        resumed = ", ".join(f"{frames:,}" for frames in r.get("resumed_at_frames", [])) or "—"  # older records: none
        lines.append(
            f"| {r['task'].lower()} | {r['algorithm']} | {r['seed']} | {r['frames']:,} | {r['wall_seconds']:.0f}"
            f" | {r['collection_seconds']:.0f} | {r['training_seconds']:.0f} | {r['evaluation_seconds']:.0f}"
            f" | {r['frames'] / r['wall_seconds']:,.0f} | {resumed} |"
        )
    return lines


def _docstring_section() -> str:
    """The module docstring's paragraphs on the plan, resuming and evaluation (what the page's numbers mean)."""
    text = (__doc__ or "").split("\n\n", 2)[2]
    return text.split("**The page.**")[0].strip().replace("``", "`")


# ---------------------------------------------------------------------------------------------------- the CLI
def _positive(name: str):
    def parse(value: str) -> int:
        try:
            number = int(value)
        except ValueError:
            number = 0
        if number < 1:
            raise argparse.ArgumentTypeError(f"argument '--{name}' must be an integer ≥ 1, got {value!r}")
        return number

    return parse


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m mrcomm_env.experiments.benchmarl_reference", description=__doc__.split("\n")[0]
    )
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="run what is missing of the plan (resumable)")
    run.add_argument("--tasks", nargs="+", default=list(ENV_ID_OF_TASK), choices=list(ENV_ID_OF_TASK))
    run.add_argument("--algorithms", nargs="+", default=list(ALGORITHMS), choices=list(ALGORITHMS))
    run.add_argument("--seeds", nargs="+", type=int, default=list(SEEDS))
    run.add_argument("--frames", type=_positive("frames"), default=FRAMES, help=f"frames per run (default {FRAMES:,})")
    run.add_argument("--frames-per-batch", type=_positive("frames-per-batch"), default=6_000)
    run.add_argument("--num-envs", type=_positive("num-envs"), default=NUM_ENVS)
    run.add_argument("--episodes", type=_positive("episodes"), default=EVAL_EPISODES)
    run.add_argument("--jobs", type=_positive("jobs"), default=1, help="processes sharing the plan (default 1)")
    run.add_argument("--out", type=Path, default=OUT)
    cost = commands.add_parser("cost", help="time two iterations of each run of the plan and project its hours")
    cost.add_argument("--tasks", nargs="+", default=list(ENV_ID_OF_TASK), choices=list(ENV_ID_OF_TASK))
    cost.add_argument("--algorithms", nargs="+", default=list(ALGORITHMS), choices=list(ALGORITHMS))
    cost.add_argument("--frames-per-batch", type=_positive("frames-per-batch"), default=6_000)
    cost.add_argument("--num-envs", type=_positive("num-envs"), default=NUM_ENVS)
    cost.add_argument("--episodes", type=_positive("episodes"), default=EVAL_EPISODES)
    cost.add_argument("--out", type=Path, default=OUT)
    page = commands.add_parser("page", help="write the page from the runs' files")
    page.add_argument("--out", type=Path, default=OUT)
    page.add_argument("--page", type=Path, default=PAGE)
    args = parser.parse_args(argv)
    try:
        if args.command == "run":
            if args.frames < args.frames_per_batch:
                raise ValueError("argument '--frames' must be at least '--frames-per-batch'")
            run_jobs(
                args.jobs, args.out, args.tasks, args.algorithms, args.seeds, args.frames, args.frames_per_batch,
                args.num_envs, args.episodes,
            )  # fmt: skip
        elif args.command == "cost":
            measure_cost(args.out, args.tasks, args.algorithms, args.frames_per_batch, args.num_envs, args.episodes)
        else:
            print(f"wrote {write_page(args.out, args.page)}")
    except (ValueError, RuntimeError, FileNotFoundError) as err:
        print(f"benchmark: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
