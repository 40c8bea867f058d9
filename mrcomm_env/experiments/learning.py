"""``mrcomm train`` and the policy names ``evaluate`` accepts: scripted baselines and learned models alike."""

from __future__ import annotations

import argparse
import importlib
import json
from pathlib import Path

import numpy as np

from mrcomm_env.registry import canonical_id, short_name


def make_any_policy(env_id: str, name: str, **params):
    """A scripted baseline by name, or a learned model: ``ppo:PATH``, ``maskable_ppo:PATH``, ``dqn:PATH``,
    ``pretrained``. Unknown names raise ``ValueError`` listing both kinds."""
    from mrcomm_baselines import make_policy, policy_names

    if name in policy_names(env_id):
        return make_policy(env_id, name, **params)
    try:
        from mrcomm_agents.learned import is_learned, load_policy
    except ImportError:
        if ":" in name or name == "pretrained":
            raise ValueError("learned policies need the training extra: pip install 'mrcomm-env[train]'") from None
        raise
    if is_learned(name):
        return load_policy(name, env_id, **params)
    raise ValueError(
        f"unknown policy {name!r} for {canonical_id(env_id)}; valid policies are: "
        f"{', '.join(policy_names(env_id))}, pretrained, or ALGO:RUN_FOLDER with ALGO ppo, maskable_ppo or dqn"
    )


def add_train_parser(command) -> None:
    from mrcomm_env.experiments.arguments import positive_int, seed_type
    from mrcomm_env.experiments.sweep import add_runner_arguments

    p = command("train", help="train one shared SB3 policy for every agent of an env")
    p.add_argument("env_id")
    p.add_argument("--algo", default=None, help="ppo (default), maskable_ppo or dqn")
    p.add_argument("--timesteps", type=positive_int, default=None, help="agent-steps (default: the env's config)")
    p.add_argument("--seed", type=seed_type, default=None, help="training seed (default 0)")
    p.add_argument("--out", required=False, help="run folder (default runs/<Name>-<algo>-s<seed>)")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="environment argument (JSON value)")
    p.add_argument("--config", metavar="FILE", help="JSON settings overriding agents/configs/<Name>-v0.json")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    p.add_argument(
        "--seeds", type=seed_list, metavar="S,S,…", help="train one run per seed (a sweep; instead of --seed)"
    )
    p.add_argument(
        "--grid",
        action="append",
        metavar="KEY=V,V,…",
        help="sweep KEY over the values (repeatable: every combination); KEY is a hyperparameter of --algo, a "
        "run setting (n_envs, net_arch, timesteps, …) or else an environment argument",
    )
    p.add_argument(
        "--eval-episodes",
        type=positive_int,
        default=5,
        help="sweeps: held-out episodes each run is scored on (seeds 20000+, apart from reproduce-learning's)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_runner_arguments(p)
    p.set_defaults(func=cmd_train)


def seed_list(text: str) -> list[int]:
    """``0,1,2`` → [0, 1, 2]: distinct integers ≥ 0."""
    from mrcomm_env.experiments.arguments import seed_type

    seeds = [seed_type(part.strip()) for part in text.split(",") if part.strip()]
    if not seeds or len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"--seeds takes distinct integers ≥ 0 separated by commas, got {text!r}")
    return seeds


def split_values(text: str) -> list[str]:
    """Comma-separated values, where commas inside brackets belong to a value (``net_arch=[64,64],[128,128]``)."""
    values, depth, start = [], 0, 0
    for i, char in enumerate(text):
        depth += char in "[{"
        depth -= char in "]}"
        if char == "," and depth == 0:
            values.append(text[start:i])
            start = i + 1
    values.append(text[start:])
    return [v.strip() for v in values]


def parse_grid(pairs: list[str] | None) -> dict[str, list]:
    """``["lam=0.01,0.1", "learning_rate=3e-4,1e-3"]`` → {key: [values]} (values read as JSON where possible)."""
    grid: dict[str, list] = {}
    for pair in pairs or []:
        key, sep, text = pair.partition("=")
        key = key.strip()
        if not sep or not key or not text.strip():
            raise ValueError(f"--grid takes KEY=V1,V2,…, got {pair!r}")
        if key in grid:
            raise ValueError(f"--grid names {key!r} twice")
        values = []
        for item in split_values(text):
            try:
                values.append(json.loads(item))
            except json.JSONDecodeError:
                values.append(item)
        grid[key] = values
    return grid


