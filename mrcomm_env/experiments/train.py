"""The sweeps of ``mrcomm train`` (its parser and run: ``commands/train.py``): runs over seeds and a grid of settings
(``--seeds``, ``--grid``) as sweep tasks, ranked by their held-out score."""

from __future__ import annotations

import importlib
import inspect
import itertools
import json
import shlex
import sys
from pathlib import Path

import numpy as np

from mrcomm_env.core.stats import mean_ci95
from mrcomm_env.experiments.io import atomic_write_csv, atomic_write_text
from mrcomm_env.experiments.runs import comparison_spec, run_folder
from mrcomm_env.experiments.sweep import Task, runner_from_args


def grid_setting(algo: str, key: str) -> str:
    """Where a --grid key goes: ``"run"`` (TrainConfig's own settings), ``"hyper"`` (the algorithm's constructor)
    or ``"env"`` (an environment argument, checked by the env itself)."""
    from mrcomm_agents.training import ALGORITHMS, RUN_KEYS  # extra "train"

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
    from mrcomm_agents.training import TrainConfig  # extra "train"

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
            "mrcomm_env.experiments.runs:train_and_evaluate",
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
