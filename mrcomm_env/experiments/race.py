"""``mrcomm race ID`` (its parser and run: ``commands/race.py``): the same quality in less time? SB3 with an env's shipped settings against the batched trainer.

For each seed, both trainers train on the env's shipped configuration (``agents/configs/<Name>-v0.json``: its env
arguments, agent-steps and problem-level hyperparameters γ, GAE λ, learning rate and entropy coefficient), with
the same held-out evaluation (the comparison's task metric and bits, on held-out episode seeds, every 1/16 of SB3's
agent-steps). SB3 keeps its shipped batching (copies, rollout length, minibatch, epochs); the batched trainer uses
its documented defaults (``agents/batched_ppo.py`` ``DEFAULTS``) and twice SB3's agent-steps (:data:`BATCHED_STEPS`).
Wall time is training's own, without the held-out evaluations (``time/training_seconds``), so their cost does not
favour either side.

Quality is the held-out episode return: the env's reward, which prices the bits a policy sends against its task
metric, so it cannot be bought by sending more (a random MapSync policy, syncing all the time, has a better
disagreement than a trained one, at seven times its bits). The comparison's task metric and bits are reported
beside it. The verdict: the wall time the batched trainer needs to first reach SB3's final held-out return (the
mean over seeds), against SB3's whole wall time; the goal is at most a quarter. A shipped configuration that starts from a
clone of a paper algorithm (``init_from``) is refused: its clone, not the trainer, sets its quality, and the clone
takes the same time in both. Needs the "train" extra; the CLI imports this module when ``race`` runs.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from tqdm.auto import tqdm

from mrcomm_agents.batched_ppo import DEFAULTS
from mrcomm_agents.training import TrainConfig, default_config, split_settings, train
from mrcomm_env.core.stats import mean_ci95
from mrcomm_env.experiments.io import atomic_write_csv, atomic_write_json, atomic_write_text
from mrcomm_env.experiments.runs import comparison_spec, run_folder, sb3_algo
from mrcomm_env.registry import canonical_id, short_name

#: the shipped hyperparameters that define the problem rather than the trainer's batching: both trainers use them
PROBLEM_KEYS = ("learning_rate", "gamma", "gae_lambda", "ent_coef")
#: held-out evaluations per run (evenly spaced in agent-steps, plus the start), and episodes each
EVALUATIONS = 16
EVAL_EPISODES = 4
#: the goal: the batched trainer reaches SB3's final return in at most this share of SB3's wall time
GOAL_SHARE = 0.25
#: the batched trainer's agent-steps, as a multiple of the shipped SB3 run's: its agent-steps are cheaper, and the
#: race is in wall time, so it may use more of them (its defaults learn less per agent-step than SB3's settings)
BATCHED_STEPS = 2


def race_configs(env_id: str, algo: str = "ippo") -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """(SB3 run settings, batched run settings, the comparison's spec) of ``env_id``'s shipped configuration, as
    ``TrainConfig`` arguments without the seed."""
    spec = comparison_spec(env_id)
    sb3_side = sb3_algo(spec)  # SB3's shipped settings, also where the comparison now trains the batched trainer
    run, hyper = split_settings(default_config(env_id, sb3_side))
    if run.get("init_from"):
        raise ValueError(
            f"{canonical_id(env_id)}'s shipped configuration starts from a clone ({run['init_from']}): the clone, not the "
            "trainer, sets its quality; race an env trained from scratch"
        )
    timesteps = int(run.pop("timesteps", 200_000))
    env_kwargs = dict(run.pop("env_kwargs", {}))
    for key in ("checkpoint_every", "eval_every", "eval_episodes"):
        run.pop(key, None)
    common = {"env_id": canonical_id(env_id), "env_kwargs": env_kwargs, "eval_episodes": EVAL_EPISODES}
    sb3 = {
        **common,
        "algo": sb3_side,
        "timesteps": timesteps,
        "eval_every": max(1, timesteps // EVALUATIONS),
        "hyperparams": hyper,
        "checkpoint_every": timesteps,
        **run,
    }
    batched_hyper = dict(DEFAULTS)
    batched_hyper.update({k: hyper[k] for k in PROBLEM_KEYS if k in hyper})
    batched = {
        **common,
        "algo": algo,
        "timesteps": BATCHED_STEPS * timesteps,
        "eval_every": max(1, timesteps // EVALUATIONS),
        "hyperparams": batched_hyper,
        "checkpoint_every": BATCHED_STEPS * timesteps,
        **{k: run[k] for k in ("net_arch", "policy", "normalize") if k in run},
    }
    return sb3, batched, spec


def curve(run: Path, metric: str, bits_key: str) -> list[dict[str, float]]:
    """The held-out rows of a run's ``progress.csv``: agent-steps, training's own seconds, metric and bits."""
    with open(run / "progress.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    out = []
    for row in rows:
        if not row.get(f"heldout/{metric}"):
            continue
        seconds = float(row.get("time/training_seconds") or 0.0)
        out.append(
            {
                "agent_steps": float(row["time/total_timesteps"]),
                "seconds": max(seconds, 0.0),
                "return": float(row["heldout/episode_return"]),
                "metric": float(row[f"heldout/{metric}"]),
                "bits": float(row[f"heldout/{bits_key}"]),
            }
        )
    return out


def first_reaching(points: list[dict[str, float]], target: float) -> float | None:
    """Training seconds at the first evaluation whose return is at least ``target`` (None: never)."""
    for point in points:
        if point["return"] >= target:
            return point["seconds"]
    return None


def summarize(curves: dict[str, list[list[dict[str, float]]]], algo: str) -> dict[str, Any]:
    """The verdict of :func:`race` from each trainer's curves (one per seed)."""
    sb3_seconds = [c[-1]["seconds"] for c in curves["sb3"]]
    target = float(np.mean([c[-1]["return"] for c in curves["sb3"]]))
    reached = [first_reaching(c, target) for c in curves[algo]]
    summary: dict[str, Any] = {"target_return": target}
    for name, runs in curves.items():
        summary[name] = {"agent_steps": runs[0][-1]["agent_steps"]}
        for key in ("return", "metric", "bits", "seconds"):
            mean, half_width = mean_ci95([c[-1][key] for c in runs])
            summary[name][f"final_{key}"], summary[name][f"final_{key}_ci95"] = mean, half_width
    summary[algo]["seconds_to_target"] = reached
    every_seed = all(r is not None for r in reached)
    share = float(np.mean([r for r in reached if r is not None])) / float(np.mean(sb3_seconds)) if every_seed else None
    summary["share_of_sb3_time"] = share
    summary["goal_share"] = GOAL_SHARE
    summary["verdict"] = (
        "not reached by every seed"
        if share is None
        else ("met" if share <= GOAL_SHARE else f"missed ({share:.2f} of SB3's time, goal {GOAL_SHARE})")
    )
    return summary


def race(env_id: str, seeds: int, out: Path, algo: str = "ippo", progress: bool = True) -> dict[str, Any]:
    """Train both trainers ``seeds`` times into ``out/<trainer>-<digest of its settings>/s<seed>`` (a finished run is
    reused) and write
    ``curves.csv``, ``race.json``, ``race.png`` and ``race.md`` into ``out``."""
    sb3, batched, spec = race_configs(env_id, algo)
    metric, lower = spec["metric"], bool(spec.get("lower_is_better"))
    bits_key = "bits_per_agent_episode" if spec.get("bits_per") == "episode" else "bits_per_agent_step"
    curves: dict[str, list[list[dict[str, float]]]] = {"sb3": [], algo: []}
    jobs = [(name, settings, seed) for name, settings in (("sb3", sb3), (algo, batched)) for seed in range(seeds)]
    for name, settings, seed in tqdm(jobs, desc=f"race {short_name(env_id)}", disable=not progress):
        folder = out / run_folder(name, {**settings, "seed": seed})  # other settings: other folders
        if not (folder / "done.json").exists():
            train(TrainConfig(seed=seed, **json.loads(json.dumps(settings))), folder, progress=False)
        curves[name].append(curve(folder, metric, bits_key))
    summary = summarize(curves, algo)
    summary.update(env_id=canonical_id(env_id), metric=metric, lower_is_better=lower, bits=bits_key, seeds=seeds)
    summary["settings"] = {"sb3": sb3, algo: batched}
    rows = [
        {"trainer": name, "seed": seed, **point}
        for name, runs in curves.items()
        for seed, points in enumerate(runs)
        for point in points
    ]
    atomic_write_csv(out / "curves.csv", rows)
    atomic_write_json(out / "race.json", summary, indent=2)
    _plot(curves, summary, out / "race.png")
    atomic_write_text(out / "race.md", race_table(summary, algo))
    return summary


def race_table(summary: dict[str, Any], algo: str) -> str:
    """The markdown table of one race."""
    metric = summary["metric"]
    lines = [
        f"| {summary['env_id']} | agent-steps | training seconds | final return | final {metric} | final bits "
        f"({summary['bits']}) |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for name in ("sb3", algo):
        s = summary[name]
        cells = [f"{s[f'final_{k}']:.4g} ± {s[f'final_{k}_ci95']:.2g}" for k in ("seconds", "return", "metric", "bits")]
        lines.append(f"| {name} | {s['agent_steps']:,.0f} | {' | '.join(cells)} |")
    reached = ", ".join("never" if r is None else f"{r:.1f} s" for r in summary[algo]["seconds_to_target"])
    share = summary["share_of_sb3_time"]
    lines.append("")
    lines.append(
        f"(means ± 95 % intervals over {summary['seeds']} seeds.) {algo} first reached SB3's final return "
        f"({summary['target_return']:.4g}) after {reached} per seed"
        + ("" if share is None else f": {share:.2f} of SB3's wall time")
        + f". Verdict: {summary['verdict']}."
    )
    return "\n".join(lines) + "\n"


def _plot(curves: dict[str, list[list[dict[str, float]]]], summary: dict[str, Any], path: Path) -> None:
    fig = Figure(figsize=(6.4, 4.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for (name, runs), color in zip(curves.items(), ("tab:gray", "tab:blue")):
        for seed, points in enumerate(runs):
            ax.plot(
                [p["seconds"] for p in points],
                [p["return"] for p in points],
                color=color,
                marker="o",
                markersize=3,
                label=name if seed == 0 else None,
            )
    ax.axhline(summary["target_return"], color="tab:gray", linestyle=":", label="SB3's final (mean)")
    ax.set_xscale("symlog", linthresh=1.0)
    ax.set_xlabel("training wall time, s (held-out evaluations excluded)")
    ax.set_ylabel("held-out episode return")
    ax.set_title(f"{summary['env_id']}: {len(next(iter(curves.values())))} seeds per trainer")
    ax.legend()
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=110)
    tmp.replace(path)