def cmd_train(args: argparse.Namespace) -> int:
    from mrcomm_agents.training import (
        TrainConfig,
        default_config,
        load_config_file,
        split_settings,
        train,
    )
    from mrcomm_env.experiments.arguments import parse_params
    from mrcomm_env.experiments.evaluation import limit_threads

    limit_threads()
    env_id = canonical_id(args.env_id)
    explicit = {"algo": args.algo, "seed": args.seed}  # None where the user named nothing
    args.algo = args.algo or "ppo"
    args.seed = 0 if args.seed is None else args.seed
    out = Path(args.out or f"runs/{short_name(env_id)}-{args.algo}-s{args.seed}")
    if args.resume:
        for flag, value in (("--config", args.config), ("--grid", args.grid), ("--seeds", args.seeds)):
            if value:
                raise ValueError(f"{flag} cannot be used with --resume: a resumed run keeps its own settings")
        requested = {"env_id": env_id, **explicit, "env_kwargs": parse_params(args.param), "timesteps": args.timesteps}
        train(None, out, resume=True, progress=not args.quiet, requested=requested)
        print(f"resumed and finished {out}")
        return 0
    settings = default_config(env_id, args.algo)
    if args.config:
        settings = {**settings, **load_config_file(args.config, args.algo)}
    run, hyper = split_settings(settings)
    env_kwargs = {**run.pop("env_kwargs", {}), **parse_params(args.param)}
    timesteps = args.timesteps if args.timesteps is not None else run.pop("timesteps", 200_000)
    run.pop("timesteps", None)
    base = dict(env_id=env_id, algo=args.algo, timesteps=timesteps, env_kwargs=env_kwargs, hyperparams=hyper, **run)
    if args.seeds is not None or args.grid:
        default_out = f"runs/{short_name(env_id)}-{args.algo}-sweep"
        return train_sweep(base, args.seeds or [args.seed], parse_grid(args.grid), Path(args.out or default_out), args)
    config = TrainConfig(seed=args.seed, **base)
    train(config, out, progress=not args.quiet)
    print(f"wrote {out}/model.zip, {out}/config.json, {out}/progress.csv")
    return 0


def grid_setting(algo: str, key: str) -> str:
    """Where a --grid key goes: ``"run"`` (TrainConfig's own settings), ``"hyper"`` (the algorithm's constructor)
    or ``"env"`` (an environment argument, checked by the env itself)."""
    import inspect

    from mrcomm_agents.training import ALGORITHMS, RUN_KEYS

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
    import itertools

    from mrcomm_agents.training import TrainConfig

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


def train_and_evaluate(out: str, config: dict, eval_seeds: list[int]) -> dict:
    """A sweep task: train one run into ``out`` (resumed, or skipped when finished) and score it on ``eval_seeds``
    with the env's comparison metric, bits and return. Returns JSON data only, so any backend can carry it."""
    from mrcomm_agents.learned import LearnedPolicy

    _train_task({"out": out, "config": config})
    summary = training_summary(Path(out))
    try:
        spec = comparison_spec(config["env_id"])
    except ValueError:  # no comparison section: score by the return alone
        spec = {"metric": "episode_return", "deterministic": True}
    policy = LearnedPolicy(out, config["env_id"], config.get("algo"), deterministic=spec.get("deterministic", True))
    evaluation = evaluate_policy(config["env_id"], config.get("env_kwargs", {}), policy, eval_seeds, spec)
    return {"run": out, "training": summary, "evaluation": evaluation}


def training_summary(run: Path) -> dict:
    """The last logged mean training return and the run's length, from SB3's ``progress.csv``."""
    import csv

    rows = list(csv.DictReader(open(run / "progress.csv")))
    returns = [float(r["rollout/ep_rew_mean"]) for r in rows if r.get("rollout/ep_rew_mean")]
    last = rows[-1] if rows else {}
    return {
        "timesteps": int(float(last.get("time/total_timesteps") or 0)),
        "seconds": float(last.get("time/time_elapsed") or 0.0),
        "final_train_return": returns[-1] if returns else float("nan"),
    }


