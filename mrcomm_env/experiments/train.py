"""Training runs as sweep tasks, and the sweeps of ``mrcomm train`` (its parser and run: ``commands/train.py``).

A task trains one run (or resumes it, or skips it when finished) and scores it on held-out episodes; ``mrcomm train
--seeds/--grid`` sends one per grid point and seed through the sweep runner and ranks the grid points by their
held-out score, and the learned-against-scripted comparison (``comparison.py``) sends its runs the same way. Needs
the "train" extra (it imports the agents); the CLI imports it when a command trains."""

from __future__ import annotations

import csv
import importlib
import inspect
import itertools
import json
import shlex
import sys
from pathlib import Path

import numpy as np

from mrcomm_agents.learned import LearnedPolicy
from mrcomm_agents.training import ALGORITHMS, RUN_KEYS, TrainConfig, has_checkpoint, train
from mrcomm_env.core.stats import mean_ci95
from mrcomm_env.experiments.evaluation import evaluate_policy, limit_threads
from mrcomm_env.experiments.io import atomic_write_csv, atomic_write_text
from mrcomm_env.experiments.runs import comparison_spec, run_folder, scored_policy_settings, teacher_for
from mrcomm_env.experiments.sweep import Task, runner_from_args


def grid_setting(algo: str, key: str) -> str:
    """Where a --grid key goes: ``"run"`` (TrainConfig's own settings), ``"hyper"`` (the algorithm's constructor)
    or ``"env"`` (an environment argument, checked by the env itself)."""
    if key in (*RUN_KEYS, "timesteps"):
        return "run"
    module, name = ALGORITHMS[algo]
    algorithm = getattr(importlib.import_module(module), name)
    if key in inspect.signature(algorithm.__init__).parameters and key not in ("env", "policy", "seed", "device"):
        return "hyper"
    return "env"


def sweep_configs(base: dict, seeds: list[int], grid: dict[str, list]) -> list[tuple[str, dict, dict]]:
    """One (folder, TrainConfig arguments, grid point) per combination of the grid's values and per seed, in a
    fixed order: the grid's keys as given, each key's values as given, then the seeds."""
    places = {key: grid_setting(base["algo"], key) for key in grid}
    out = []
    for values in itertools.product(*grid.values()):
        point = dict(zip(grid, values))
        config = {**base, "env_kwargs": dict(base["env_kwargs"]), "hyperparams": dict(base["hyperparams"])}
        for key, value in point.items():
            if places[key] == "run":
                config[key] = value
            elif places[key] == "hyper":
                config["hyperparams"][key] = value
            else:
                config["env_kwargs"][key] = value
        label = ",".join(f"{k}={json.dumps(v, separators=(',', ':'))}" for k, v in point.items()) or "default"
        for seed in seeds:
            TrainConfig(**{**config, "seed": seed}).validate()  # every bad value is reported before any training
            out.append((run_folder(label, {**config, "seed": seed}), {**config, "seed": seed}, point))
    return out


def sweep_rows(runs: list[tuple[str, dict, dict]], results: list[dict], metric: str) -> list[dict]:
    """One row of ``summary.csv`` per run: its grid point, seed, training summary and held-out means."""
    rows = []
    for (name, config, point), result in zip(runs, results):
        evaluation = result["evaluation"]
        rows.append(
            {
                **point,
                "seed": config["seed"],
                **result["training"],
                f"eval_{metric}": float(np.mean(evaluation["metric"])),
                "eval_bits": float(np.mean(evaluation["bits"])),
                "eval_return": float(np.mean(evaluation["return"])),
                "run": name,
            }
        )
    return rows


def print_ranking(rows: list[dict], metric: str, lower_is_better: bool) -> None:
    """The grid points by their mean held-out metric over seeds; at equal metric, fewer bits first."""
    points: dict[str, list[dict]] = {}
    for row in rows:
        points.setdefault(row["run"].rsplit("/", 1)[0], []).append(row)
    sign = 1.0 if lower_is_better else -1.0
    ranked = sorted(
        points.items(),
        key=lambda kv: (
            sign * float(np.mean([r[f"eval_{metric}"] for r in kv[1]])),
            float(np.mean([r["eval_bits"] for r in kv[1]])),
        ),
    )
    print(f"{len(rows)} runs; grid points by held-out {metric} ({'lower' if lower_is_better else 'higher'} is better):")
    for label, group in ranked:
        m, h = mean_ci95([r[f"eval_{metric}"] for r in group])
        b = float(np.mean([r["eval_bits"] for r in group]))
        print(f"  {label}: {metric} {m:.4g} ± {h:.2g}, bits {b:.4g} ({len(group)} seeds)")


