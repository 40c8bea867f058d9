"""The learned-against-scripted comparison at equal bits (``mrcomm reproduce-learning``): train policies at each
price of a bit, score them and every baseline on held-out episodes, apply the equal-bits rule (``dominates``,
``beats``) and ship the best run with its model card. Needs the "train" extra (it imports the agents); the CLI
imports it when ``reproduce-learning`` runs."""

from __future__ import annotations

import csv
import json
import math
import shutil
from pathlib import Path

import numpy as np
from scipy import stats
from tqdm.auto import tqdm

from mrcomm_agents.artifacts import MODEL_FILE, STATISTICS_FILE, read_json
from mrcomm_agents.heldout import HELDOUT_SEEDS
from mrcomm_agents.learned import CARD_NAME, LearnedPolicy, pretrained_dir
from mrcomm_agents.training import TrainConfig, best_checkpoint, split_settings
from mrcomm_baselines import make_policy
from mrcomm_env.core.stats import mean_ci95
from mrcomm_env.experiments.actions import ActionProfile, profile_actions
from mrcomm_env.experiments.evaluation import baseline_label, evaluate_policy
from mrcomm_env.experiments.io import atomic_write_text
from mrcomm_env.experiments.runs import comparison_spec, run_folder, scored_policy_settings
from mrcomm_env.experiments.sweep import Task, run_tasks
from mrcomm_env.registry import canonical_id, env_revision, short_name

#: the first episode seed the comparison scores every policy on (training uses its own; held-out logs 30000+)
COMPARISON_SEEDS = 10_000
#: a learned point *matches* with up to this fraction more bits than a baseline (the bits' own noise), and sends
#: *fewer* only below the same fraction less
BITS_SLACK = 0.05


def within_bits(bits: float, baseline_bits: float) -> bool:
    """At most :data:`BITS_SLACK` more bits than the baseline's."""
    return bits <= baseline_bits * (1.0 + BITS_SLACK) + 1e-9


#: bootstrap resamples and their seed: the interval is a function of the values alone, so a rerun gives the same
#: page (rliable uses 50,000 resamples for its figures; 10,000 moves these intervals by well under 1 %)
BOOTSTRAP_RESAMPLES = 10_000
BOOTSTRAP_SEED = 0


def iqm_ci95(values) -> tuple[float, float, float]:
    """Interquartile mean and its 95 % percentile-bootstrap interval over runs, as rliable defines them
    (Agarwal et al., "Deep RL at the edge of the statistical precipice", NeurIPS 2021): the IQM is the 25 %
    trimmed mean (``rliable.metrics.aggregate_iqm`` is ``scipy.stats.trim_mean(scores, 0.25)``) and, with one
    task, rliable's stratified bootstrap resamples the runs of that task, which is scipy's percentile bootstrap.
    Returns (iqm, low, high); with fewer than 2 finite values the interval is the point itself."""
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return math.nan, math.nan, math.nan
    iqm = float(stats.trim_mean(x, 0.25))
    if x.size < 2 or np.all(x == x[0]):
        return iqm, iqm, iqm
    result = stats.bootstrap(
        (x,),
        lambda sample, axis=-1: stats.trim_mean(sample, 0.25, axis=axis),
        n_resamples=BOOTSTRAP_RESAMPLES,
        method="percentile",
        confidence_level=0.95,
        random_state=np.random.default_rng(BOOTSTRAP_SEED),
    )
    return iqm, float(result.confidence_interval.low), float(result.confidence_interval.high)


def heldout_seeds(spec: dict) -> list[int]:
    """The comparison's episode seeds, which no training or tuning sees: ``eval_episodes`` from COMPARISON_SEEDS."""
    return [COMPARISON_SEEDS + k for k in range(spec.get("eval_episodes", 10))]