def train_sweep(base: dict, seeds: list[int], grid: dict[str, list], out: Path, args) -> int:
    """``mrcomm train --seeds/--grid``: every run through the sweep runner, then ``summary.csv`` (one row per run)
    and a ranking of the grid points by their mean held-out score."""
    import csv
    import shlex
    import sys

    from mrcomm_env.core.stats import mean_ci95
    from mrcomm_env.experiments.io import atomic_open, atomic_write_text
    from mrcomm_env.experiments.sweep import Task, runner_from_args

    runs = sweep_configs(base, seeds, grid)
    eval_seeds = [20_000 + k for k in range(args.eval_episodes)]
    tasks = [
        Task(
            "mrcomm_env.experiments.learning:train_and_evaluate",
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
    with atomic_open(out / "summary.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    points: dict[str, list[dict]] = {}
    for row in rows:
        points.setdefault(row["run"].rsplit("/", 1)[0], []).append(row)
    sign = 1.0 if spec.get("lower_is_better") else -1.0
    ranked = sorted(  # the metric first; at equal metric, fewer bits
        points.items(),
        key=lambda kv: (
            sign * float(np.mean([r[f"eval_{metric}"] for r in kv[1]])),
            float(np.mean([r["eval_bits"] for r in kv[1]])),
        ),
    )
    print(f"{len(rows)} runs; grid points by held-out {metric} ({'lower' if sign > 0 else 'higher'} is better):")
    for label, group in ranked:
        m, h = mean_ci95([r[f"eval_{metric}"] for r in group])
        b = float(np.mean([r["eval_bits"] for r in group]))
        print(f"  {label}: {metric} {m:.4g} ± {h:.2g}, bits {b:.4g} ({len(group)} seeds)")
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


# ------------------------------------------------------------------------------------ learned vs scripted
COMPARISON_KEY = "comparison"


def comparison_spec(env_id: str) -> dict:
    """The env's comparison settings from ``agents/configs/<Name>-v0.json``: the cost argument swept (λ or the
    bit price), its values, the task metric and whether lower is better, the baselines, seeds and episodes."""
    from mrcomm_agents.training import CONFIG_DIR

    path = CONFIG_DIR / f"{short_name_of(env_id)}.json"
    if not path.exists():
        raise ValueError(f"{canonical_id(env_id)} has no learning configuration ({path.name})")
    spec = json.loads(path.read_text())
    if COMPARISON_KEY not in spec:
        raise ValueError(f"{path.name} has no '{COMPARISON_KEY}' section")
    return {"algo": "ppo", **spec[COMPARISON_KEY], "settings": spec}


def short_name_of(env_id: str) -> str:
    from mrcomm_env.registry import short_name

    return short_name(env_id)


def bits_per_agent(env, metrics: dict, per: str = "step") -> float:
    """Bits sent per agent, per step (``per="step"``) or over the whole episode (``"episode"``: for envs whose
    episodes end when the task is done, where a per-step rate would hide that a slow policy sends longer)."""
    steps = max(env.step_count, 1) if per == "step" else 1
    return float(metrics["bits_sent"]) / (env.n_agents * steps)


def evaluate_policy(env_id: str, env_kwargs: dict, policy, seeds: list[int], spec: dict) -> dict[str, list[float]]:
    """Per episode: the task metric, bits per agent (per step or per episode) and the return.

    ``spec["unfinished"]``: the value a metric that reports −1 or nan for "not done within the episode" (a
    completion time) counts as, so that never finishing is not mistaken for finishing at once."""
    from mrcomm_env.experiments.evaluation import run_episode
    from mrcomm_env.registry import make

    env = make(env_id, **env_kwargs)
    out = {"metric": [], "bits": [], "return": []}
    for seed in seeds:
        metrics = run_episode(env, policy, seed)
        value = float(metrics[spec["metric"]])
        if "unfinished" in spec and not value >= 0:  # −1 or nan: not done within the episode
            value = float(spec["unfinished"])
        out["metric"].append(value)
        out["bits"].append(bits_per_agent(env, metrics, spec.get("bits_per", "step")))
        out["return"].append(float(metrics["episode_return"]))
    env.close()
    return out


def _train_task(task: dict) -> str:
    """One training run of the comparison (a process of its own: one torch thread)."""
    from mrcomm_agents.training import TrainConfig, has_checkpoint, train
    from mrcomm_env.experiments.evaluation import limit_threads

    limit_threads()
    out = Path(task["out"])
    if (out / "done.json").exists():
        return str(out)  # a rerun skips what is done (the folder's name holds every setting: run_folder)
    if has_checkpoint(out):
        train(None, out, resume=True, progress=False)
    else:
        train(TrainConfig(**task["config"]), out, progress=False)  # never checkpointed: starts over
    return str(out)


def run_folder(label: str, config: dict) -> str:
    """``<grid point>-<digest>/s<seed>``: the digest covers every setting of the run but its seed (env arguments,
    algorithm, hyperparameters, agent-steps, …) and the backend of the env's hot loops, so a rerun with any of
    them changed trains new runs instead of reusing the old ones."""
    import hashlib

    from mrcomm_env.core import backend

    settings = {k: v for k, v in config.items() if k != "seed"}
    blob = json.dumps([settings, backend.name()], sort_keys=True, default=str)
    return f"{label}-{hashlib.sha1(blob.encode()).hexdigest()[:8]}/s{config['seed']}"


def reproduce_learning(env_id: str, out_dir: Path, quick: bool = False, progress: bool = True):
    """Train ``seeds`` policies per cost value, evaluate them and every baseline on held-out seeds, and return
    (rows, markdown). Rows: policy, cost, metric mean ± CI, bits per agent per step mean ± CI. The training runs
    (each scored on the held-out seeds where it ran) go through the sweep runner the caller chose."""
    from tqdm.auto import tqdm

    from mrcomm_agents.training import split_settings
    from mrcomm_baselines import make_policy
    from mrcomm_env.core.stats import mean_ci95

    env_id = canonical_id(env_id)
    spec = comparison_spec(env_id)
    algo = spec["algo"]
    run_settings, hyper = split_settings(spec["settings"].get(algo, {}))
    env_kwargs = dict(run_settings.pop("env_kwargs", {}))
    timesteps = run_settings.pop("timesteps", 200_000)
    if quick:
        timesteps = spec.get("quick_timesteps", max(timesteps // 10, 1))
    seeds = list(range(spec.get("seeds", 3)))
    eval_seeds = [10_000 + k for k in range(spec.get("eval_episodes", 10))]
    cost_param = spec["cost_param"]
    tasks = []
    for cost in spec["costs"]:
        for seed in seeds:
            config = dict(
                env_id=env_id,
                algo=algo,
                timesteps=timesteps,
                seed=seed,
                hyperparams=hyper,
                env_kwargs={**env_kwargs, cost_param: cost},
                **run_settings,
            )
            tasks.append(
                {
                    "out": str(out_dir / "runs" / run_folder(f"{cost_param}={cost}", config)),
                    "config": config,
                    "cost": cost,
                    "seed": seed,
                }
            )
    from mrcomm_env.experiments.sweep import Task, run_tasks

    sweep = [
        Task(
            "mrcomm_env.experiments.learning:train_and_evaluate",
            {"out": task["out"], "config": task["config"], "eval_seeds": eval_seeds},
            f"{cost_param}={task['cost']} s{task['seed']}",
        )
        for task in tasks
    ]
    rows = []
    learned: dict[float, list[dict]] = {}
    for task, done in zip(tasks, run_tasks(sweep, desc=f"training {short_name_of(env_id)}")):
        result = done["evaluation"]
        task["score"] = float(np.nanmean(result["metric"]))
        learned.setdefault(task["cost"], []).append(result)
    spec["best_run"] = _best(tasks, spec)
    for cost, results in learned.items():
        # one point per training seed (its mean over the evaluation episodes): the CI is over training seeds
        per_seed_metric = [float(np.nanmean(r["metric"])) for r in results]
        per_seed_bits = [float(np.mean(r["bits"])) for r in results]
        rows.append(_row(f"learned ({algo})", cost, per_seed_metric, per_seed_bits, len(results), mean_ci95))
    # a baseline's actions do not depend on the price of bits, so it is evaluated once, unless the swept argument
    # changes the setting itself (``baselines_per_cost``: e.g. the communication range)
    costs = spec["costs"] if spec.get("baselines_per_cost") else [None]
    for name, params in tqdm(spec["baselines"], desc="evaluating baselines", disable=not progress, leave=False):
        for cost in costs:
            policy = make_policy(env_id, name, **params)
            kwargs = env_kwargs if cost is None else {**env_kwargs, cost_param: cost}
            result = evaluate_policy(env_id, kwargs, policy, eval_seeds, spec)
            label = name + (" " + ", ".join(f"{k}={v}" for k, v in params.items()) if params else "")
            row = _row(label, None, result["metric"], result["bits"], len(eval_seeds), mean_ci95)
            row["setting"] = cost
            rows.append(row)
    for row in rows:
        row.setdefault("setting", row["cost"])
    return rows, spec


def _best(tasks: list[dict], spec: dict) -> str:
    """The run with the best task metric on the evaluation episodes (the model ``--export-pretrained`` ships)."""
    sign = 1.0 if spec.get("lower_is_better") else -1.0
    return min(tasks, key=lambda t: (sign * t["score"], t["cost"], t["seed"]))["out"]


def export_pretrained(run: str | Path, env_id: str) -> Path:
    """Copy a run's model, statistics and config into ``agents/pretrained/<Name>-v0/`` (shipped in the package;
    ``mrcomm evaluate ID --policy pretrained``). Checkpoints and logs stay behind: well under 1 MB."""
    import shutil

    from mrcomm_agents.learned import pretrained_dir

    target = pretrained_dir(env_id)
    target.mkdir(parents=True, exist_ok=True)
    for name in ("model.zip", "vecnormalize.pkl", "config.json"):
        if (Path(run) / name).exists():
            tmp = target / f".{name}.tmp"
            shutil.copyfile(Path(run) / name, tmp)
            tmp.replace(target / name)
    write_model_card(env_id, json.loads((target / "config.json").read_text()))
    return target


def write_model_card(env_id: str, record: dict) -> Path:
    """``card.json`` beside a shipped model: what ``--policy pretrained`` and a reader need to know of it. The
    evaluation mode is the one the comparison chose the model with (``comparison.deterministic`` of
    ``agents/configs/<Name>-v0.json``, deterministic by default)."""
    from mrcomm_agents.learned import CARD_NAME, pretrained_dir
    from mrcomm_env.experiments.io import atomic_write_text

    try:
        spec = comparison_spec(env_id)
    except ValueError:
        spec = {}
    card = {
        "env_id": canonical_id(env_id),
        "env_kwargs": record.get("env_kwargs", {}),
        "algo": record.get("algo"),
        "policy": record.get("policy", "mlp"),
        "seed": record.get("seed"),
        "agent_steps": record.get("timesteps"),
        "deterministic": bool(spec.get("deterministic", True)),
        "metric": spec.get("metric"),
        "reproduce": f"mrcomm reproduce-learning {short_name(env_id)} --export-pretrained",
    }
    path = pretrained_dir(env_id) / CARD_NAME
    atomic_write_text(path, json.dumps(card, indent=2) + "\n")
    return path


def _row(policy, cost, metric_values, bits_values, n, mean_ci95) -> dict:
    m, mh = mean_ci95(metric_values)
    b, bh = mean_ci95(bits_values)
    return {"policy": policy, "cost": cost, "metric": m, "metric_ci95": mh, "bits": b, "bits_ci95": bh, "n": n}


def dominates(learned: dict, baseline: dict, lower_is_better: bool) -> bool:
    """*Matches*: the learned point sends no more bits than the baseline (5 % slack for the bits' own noise) and
    its task metric is not worse beyond the two 95 % intervals."""
    if learned["bits"] > baseline["bits"] * 1.05 + 1e-9:
        return False
    sign = -1.0 if lower_is_better else 1.0
    return sign * (learned["metric"] - baseline["metric"]) >= -(learned["metric_ci95"] + baseline["metric_ci95"])


def beats(learned: dict, baseline: dict, lower_is_better: bool) -> bool:
    """*Beats*: it matches the baseline and, beyond the two 95 % intervals, either has the better task metric or
    sends fewer bits (at least 5 % fewer, the slack that matching allows)."""
    if not dominates(learned, baseline, lower_is_better):
        return False
    sign = -1.0 if lower_is_better else 1.0
    better = sign * (learned["metric"] - baseline["metric"]) > learned["metric_ci95"] + baseline["metric_ci95"]
    # fewer bits counts only beyond the intervals *and* the 5 % slack that matching allows: a point 2 % cheaper
    # but worse on average is a match, not a win
    saved = baseline["bits"] - learned["bits"]
    cheaper = saved > learned["bits_ci95"] + baseline["bits_ci95"] and saved > 0.05 * baseline["bits"]
    return better or cheaper


def plot_comparison(rows: list[dict], spec: dict, title: str, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.2))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    learned = [r for r in rows if r["cost"] is not None]
    ax.errorbar(
        [r["bits"] for r in learned],
        [r["metric"] for r in learned],
        xerr=[r["bits_ci95"] for r in learned],
        yerr=[r["metric_ci95"] for r in learned],
        fmt="o-",
        color="black",
        label=f"learned ({spec['algo']}), one point per {spec['cost_param']}",
    )
    for r in learned:
        ax.annotate(
            f"{spec['cost_param']}={r['cost']:g}",
            (r["bits"], r["metric"]),
            fontsize=7,
            xytext=(4, 4),
            textcoords="offset points",
        )
    for k, r in enumerate(r for r in rows if r["cost"] is None):
        ax.errorbar(
            [r["bits"]],
            [r["metric"]],
            xerr=[r["bits_ci95"]],
            yerr=[r["metric_ci95"]],
            fmt="s",
            color=f"C{k % 10}",
            label=r["policy"] if r["setting"] is None else f"{r['policy']} ({spec['cost_param']}={r['setting']:g})",
        )
    ax.set_xlabel(f"bits sent per agent per {spec.get('bits_per', 'step')}")
    ax.set_ylabel(spec["metric"] + (" (lower is better)" if spec.get("lower_is_better") else " (higher is better)"))
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=90)
    tmp.replace(path)


def learning_section(env_id: str, rows: list[dict], spec: dict, figure: str) -> str:
    lower = bool(spec.get("lower_is_better"))
    learned = [r for r in rows if r["cost"] is not None]
    baselines = [r for r in rows if r["cost"] is None]
    lines = [
        f"## `{env_id}`",
        "",
        spec.get("setting", ""),
        "",
        f"![{spec['metric']} against bits]({figure})",
        "",
        f"| policy | {spec['cost_param']} | {spec['metric']} (mean ± 95 % CI) | bits / agent / {spec.get('bits_per', 'step')} | n |",
        "| --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        cost = "—" if r["setting"] is None else f"{r['setting']:g}"
        lines.append(
            f"| {r['policy']} | {cost} | {r['metric']:.4g} ± {r['metric_ci95']:.2g} "
            f"| {r['bits']:.4g} ± {r['bits_ci95']:.2g} | {r['n']} |"
        )

    per_setting = bool(spec.get("baselines_per_cost"))

    def verdict(name: str) -> str:
        # with per-setting baselines a learned point is compared with the baseline in its own setting only
        candidates = [b for b in baselines if b["policy"] == name]

        def where(test) -> str:
            hits = [
                r
                for r in learned
                for b in candidates
                if (not per_setting or b["setting"] == r["cost"]) and test(r, b, lower)
            ]
            return ", ".join(f"{r['cost']:g}" for r in hits)

        won, matched = where(beats), where(dominates)
        if won:
            return f"- `{name}`: **beaten** at equal or fewer bits ({spec['cost_param']} = {won})"
        if matched:
            return f"- `{name}`: **matched** (not worse, not better) at equal or fewer bits ({spec['cost_param']} = {matched})"
        return f"- `{name}`: **not matched** at equal or fewer bits"

    names = list(dict.fromkeys(b["policy"] for b in baselines))
    verdicts = [verdict(n) for n in sorted(names, key=lambda n: n != "random")]
    lines += [
        "",
        "Outcome, computed from the table. A learned point *matches* a baseline when it sends at most 5 % more "
        "bits and its metric is not worse beyond the two 95 % intervals; it *beats* it when, in addition, its "
        "metric is better beyond the intervals, or it sends at least 5 % fewer bits, also beyond the intervals:",
        "",
        *verdicts,
    ]
    if spec.get("notes"):
        lines += ["", spec["notes"]]
    return "\n".join(lines) + "\n"


def cmd_reproduce_learning(args: argparse.Namespace) -> int:
    import csv

    from mrcomm_agents.training import CONFIG_DIR
    from mrcomm_env.experiments.evaluation import limit_threads
    from mrcomm_env.experiments.sweep import runner_from_args, using
    from mrcomm_env.registry import env_ids

    limit_threads()

    from mrcomm_env.experiments.io import atomic_write_text

    targets = [canonical_id(e) for e in args.env_ids] or [
        e for e in env_ids() if (CONFIG_DIR / f"{short_name_of(e)}.json").exists()
    ]
    out = Path(args.out)
    docs = Path(args.docs)
    (docs / "learning").mkdir(parents=True, exist_ok=True)
    if args.docs_only:  # re-render every section from its recorded table (e.g. after ``make sweep``)
        for env_id in targets:
            name = short_name_of(env_id)
            table = docs / "learning" / f"{name}.csv"
            if not table.exists():
                continue
            rows = read_rows(table)
            section = learning_section(env_id, rows, comparison_spec(env_id), f"learning/{name}.png")
            atomic_write_text(docs / "learning" / f"{name}.md", section + sweep_section(env_id, docs))
        print(f"wrote {write_learning_page(docs)}")
        return 0
    with using(runner_from_args(args, progress=not args.quiet)):  # one set of workers for every env
        for env_id in targets:
            name = short_name_of(env_id)
            rows, spec = reproduce_learning(env_id, out / name, quick=args.quick, progress=not args.quiet)
            csv_path = docs / "learning" / f"{name}.csv"
            tmp = csv_path.with_name(f".{csv_path.name}.tmp")
            with open(tmp, "w", newline="") as fh:
                writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
                writer.writeheader()
                writer.writerows(rows)
            tmp.replace(csv_path)
            figure = docs / "learning" / f"{name}.png"
            plot_comparison(rows, spec, f"{env_id}: learned vs scripted at equal bits", figure)
            section = learning_section(env_id, rows, spec, f"learning/{name}.png") + sweep_section(env_id, docs)
            # one fragment per env: rerunning one env keeps the others' sections in the page
            atomic_write_text(docs / "learning" / f"{name}.md", section)
            if args.export_pretrained:
                print(f"shipped {spec['best_run']} as {export_pretrained(spec['best_run'], env_id)}")
    page = write_learning_page(docs, quick=args.quick)
    print(f"wrote {page}")
    return 0


def read_rows(path: Path) -> list[dict]:
    """The comparison rows as ``reproduce-learning`` wrote them to ``docs/learning/<Name>-v0.csv``."""
    import csv

    def number(text: str):
        return None if text == "" else float(text)

    rows = []
    for raw in csv.DictReader(open(path)):
        row = {k: number(v) for k, v in raw.items() if k not in ("policy",)}
        row["policy"], row["n"] = raw["policy"], int(float(raw["n"]))
        rows.append(row)
    return rows


def write_learning_page(docs: Path, quick: bool = False) -> Path:
    """``docs/learning.md``: the header, every env's fragment ``docs/learning/<Name>-v0.md`` (registry order) and
    the footer."""
    from mrcomm_env.experiments.io import atomic_write_text
    from mrcomm_env.registry import env_ids

    sections = [
        (docs / "learning" / f"{short_name_of(e)}.md").read_text()
        for e in env_ids()
        if (docs / "learning" / f"{short_name_of(e)}.md").exists()
    ]
    header = LEARNING_HEADER.format(command="mrcomm reproduce-learning" + (" --quick" if quick else ""))
    page = docs / "learning.md"
    atomic_write_text(page, header + "\n".join(sections) + LEARNING_FOOTER)
    return page


def sweep_section(env_id: str, docs: Path) -> str:
    """The recorded hyperparameter sweep of ``env_id`` (``make sweep``: ``docs/learning/sweep-<Name>-v0.csv`` and
    its ``.json``), as a table of grid points ranked by their mean held-out score; empty when none is recorded."""
    import csv

    from mrcomm_env.core.stats import mean_ci95

    name = short_name_of(env_id)
    table, record = docs / "learning" / f"sweep-{name}.csv", docs / "learning" / f"sweep-{name}.json"
    if not (table.exists() and record.exists()):
        return ""
    meta = json.loads(record.read_text())
    rows = list(csv.DictReader(open(table)))
    metric, keys = meta["metric"], list(meta["grid"])
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault(tuple(row[k] for k in keys), []).append(row)
    sign = 1.0 if meta.get("lower_is_better") else -1.0

    def score(group):  # the metric first; at equal metric, fewer bits
        return (
            sign * float(np.mean([float(r[f"eval_{metric}"]) for r in group])),
            float(np.mean([float(r["eval_bits"]) for r in group])),
        )

    lines = [
        "",
        "### Hyperparameter sweep",
        "",
        f"`{meta['command']}` ({len(rows)} runs of {int(float(rows[0]['timesteps'])):,} agent-steps; every other "
        f"setting as in `agents/configs/{name}.json`; each run scored on {meta['eval_episodes']} held-out episodes, "
        f"seeds apart from the comparison's). Ranked by the held-out {metric}; the interval is over training seeds.",
        "",
        f"| {' | '.join(keys)} | {metric} | bits / agent / {meta.get('bits_per', 'step')} | final training return "
        "| minutes per run |",
        "| " + " | ".join("---" for _ in range(len(keys) + 4)) + " |",
    ]
    for values, group in sorted(groups.items(), key=lambda kv: score(kv[1])):
        m, h = mean_ci95([float(r[f"eval_{metric}"]) for r in group])
        bits = np.mean([float(r["eval_bits"]) for r in group])
        ret = np.mean([float(r["final_train_return"]) for r in group])
        minutes = np.mean([float(r["seconds"]) for r in group]) / 60
        lines.append(f"| {' | '.join(values)} | {m:.4g} ± {h:.2g} | {bits:.4g} | {ret:.4g} | {minutes:.1f} |")
    from mrcomm_agents.training import default_config

    settings = default_config(env_id, meta.get("algo", "ppo"))
    chosen = ", ".join(f"`{k}={json.dumps(settings.get(k, settings.get('env_kwargs', {}).get(k)))}`" for k in keys)
    lines += ["", f"`agents/configs/{name}.json` trains with {chosen}."]
    return "\n".join(lines) + "\n"


LEARNING_HEADER = """# Learned communication against the papers' algorithms, at equal bits

_Generated by `{command}` (`make learn`); do not edit by hand. Settings: `agents/configs/<Name>-v0.json`,
chosen by the recorded hyperparameter sweep under each env's section (`make sweep`)._

One PPO policy is shared by every agent (parameter sharing, `agents/vecenv.py`). For each env, the price of a
bit in the reward (the cost argument) is swept; each value is trained with several seeds and each trained
policy is evaluated deterministically on held-out episode seeds. A learned point's interval is over training
seeds; a baseline's over episodes. The scripted baselines see more than the learned policy where the env's
page says so (`docs/envs/<Name>-v0.md`, column "global knowledge"), and their own per-robot memory: see
"What the baselines read" below.

"""

LEARNING_FOOTER = """
## What the baselines read beyond the observation

A learned policy sees only its observation. The scripted baselines read their robot's local view (the env's
`LOCAL_VIEW`, listed on each env page) and keep memory across steps; a comparison favours them by that much.

| env | baseline | reads beyond the observation |
| --- | --- | --- |
| AsyncCL-v0 | `scheme*`, `silent` | nothing (a fixed mode every step) |
| ChannelAssociation-v0 | `coin_flip`, `bernoulli` | nothing |
| ChannelAssociation-v0 | `id_bits` | its own ID and the step clock modulo B + 1 (both also in the observation since v0 rev 2) |
| MultiHop-v0 | `location_based` | its estimate list (stamps, estimated distances) and Algorithm 1's counters, kept across frames |
| MultiHop-v0 | `age_aware` | its estimate list and the stamp it last broadcast for each robot (`sent_stamp`) |
| MultiHop-v0 | `probabilistic` | its estimate list |
| MultiHop-v0 | `flooding` | a frame counter |
| MapSync-v0 | `periodic_*` | the step clock (every 10 moves) and when it last tested, kept across steps |
| RendezvousMapping-v0 | `paper_protocol` | its group's fused map (landmark estimates, information, counts) and the positions it knows, to run §IV's planner; the last actions |
| RendezvousMapping-v0 | `greedy`, `no_partition` | the candidate utilities of its local view |
"""


def add_learning_parsers(command) -> None:
    """``train`` and ``reproduce-learning``; ``command(name, **kw)`` adds a subcommand parser."""
    from mrcomm_env.experiments.sweep import add_runner_arguments

    add_train_parser(command)
    p = command("reproduce-learning", help="learned policies against every baseline at equal bits")
    p.add_argument("env_ids", nargs="*", help="default: every env with a learning configuration")
    p.add_argument("--out", default="results/learning", help="training runs and evaluations")
    p.add_argument("--docs", default="docs", help="where learning.md and its figures go")
    p.add_argument("--quick", action="store_true", help="a tenth of the training budget (a smoke run)")
    p.add_argument("--export-pretrained", action="store_true", help="ship each env's best run in agents/pretrained")
    p.add_argument(
        "--docs-only",
        action="store_true",
        help="no training: re-render learning.md from the recorded tables and sweeps",
    )
    p.add_argument("--quiet", action="store_true")
    add_runner_arguments(p)
    p.set_defaults(func=cmd_reproduce_learning)


# ------------------------------------------------------------------------------------ training throughput
#: the PPO settings every env (and the reference) trains with in ``mrcomm bench --train``: the same work per
#: agent-step everywhere, so the figures compare the envs and not the settings
BENCH_PPO = {"n_steps": 64, "n_epochs": 4, "policy_kwargs": {"net_arch": [64, 64]}}


def train_throughput(env_fns, timesteps: int, seed: int = 0) -> dict[str, float]:
    """PPO agent-steps/s through ``AgentSlotVecEnv`` over ``env_fns`` and the share of wall time in ``env.step``."""
    import time

    import torch
    from stable_baselines3 import PPO

    from mrcomm_agents.vecenv import AgentSlotVecEnv

    torch.set_num_threads(1)
    venv = AgentSlotVecEnv(env_fns)
    in_step = [0.0]
    for env in venv.envs:
        step = env.step

        def timed(actions, _step=step):
            start = time.perf_counter()
            try:
                return _step(actions)
            finally:
                in_step[0] += time.perf_counter() - start

        env.step = timed
    # one minibatch per epoch: the gradient work per agent-step is then the same whatever the slot count
    batch = BENCH_PPO["n_steps"] * venv.num_envs
    model = PPO("MlpPolicy", venv, seed=seed, device="cpu", verbose=0, batch_size=batch, **BENCH_PPO)
    start = time.perf_counter()
    model.learn(total_timesteps=timesteps)
    wall = time.perf_counter() - start
    venv.close()
    return {
        "agent_steps_per_s": model.num_timesteps / wall,
        "env_step_share": in_step[0] / wall,
        "agent_steps": model.num_timesteps,
        "seconds": wall,
        "slots": venv.num_envs,
    }