def train_sweep(base: dict, seeds: list[int], grid: dict[str, list], out: Path, args) -> int:
    """``mrcomm train --seeds/--grid``: every run through the sweep runner, then ``summary.csv`` (one row per run)
    and a ranking of the grid points by their mean held-out score."""
    runs = sweep_configs(base, seeds, grid)
    eval_seeds = [20_000 + k for k in range(args.eval_episodes)]
    tasks = [
        Task(
            "mrcomm_env.experiments.train:train_and_evaluate",
            {"out": str(out / name), "config": config, "eval_seeds": eval_seeds},
            name,
        )
        for name, config, _ in runs
    ]
    results = runner_from_args(args, progress=not args.quiet).map(tasks, desc=f"training {len(tasks)} runs")
    try:
        spec = comparison_spec(base["env_id"])
    except ValueError:
        spec = {"metric": "episode_return", "lower_is_better": False}
    metric = spec["metric"]
    rows = sweep_rows(runs, results, metric)
    atomic_write_csv(out / "summary.csv", rows)
    print_ranking(rows, metric, bool(spec.get("lower_is_better")))
    record = {
        "command": "mrcomm " + " ".join(shlex.quote(a) for a in getattr(args, "argv", []) or sys.argv[1:]),
        "algo": base["algo"],
        "grid": grid,
        "seeds": seeds,
        "eval_episodes": len(eval_seeds),
        "metric": metric,
        "lower_is_better": bool(spec.get("lower_is_better")),
        "bits_per": spec.get("bits_per", "step"),
    }
    atomic_write_text(out / "sweep.json", json.dumps(record, indent=2) + "\n")
    print(f"wrote {out / 'summary.csv'} and {out / 'sweep.json'}")
    return 0


def train_run(out: str, config: dict) -> str:
    """Train one run into ``out`` (a process of its own: one torch thread). A finished run is skipped, a
    checkpointed one resumed, one never checkpointed starts over."""
    limit_threads()
    folder = Path(out)
    if (folder / "done.json").exists():
        return out  # a rerun skips what is done (the folder's name holds every setting: run_folder)
    if has_checkpoint(folder):
        train(None, folder, resume=True, progress=False)
    else:
        teacher = teacher_for(config["env_id"], config.get("init_from"))
        train(TrainConfig(**config), folder, progress=False, teacher=teacher)
    return out


def training_summary(run: Path) -> dict:
    """The last logged mean training return and the run's length, from SB3's ``progress.csv``."""
    with open(run / "progress.csv") as fh:
        rows = list(csv.DictReader(fh))
    returns = [float(r["rollout/ep_rew_mean"]) for r in rows if r.get("rollout/ep_rew_mean")]
    last = rows[-1] if rows else {}
    return {
        "timesteps": int(float(last.get("time/total_timesteps") or 0)),
        "seconds": float(last.get("time/time_elapsed") or 0.0),
        "final_train_return": returns[-1] if returns else float("nan"),
    }


def train_and_evaluate(out: str, config: dict, eval_seeds: list[int]) -> dict:
    """A sweep task: train one run into ``out`` (resumed, or skipped when finished) and score it on ``eval_seeds``
    with the env's comparison metric, bits and return: its final model, or its best by held-out return where the
    comparison says ``"checkpoint": "best"``. Returns JSON data only, so any backend can carry it."""
    train_run(out, config)
    summary = training_summary(Path(out))
    try:
        spec = comparison_spec(config["env_id"])
    except ValueError:  # no comparison section: score by the return alone
        spec = {"metric": "episode_return", "deterministic": True}
    policy = LearnedPolicy(out, config["env_id"], config.get("algo"), **scored_policy_settings(spec))
    evaluation = evaluate_policy(config["env_id"], config.get("env_kwargs", {}), policy, eval_seeds, spec)
    return {"run": out, "training": summary, "evaluation": evaluation}