def reproduce_learning(env_id: str, out_dir: Path, quick: bool = False, progress: bool = True):
    """Train ``seeds`` policies per cost value, evaluate them and every baseline on held-out seeds, and return
    (rows, markdown). Rows: policy, cost, metric mean ± CI, bits per agent per step mean ± CI. The training runs
    (each scored on the held-out seeds where it ran) go through the sweep runner the caller chose."""
    env_id = canonical_id(env_id)
    spec = comparison_spec(env_id)
    algo = spec["algo"]
    run_settings, hyper = split_settings(spec["settings"].get(algo, {}))
    env_kwargs = dict(run_settings.pop("env_kwargs", {}))
    timesteps = run_settings.pop("timesteps", 200_000)
    if quick:
        timesteps = spec.get("quick_timesteps", max(timesteps // 10, 1))
    seeds = list(range(spec.get("seeds", 3)))
    eval_seeds = heldout_seeds(spec)
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
    sweep = [
        Task(
            "mrcomm_env.experiments.train:train_and_evaluate",
            {"out": task["out"], "config": task["config"], "eval_seeds": eval_seeds},
            f"{cost_param}={task['cost']} s{task['seed']}",
        )
        for task in tasks
    ]
    rows = []
    learned: dict[float, list[dict]] = {}
    for task, done in zip(tasks, run_tasks(sweep, desc=f"training {short_name(env_id)}")):
        result = done["evaluation"]
        task["score"] = float(np.mean(result["metric"]))
        task["bits"] = float(np.mean(result["bits"]))
        learned.setdefault(task["cost"], []).append(result)
    for cost, results in learned.items():
        # one point per training seed (its mean over the evaluation episodes): the CI is over training seeds
        # np.mean, not nanmean: an episode without a value must show, not vanish from the average (an unfinished
        # time is counted at the episode's length by evaluate_policy)
        per_seed_metric = [float(np.mean(r["metric"])) for r in results]
        per_seed_bits = [float(np.mean(r["bits"])) for r in results]
        row = comparison_row(f"learned ({algo})", cost, per_seed_metric, per_seed_bits, len(results))
        row["metric_iqm"], row["metric_iqm_low"], row["metric_iqm_high"] = iqm_ci95(per_seed_metric)
        rows.append(row)
    # a baseline's actions do not depend on the price of bits, so it is evaluated once, unless the swept argument
    # changes the setting itself (``baselines_per_cost``: e.g. the communication range)
    costs = spec["costs"] if spec.get("baselines_per_cost") else [None]
    for name, params in tqdm(spec["baselines"], desc="evaluating baselines", disable=not progress, leave=False):
        for cost in costs:
            policy = make_policy(env_id, name, **params)
            kwargs = env_kwargs if cost is None else {**env_kwargs, cost_param: cost}
            result = evaluate_policy(env_id, kwargs, policy, eval_seeds, spec)
            label = baseline_label(name, params)
            row = comparison_row(label, None, result["metric"], result["bits"], len(eval_seeds))
            row["setting"] = cost
            rows.append(row)
    for row in rows:
        row.setdefault("setting", row["cost"])
    spec["tasks"] = [{"out": t["out"], "cost": t["cost"], "seed": t["seed"]} for t in tasks]
    spec["shipped"] = shipped_run(tasks, [r for r in rows if r["cost"] is None], spec, len(eval_seeds))
    spec["best_run"] = spec["shipped"]["run"]
    return rows, spec


def training_heldout(spec: dict) -> tuple[int, int]:
    """(first seed, episodes) of the held-out evaluation the comparison's runs log while they train."""
    settings = spec["settings"].get(spec["algo"], {})
    return HELDOUT_SEEDS, int(settings.get("eval_episodes", TrainConfig.eval_episodes))


def baseline_on_training_heldout(env_id: str, spec: dict, label: str, setting: float | None = None) -> dict:
    """The baseline named ``label`` in the table, played on the episodes of the runs' own held-out evaluation (the
    curves' episodes, not the comparison's): its mean metric and bits there, with the cost argument at ``setting``
    where the baselines are scored per setting."""
    name, params = next((n, p) for n, p in spec["baselines"] if baseline_label(n, p) == label)
    first, episodes = training_heldout(spec)
    env_kwargs = dict(spec["settings"].get(spec["algo"], {}).get("env_kwargs", {}))
    if setting is not None:
        env_kwargs[spec["cost_param"]] = setting
    seeds = list(range(first, first + episodes))
    result = evaluate_policy(env_id, env_kwargs, make_policy(env_id, name, **params), seeds, spec)
    return {"policy": label, "metric": float(np.mean(result["metric"])), "bits": float(np.mean(result["bits"]))}


def first_reach(points: list[dict], target: dict, lower_is_better: bool) -> dict | None:
    """The first of a run's curve points (in agent-steps) whose metric is at least as good as ``target``'s with at most
    5 % more bits (the comparison's slack), or None."""
    for point in sorted(points, key=lambda p: p["agent_steps"]):
        good = point["metric"] <= target["metric"] if lower_is_better else point["metric"] >= target["metric"]
        if good and within_bits(point["bits"], target["bits"]):
            return point
    return None


def best_baseline(baseline_rows: list[dict], setting, spec: dict, eligible=None) -> dict | None:
    """The scripted rule with the best task metric in ``setting`` (fewer bits breaks a tie), the paper's or ours;
    ``random`` is a reference, not a rule. ``eligible`` (a policy name → bool) narrows the rules, e.g. to the
    paper's own (:func:`mrcomm_baselines.from_paper`)."""
    sign = 1.0 if spec.get("lower_is_better") else -1.0
    rows = [
        r
        for r in baseline_rows
        if r["setting"] == setting
        and r["policy"].split()[0] != "random"
        and (eligible is None or eligible(r["policy"].split()[0]))
    ]
    return min(rows, key=lambda r: (sign * r["metric"], r["bits"])) if rows else None


def shipped_run(tasks: list[dict], baseline_rows: list[dict], spec: dict, episodes: int) -> dict:
    """The run ``--export-pretrained`` ships, and what its card says of it: the best task metric on the held-out
    episodes among the runs that send no more bits than the best scripted rule of their setting (with the 5 %
    slack of :func:`dominates`), so that a shipped model never buys its metric with more bits; the best metric
    overall when no run is that frugal. Where the swept argument changes the setting (``baselines_per_cost``), a
    metric is only comparable with its own setting's: the run whose metric is best *relative to* its setting's
    best scripted rule ships, then the one with the fewest bits relative to it."""
    sign = 1.0 if spec.get("lower_is_better") else -1.0
    per_cost = bool(spec.get("baselines_per_cost"))
    for task in tasks:
        task["baseline"] = best_baseline(baseline_rows, task["cost"] if per_cost else None, spec)

    def rank(task: dict) -> tuple:
        base = task["baseline"]
        if per_cost and base is not None and base["metric"] != 0 and base["bits"] > 0:
            relative = (sign * task["score"] / abs(base["metric"]), task["bits"] / base["bits"])
        else:
            relative = (sign * task["score"], task["bits"])
        return (*relative, task["cost"], task["seed"])

    frugal = [t for t in tasks if t["baseline"] is None or within_bits(t["bits"], t["baseline"]["bits"])]
    best = min(frugal or tasks, key=rank)
    baseline = best["baseline"]
    return {
        "run": best["out"],
        "heldout": {
            "metric": best["score"],
            "bits": best["bits"],
            "bits_per": spec.get("bits_per", "step"),
            "episodes": episodes,
            "first_seed": COMPARISON_SEEDS,
        },
        "best_baseline": None
        if baseline is None
        else {"policy": baseline["policy"], "metric": baseline["metric"], "bits": baseline["bits"]},
        "within_baseline_bits": bool(frugal),
    }


def curve_rows(tasks: list[dict], spec: dict) -> list[dict]:
    """Every run's held-out evaluations against agent-steps (the ``heldout/`` columns of its progress.csv,
    ``agents/heldout.py``). Where a step has two rows (the rollout's policy and, at the end, the final one), the
    later one is kept. ``seconds``: the run's training wall time so far, over every session of a resumed run (a
    session's ``time/time_elapsed`` starts again from 0, so each session goes on from where the log left off)."""
    metric, per = spec["metric"], spec.get("bits_per", "step")
    rows = []
    for task in tasks:
        path = Path(task["out"]) / "progress.csv"
        if not path.exists():
            continue
        points: dict[int, dict] = {}
        earlier_sessions, last = 0.0, 0.0
        with open(path, newline="") as fh:
            for raw in csv.DictReader(fh):
                if raw.get("time/time_elapsed"):
                    session = float(raw["time/time_elapsed"])
                    if session < last:  # a resumed session: the log up to its checkpoint was the earlier ones'
                        earlier_sessions += last
                    last = session
                value, bits = raw.get(f"heldout/{metric}"), raw.get(f"heldout/bits_per_agent_{per}")
                if not value or not bits or not raw.get("time/total_timesteps"):
                    continue
                steps = int(float(raw["time/total_timesteps"]))
                elapsed = earlier_sessions + last
                points[steps] = {
                    "cost": task["cost"],
                    "seed": task["seed"],
                    "agent_steps": steps,
                    "metric": float(value),
                    "bits": float(bits),
                    "seconds": float(elapsed),
                }
        rows += [points[k] for k in sorted(points)]
    return rows


def rl_phase(points: list[dict], episodes: int | None, first_seed: int) -> dict | None:
    """The held-out metric and bits at the start of a run's RL phase (agent-step 0: random weights, or the clone a
    warm start made) and at its end, from the run's curve (:func:`curve_rows`, one run's points in order); None
    without points. These are the run's own evaluations while training (``agents/heldout.py``: ``episodes``
    episodes from ``first_seed``), not the card's comparison episodes."""
    if not points:
        return None
    first, last = points[0], points[-1]
    return {
        "start": {"agent_steps": first["agent_steps"], "metric": first["metric"], "bits": first["bits"]},
        "end": {"agent_steps": last["agent_steps"], "metric": last["metric"], "bits": last["bits"]},
        "episodes": episodes,
        "first_seed": first_seed,
    }


def shipped_actions(env_id: str, spec: dict) -> ActionProfile | None:
    """What the run that ships (``spec["best_run"]``) chooses on the table's held-out episodes, beside the rules the
    comparison's ``actions_against`` names (``[name, params]`` pairs of its baselines), each asked at every state the
    learned policy reaches; None where the config names none."""
    against = spec.get("actions_against")
    if not against:
        return None
    policy = LearnedPolicy(spec["best_run"], env_id, spec["algo"], **scored_policy_settings(spec))
    rules = {baseline_label(name, params): make_policy(env_id, name, **params) for name, params in against}
    return profile_actions(env_id, policy.env_kwargs, policy, rules, heldout_seeds(spec))


def export_pretrained(run: str | Path, env_id: str, shipped: dict | None = None) -> Path:
    """Copy a run's model, statistics and config into ``agents/pretrained/<Name>-v0/`` (shipped in the package;
    ``mrcomm evaluate ID --policy pretrained``): its final model, or its best by held-out return where the
    comparison says ``"checkpoint": "best"`` (the model the comparison scored). Checkpoints and logs stay behind:
    well under 1 MB. ``shipped``: the comparison's account of the run (:func:`shipped_run`), written into the card."""
    spec = comparison_spec(env_id)
    chosen = scored_policy_settings(spec)["checkpoint"]
    source = best_checkpoint(Path(run)) if chosen == "best" else Path(run)
    target = pretrained_dir(env_id)
    target.mkdir(parents=True, exist_ok=True)
    for folder, name in ((source, MODEL_FILE), (source, STATISTICS_FILE), (Path(run), "config.json")):
        if (folder / name).exists():
            tmp = target / f".{name}.tmp"
            shutil.copyfile(folder / name, tmp)
            tmp.replace(target / name)
    record = json.loads((target / "config.json").read_text())
    # the agent-steps the model was trained for, which a rollout's length rounds up from the budget ``timesteps``
    state = source / "state.json"
    if state.exists():
        record = {**record, "trained_agent_steps": int(read_json(state)["num_timesteps"])}
    record["checkpoint"] = chosen
    cost = record.get("env_kwargs", {}).get(spec["cost_param"])
    points = curve_rows([{"out": str(run), "cost": cost, "seed": record.get("seed")}], spec)
    write_model_card(env_id, record, shipped, rl_phase(points, record.get("eval_episodes"), HELDOUT_SEEDS))
    return target


def write_model_card(env_id: str, record: dict, shipped: dict | None = None, phase: dict | None = None) -> Path:
    """``card.json`` beside a shipped model: what ``--policy pretrained`` and a reader need to know of it. The
    evaluation mode is the one the comparison chose the model with (``comparison.deterministic`` of
    ``agents/configs/<Name>-v0.json``, deterministic by default). ``phase``: :func:`rl_phase` of its run."""
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
        "agent_steps": record.get("trained_agent_steps", record.get("timesteps")),
        # which of its run's models ships: "final", or "best" by the run's held-out return (its agent_steps above)
        "checkpoint": record.get("checkpoint", "final"),
        "deterministic": bool(scored_policy_settings(spec)["deterministic"]),
        "metric": spec.get("metric"),
        "reproduce": f"mrcomm reproduce-learning {short_name(env_id)} --export-pretrained",
        # the env revision its held-out figures below were evaluated at (docs/learning.md flags a table the env has
        # changed since)
        "env_revision": env_revision(env_id),
    }
    if record.get("init_from"):
        card["init_from"] = record["init_from"]
    if shipped is not None:
        card["heldout"] = shipped["heldout"]
        card["best_baseline"] = shipped["best_baseline"]
    if phase is not None:
        card["rl_phase"] = phase
    path = pretrained_dir(env_id) / CARD_NAME
    atomic_write_text(path, json.dumps(card, indent=2) + "\n")
    return path


def stale_revision(env_id: str, rows: list[dict]) -> str | None:
    """The revision a recorded comparison table was trained and evaluated at (its rows' ``env_revision``) when the
    env has changed since, else None (a table written before the column was added says nothing: None)."""
    recorded = {str(row["env_revision"]) for row in rows if row.get("env_revision")}
    if not recorded:
        return None
    current = env_revision(env_id)
    stale = sorted(recorded - {current})
    return ", ".join(stale) if stale else None


def comparison_row(policy: str, cost, metric_values, bits_values, n: int) -> dict:
    """A row of the comparison table: the metric and bits as mean ± 95 % CI over ``n`` values."""
    m, mh = mean_ci95(metric_values)
    b, bh = mean_ci95(bits_values)
    return {
        "policy": policy,
        "cost": cost,
        "metric": m,
        "metric_ci95": mh,
        "bits": b,
        "bits_ci95": bh,
        "n": n,
        # a learned row's interquartile mean over training seeds (rliable's IQM and bootstrap, core/stats.py)
        "metric_iqm": None,
        "metric_iqm_low": None,
        "metric_iqm_high": None,
    }


def metric_interval(point: dict) -> tuple[float, float]:
    """The 95 % interval of a point's task metric: for a learned point with several training seeds, the bootstrap
    interval of its interquartile mean (robust to one collapsed seed, which makes a t-interval over 5 seeds
    wide enough to excuse anything); otherwise its mean ± the t half-width."""
    if point.get("metric_iqm") is not None and point.get("n", 0) >= 2:
        return float(point["metric_iqm_low"]), float(point["metric_iqm_high"])
    return point["metric"] - point["metric_ci95"], point["metric"] + point["metric_ci95"]


def finishes_some(point: dict, spec: dict) -> bool:
    """Whether a point finished any of its held-out episodes, where the metric is a time that an unfinished episode
    counts at the comparison's ``unfinished`` value (its mean is that value only when every episode is unfinished).
    A point that finishes none gets no verdict: sending fewer bits while never doing the task is no win, and
    matching a baseline that fails as well says nothing."""
    unfinished = spec.get("unfinished")
    return unfinished is None or not spec.get("lower_is_better") or point["metric"] < float(unfinished)


def dominates(learned: dict, baseline: dict, lower_is_better: bool) -> bool:
    """*Matches*: the learned point sends no more bits than the baseline (5 % slack for the bits' own noise) and
    its task metric is not worse beyond the two 95 % intervals (:func:`metric_interval`)."""
    if not within_bits(learned["bits"], baseline["bits"]):
        return False
    low, high = metric_interval(learned)
    base_low, base_high = metric_interval(baseline)
    return low <= base_high if lower_is_better else high >= base_low


#: #42's goal 2: a learned policy beats a rule by a margin when it is this much better on the task metric at
#: equal bits (5 % slack), or sends this much fewer bits at a metric not worse
METRIC_MARGIN, BITS_MARGIN = 0.10, 0.20


def margins(learned: dict, baseline: dict, lower_is_better: bool) -> tuple[float | None, float | None]:
    """How far a learned point is ahead of a baseline, as fractions of the baseline's figures, each taken at the
    worse ends of the two 95 % intervals (:func:`metric_interval`; bits: mean ± t half-width), so a margin that is
    there holds beyond the intervals. The metric margin counts only where the learned point sends at most 5 % more
    bits (:func:`within_bits`), the bits margin only where its metric is not worse (:func:`centre_not_worse`);
    ``None`` where its condition fails or the baseline's end is not positive."""
    low, high = metric_interval(learned)
    base_low, base_high = metric_interval(baseline)
    metric = None
    if within_bits(learned["bits"], baseline["bits"]):
        if lower_is_better and base_low > 0:
            metric = 1.0 - high / base_low
        elif not lower_is_better and base_high > 0:
            metric = low / base_high - 1.0
    bits = None
    not_worse = centre_not_worse(learned, baseline, lower_is_better)
    cheapest = baseline["bits"] - baseline["bits_ci95"]
    if not_worse and cheapest > 0:
        bits = 1.0 - (learned["bits"] + learned["bits_ci95"]) / cheapest
    return metric, bits


def centre_not_worse(learned: dict, baseline: dict, lower_is_better: bool) -> bool:
    """#42's "at a metric not worse", for the bits margin: the learned point's own figure (the IQM whose interval
    :func:`metric_interval` gives, else its mean) is no worse than the worse end of the baseline's 95 % interval.
    Overlapping intervals (the test of :func:`dominates`, a match) are not enough to claim a margin: with 5 episodes
    and 5 training seeds they passed a policy 23 % slower on average (RendezvousMapping v0 rev 4 at d_comms = 10:
    29.8 phases, IQM 30.6 [25.2, 33.7], against `paper_protocol`'s 24.2 ± 4.3)."""
    centre = learned.get("metric_iqm")
    if centre is None or learned.get("n", 0) < 2:
        centre = learned["metric"]
    base_low, base_high = metric_interval(baseline)
    return centre <= base_high if lower_is_better else centre >= base_low


def clearing_criterion(metric: float | None, bits: float | None) -> str | None:
    """Which of #42's goal 2 criteria one pair's margins clear: ``"metric"`` (:data:`METRIC_MARGIN` better, checked
    first), ``"bits"`` (:data:`BITS_MARGIN` fewer bits) or None."""
    if metric is not None and metric >= METRIC_MARGIN:
        return "metric"
    if bits is not None and bits >= BITS_MARGIN:
        return "bits"
    return None


def clears_margin(metric: float | None, bits: float | None) -> bool:
    """#42's goal 2 on one pair: :data:`METRIC_MARGIN` better, or :data:`BITS_MARGIN` fewer bits."""
    return clearing_criterion(metric, bits) is not None


def beats(learned: dict, baseline: dict, lower_is_better: bool) -> bool:
    """*Beats*: it matches the baseline and, beyond the two 95 % intervals, either has the better task metric or
    sends fewer bits (at least 5 % fewer, the slack that matching allows)."""
    if not dominates(learned, baseline, lower_is_better):
        return False
    low, high = metric_interval(learned)
    base_low, base_high = metric_interval(baseline)
    better = high < base_low if lower_is_better else low > base_high
    # fewer bits counts only beyond the intervals *and* the 5 % slack that matching allows: a point 2 % cheaper
    # but worse on average is a match, not a win
    saved = baseline["bits"] - learned["bits"]
    cheaper = saved > learned["bits_ci95"] + baseline["bits_ci95"] and saved > BITS_SLACK * baseline["bits"]
    return better or cheaper
