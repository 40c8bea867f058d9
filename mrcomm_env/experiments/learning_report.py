"""docs/learning.md, which ``mrcomm reproduce-learning`` writes (``commands/reproduce_learning.py``): per env, the comparison's table, its figure (task metric
against bits) and the verdicts of the equal-bits rule, plus the recorded hyperparameter sweep."""

from __future__ import annotations

import csv
import json
import math
import shlex
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from mrcomm_agents.learned import has_pretrained, model_card
from mrcomm_agents.training import default_config
from mrcomm_baselines import default_policy, from_paper
from mrcomm_env.core.stats import mean_ci95
from mrcomm_env.experiments.actions import ActionProfile, context_table, profile_table
from mrcomm_env.experiments.arguments import rule_argument
from mrcomm_env.experiments.bounds import bound_paragraph
from mrcomm_env.experiments.comparison import (
    BITS_MARGIN,
    METRIC_MARGIN,
    baseline_on_training_heldout,
    beats,
    best_baseline,
    clearing_criterion,
    clears_margin,
    dominates,
    finishes_some,
    first_reach,
    margins,
    stale_revision,
    training_heldout,
)
from mrcomm_env.experiments.evaluation import baseline_label
from mrcomm_env.experiments.io import atomic_write_text
from mrcomm_env.experiments.runs import comparison_spec, comparison_teacher
from mrcomm_env.registry import env_ids, env_revision, short_name


def plot_comparison(rows: list[dict], spec: dict, title: str, path: Path) -> None:
    """``metric`` against bits per agent: the learned points (one per price of a bit) and every baseline."""
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


def plot_curves(rows: list[dict], spec: dict, title: str, path: Path) -> None:
    """The learning curve: held-out metric and bits against agent-steps, a thin line per training seed and a
    thick one for their mean, a colour per price of a bit."""
    fig = Figure(figsize=(9.6, 3.6))
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    for k, cost in enumerate(sorted({r["cost"] for r in rows})):
        mine = [r for r in rows if r["cost"] == cost]
        for panel, key in zip(axes, ("metric", "bits")):
            for seed in sorted({r["seed"] for r in mine}):
                run = [r for r in mine if r["seed"] == seed]
                panel.plot([r["agent_steps"] for r in run], [r[key] for r in run], color=f"C{k}", alpha=0.3, lw=0.8)
            steps = sorted({r["agent_steps"] for r in mine})
            mean = [np.mean([r[key] for r in mine if r["agent_steps"] == x]) for x in steps]
            panel.plot(steps, mean, color=f"C{k}", lw=2, label=f"{spec['cost_param']} = {cost:g}")
    axes[0].set_ylabel(f"held-out {spec['metric']}")
    axes[1].set_ylabel(f"bits per agent per {spec.get('bits_per', 'step')}")
    for panel in axes:
        panel.set_xlabel("agent-steps")
        panel.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=90)
    tmp.replace(path)


def spread(values: list[float], fmt: str) -> str:
    """``low–high`` of ``values`` in format ``fmt``, or one number where both read the same."""
    low, high = format(min(values), fmt), format(max(values), fmt)
    return low if low == high else f"{low}–{high}"


def curves_paragraph(env_id: str, docs: Path | None) -> list[str]:
    """The learning-curve figure and its budget, where ``reproduce-learning`` recorded the runs' curves."""
    name = short_name(env_id)
    rows = read_curves(env_id, docs)
    if not rows:
        return []
    runs = {(r["cost"], r["seed"]) for r in rows}
    last = {
        run: max((r for r in rows if (r["cost"], r["seed"]) == run), key=lambda r: r["agent_steps"]) for run in runs
    }
    steps = sorted({int(r["agent_steps"]) for r in last.values()})
    minutes = spread([r["seconds"] / 60 for r in last.values()], ".1f")
    return [
        f"![learning curves: held-out metric and bits against agent-steps](learning/{name}-curves.png)",
        "",
        f"_Learning curves: {len(runs)} runs ({len({r['seed'] for r in rows})} training seeds per price), "
        f"{', '.join(f'{s:,}' for s in steps)} agent-steps each, {minutes} minutes of PPO per run (after any warm "
        "start; the curve starts at agent-step 0 with the policy PPO starts from); each point is the held-out "
        "evaluation logged while training "
        f"(`heldout/` in the run's progress.csv; recorded in `docs/learning/{name}-curves.csv`)._",
        "",
    ]


def read_curves(env_id: str, docs: Path | None, kind: str = "curves") -> list[dict]:
    """The runs' held-out curves as ``reproduce-learning`` recorded them: ``docs/learning/<Name>-v0-curves.csv``, or
    with ``kind="scratch-curves"`` those of the same section's runs from random weights that a comparison starting
    from a clone keeps beside its own (``<Name>-v0-scratch-curves.csv``, the curves file of an earlier revision)."""
    table = None if docs is None else docs / "learning" / f"{short_name(env_id)}-{kind}.csv"
    if table is None or not table.exists():
        return []
    with open(table, newline="") as fh:
        return [{k: float(v) for k, v in raw.items()} for raw in csv.DictReader(fh)]


def from_random_weights(env_id: str, baselines: list[dict], spec: dict, docs: Path | None) -> list[str]:
    """#42's from-scratch table, per price of a bit: how many of the runs (which start from random weights) reach the
    best scripted rule's metric at equal bits on their held-out curves (that algorithm played on the curves' own
    episodes), after how many agent-steps and wall seconds, and where the runs end; a sentence instead where the
    comparison's runs start from a clone."""
    teacher = comparison_teacher(spec)
    if not teacher:
        source = "**From random weights** (#42's goal 3, read from the learning curves): the first held-out evaluation"
        return scratch_table(env_id, read_curves(env_id, docs), baselines, spec, source)
    scratch = read_curves(env_id, docs, "scratch-curves")
    clone = f"The comparison's runs start from a clone of `{teacher}`"
    if not scratch:
        return [f"**From random weights.** {clone}; what training from random weights reached is in the notes below."]
    kept = f"docs/learning/{short_name(env_id)}-scratch-curves.csv"
    source = (
        f"**From random weights** (#42's goal 3). {clone}, so this table reads the curves of runs of the same "
        f"section without its warm start, from random weights (`{kept}`; the notes below say which runs): the "
        "first held-out evaluation"
    )
    return scratch_table(env_id, scratch, baselines, spec, source)


def scratch_table(env_id: str, curves: list[dict], baselines: list[dict], spec: dict, source: str) -> list[str]:
    """The from-scratch table of :func:`from_random_weights` over ``curves``, after its opening ``source``: per price
    of a bit, against the best scripted rule (of that setting, where the baselines are scored per setting)."""
    lower = bool(spec.get("lower_is_better"))
    per_setting = bool(spec.get("baselines_per_cost"))
    first, episodes = training_heldout(spec)
    per = spec.get("bits_per", "step")
    targets = {}
    for cost in sorted({r["cost"] for r in curves}):
        best = best_baseline(baselines, cost if per_setting else None, spec)
        if best is not None:
            setting = cost if per_setting else None
            targets[cost] = baseline_on_training_heldout(env_id, spec, best["policy"], setting)
    if not targets:
        return []
    if per_setting:
        scored = "; ".join(
            f"at {spec['cost_param']} = {cost:g}, `{t['policy']}` scores {t['metric']:.4g} at {t['bits']:.4g} bits"
            for cost, t in targets.items()
        )
        whose = "the best scripted rule's of its setting"
    else:
        t = next(iter(targets.values()))
        scored, whose = f"`{t['policy']}` scores {t['metric']:.4g} at {t['bits']:.4g} bits", f"`{t['policy']}`'s"
    lines = [
        f"{source} at which each run's {spec['metric']} is as good as {whose} with at most 5 % more bits, both on the "
        f"curves' own {episodes} episodes from seed {first:,} (where {scored} per agent per {per}); wall seconds "
        "include the evaluations.",
        "",
        f"| {spec['cost_param']} | runs that reach it | first at agent-steps | after seconds | at the end: "
        f"{spec['metric']}, bits (mean over the runs) |",
        "| --- | --- | --- | --- | --- |",
    ]
    for cost, target in targets.items():
        seeds = sorted({r["seed"] for r in curves if r["cost"] == cost})
        runs = [[r for r in curves if r["cost"] == cost and r["seed"] == seed] for seed in seeds]
        hits = [hit for hit in (first_reach(points, target, lower) for points in runs) if hit is not None]
        ends = [max(points, key=lambda p: p["agent_steps"]) for points in runs]
        reached = (
            f"{spread([h['agent_steps'] for h in hits], ',.0f')} | {spread([h['seconds'] for h in hits], '.1f')}"
            if hits
            else "— | —"
        )
        count = f"{len(hits)} of {len(runs)}"
        if not finishes_some(target, spec):  # the target never did the task: reaching its time means nothing
            count, reached = f"no target: `{target['policy']}` finishes none of the {episodes} episodes", "— | —"
        lines.append(
            f"| {cost:g} | {count} | {reached} | {np.mean([e['metric'] for e in ends]):.4g}, "
            f"{np.mean([e['bits'] for e in ends]):.4g} (after {spread([e['agent_steps'] for e in ends], ',.0f')} "
            f"agent-steps, {spread([e['seconds'] for e in ends], '.0f')} s) |"
        )
    return lines


def side_by_side(env_id: str, docs: Path | None) -> list[str]:
    """The recording of the shipped learned policy beside the paper's algorithm, where ``mrcomm docs`` made one
    (``docs/learning/<Name>-v0.gif``)."""
    name = short_name(env_id)
    if docs is None or not (docs / "learning" / f"{name}.gif").exists():
        return []
    return [
        f"![the shipped learned policy (left) and the paper's algorithm (right), seed 0](learning/{name}.gif)",
        "",
        f"_`mrcomm record {name} --policy pretrained --policy {default_policy(env_id)} --seed 0 --max-steps 40 "
        f"--out {name}.gif`_",
        "",
    ]


def learning_section(
    env_id: str, rows: list[dict], spec: dict, figure: str, docs: Path | None = None, bounds: Sequence[dict] = ()
) -> str:
    """An env's section of docs/learning.md: the table, the figure and the verdicts the equal-bits rule gives, and
    the ``bounds`` (:mod:`mrcomm_env.experiments.bounds`) as the table's last rows with what they rule out."""
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
        *curves_paragraph(env_id, docs),
        *side_by_side(env_id, docs),
        f"| policy | {spec['cost_param']} | {spec['metric']} (mean ± 95 % CI) | IQM [95 % bootstrap] "
        f"| bits / agent / {spec.get('bits_per', 'step')} | n |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for r in [*rows, *bounds]:
        cost = "—" if r["setting"] is None else f"{r['setting']:g}"
        iqm = "—"
        if r.get("metric_iqm") is not None:
            iqm = f"{r['metric_iqm']:.4g} [{r['metric_iqm_low']:.4g}, {r['metric_iqm_high']:.4g}]"
        lines.append(
            f"| {r['policy']} | {cost} | {r['metric']:.4g} ± {r['metric_ci95']:.2g} | {iqm} "
            f"| {r['bits']:.4g} ± {r['bits_ci95']:.2g} | {r['n']} |"
        )

    per_setting = bool(spec.get("baselines_per_cost"))
    judged = [r for r in learned if finishes_some(r, spec)]
    unjudged = ", ".join(f"{r['cost']:g}" for r in learned if not finishes_some(r, spec))

    def verdict(name: str) -> str:
        # with per-setting baselines a learned point is compared with the baseline in its own setting only
        candidates = [b for b in baselines if b["policy"] == name]

        def where(test) -> str:
            hits = [
                r
                for r in judged
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
        "bits and its metric is not worse beyond the two 95 % intervals (a learned point's: the bootstrap interval "
        "of its IQM over training seeds; a baseline's: its t-interval over episodes); it *beats* it when, in "
        "addition, its metric is better beyond the intervals, or it sends at least 5 % fewer bits, also beyond the "
        "intervals:",
        "",
        *verdicts,
    ]
    if unjudged:
        lines += [
            "",
            f"No verdict at {spec['cost_param']} = {unjudged}: the learned policy finished none of its held-out "
            f"episodes there (each counts as {spec['unfinished']:g}), and sending fewer bits while never doing the "
            "task is no win.",
        ]
    lines += margins_paragraph(env_id, rows, spec)
    lines += stale_paragraph(env_id, rows)
    best = best_baseline(baselines, None, spec)
    if best is not None and lower:  # the paragraph's margins are written for a metric where lower is better
        for bound in bounds:
            lines += ["", bound_paragraph(bound, best, learned, spec)]
    scratch = from_random_weights(env_id, baselines, spec, docs)
    if scratch:
        lines += ["", *scratch]
    lines += actions_paragraph(env_id, docs, spec.get("actions_against", []))
    if spec.get("notes"):
        lines += ["", spec["notes"]]
    return "\n".join(lines) + "\n"


#: the two references #42's goal 2 is measured against: the best of the paper's own algorithms (``FROM_PAPER``),
#: and the best scripted rule, ours included
REFERENCES = ("paper", "any")


@dataclass(frozen=True)
class Margin:
    """A learned point's margins over a reference rule (:func:`~mrcomm_env.experiments.comparison.margins`)."""

    learned: dict
    rule: dict
    metric: float | None
    bits: float | None

    @property
    def score(self) -> float:
        """The wider margin as a share of #42's threshold for it (``-inf`` where neither counts)."""
        shares = [m / t for m, t in ((self.metric, METRIC_MARGIN), (self.bits, BITS_MARGIN)) if m is not None]
        return max(shares, default=-math.inf)

    @property
    def clears(self) -> bool:
        return clears_margin(self.metric, self.bits)


def widest_margin(env_id: str, rows: list[dict], spec: dict, reference: str) -> Margin | None:
    """#42's goal 2 on one env's comparison table against ``reference`` (:data:`REFERENCES`): the best such rule
    (per setting, where the baselines are scored per setting) and the learned point with the widest margin over it
    (:attr:`Margin.score`); ``None`` where the table has no such rule or no learned point that finished an
    episode."""
    lower = bool(spec.get("lower_is_better"))
    per_setting = bool(spec.get("baselines_per_cost"))
    baselines = [r for r in rows if r["cost"] is None]
    eligible = (lambda name: bool(from_paper(env_id, name))) if reference == "paper" else None
    best: Margin | None = None
    for point in (r for r in rows if r["cost"] is not None and finishes_some(r, spec)):
        rule = best_baseline(baselines, point["cost"] if per_setting else None, spec, eligible)
        if rule is None:
            continue
        found = Margin(point, rule, *margins(point, rule, lower))
        if best is None or found.score > best.score:
            best = found
    return best


def percent(value: float, digits: int = 1) -> str:
    """A fraction as the page writes it: ``0.315`` → ``31.5 %``."""
    return f"{100 * value:.{digits}f} %"


def margin_text(found: Margin) -> str:
    """A margin of :func:`widest_margin` in words: the criterion that clears #42's threshold (bold), or both."""

    def share(value: float | None, ahead: str, behind: str) -> str:
        return "—" if value is None else f"{percent(abs(value))} {ahead if value >= 0 else behind}"

    metric = share(found.metric, "better", "worse")
    bits = share(found.bits, "fewer bits", "more bits")
    cleared = clearing_criterion(found.metric, found.bits)
    if cleared is not None:
        return f"**{metric if cleared == 'metric' else bits}**"
    return f"short of it: {metric}, {bits}"


def rule_text(env_id: str, rule: dict) -> str:
    """A reference rule with where its paper describes it, or "ours"."""
    source = from_paper(env_id, rule["policy"].split()[0])
    return f"`{rule['policy']}` ({'paper: ' + source if source else 'ours'})"


GOAL_2 = (
    f"#42's goal 2: {percent(METRIC_MARGIN, 0)} better on the task metric at equal bits, or "
    f"{percent(BITS_MARGIN, 0)} fewer bits at a metric not worse (the learned point's IQM no worse than the worse "
    "end of the rule's interval), each margin at the worse ends of the two 95 % intervals, `comparison.margins`"
)


def margins_paragraph(env_id: str, rows: list[dict], spec: dict) -> list[str]:
    """An env's margins over the best of its paper's algorithms and over the best scripted rule, ours included."""
    paper, any_rule = (widest_margin(env_id, rows, spec, reference) for reference in REFERENCES)
    if paper is None and any_rule is None:
        return []

    def sentence(found: Margin | None, what: str) -> str:
        if found is None:
            return f"The table has no {what}."
        rule, learned = found.rule, found.learned
        cleared = " (clears the margin)" if found.clears else ""
        return (
            f"{what[0].upper()}{what[1:]} is {rule_text(env_id, rule)}, {rule['metric']:.4g} at {rule['bits']:.4g} "
            f"bits; the learned point at {spec['cost_param']} = {learned['cost']:g} is {margin_text(found)}{cleared}."
        )

    same = paper is not None and any_rule is not None and paper.rule is any_rule.rule
    text = " ".join(
        [
            f"**Margins** ({GOAL_2}).",
            sentence(paper, "the best of the paper's own algorithms"),
            "It is also the best scripted rule."
            if same
            else sentence(any_rule, "the best scripted rule, ours included,"),
        ]
    )
    return ["", text]


def stale_paragraph(env_id: str, rows: list[dict]) -> list[str]:
    """Where the env has changed since its table was recorded: which revisions, and what the shipped model scores at
    the current one (its card, when it was evaluated there)."""
    stale = stale_revision(env_id, rows)
    if not stale:
        return []
    current = env_revision(env_id)
    text = (
        f"**Recorded at {stale}.** The env is now {current} (CHANGELOG), and the table, curves, margins and action "
        f"shares above are {stale}'s: the summary at the top leaves them out until `mrcomm reproduce-learning "
        f"{short_name(env_id)} --export-pretrained` trains and evaluates the comparison again."
    )
    card = model_card(env_id) if has_pretrained(env_id) else {}
    if card.get("env_revision") == current and "heldout" in card and card.get("best_baseline"):
        heldout, rule = card["heldout"], card["best_baseline"]
        text += (
            f" The shipped model scores {heldout['metric']:.4g} at {heldout['bits']:.5g} bits on "
            f"the table's {heldout['episodes']} episodes at {current}, where `{rule['policy']}` scores "
            f"{rule['metric']:.4g} at {rule['bits']:.5g} (its card)."
        )
    return ["", text]


def margins_table(docs: Path) -> list[str]:
    """The page's summary of #42's goal 2: per env, where RL starts and its margins over the two references."""
    lines = [
        "| env | RL starts from | best paper algorithm | learned's margin over it | best rule, ours included "
        "| learned's margin over it |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    cleared = dict.fromkeys(REFERENCES, 0)
    envs = 0
    stale_envs = []
    for env_id in env_ids():
        table = docs / "learning" / f"{short_name(env_id)}.csv"
        if not table.exists():
            continue
        spec = comparison_spec(env_id)
        rows = read_rows(table)
        envs += 1
        stale = stale_revision(env_id, rows)
        if stale:
            stale_envs.append(f"{short_name(env_id)}'s (recorded at {stale})")
        teacher = comparison_teacher(spec)
        cells = [short_name(env_id), f"a clone of `{teacher}`" if teacher else "random weights"]
        for reference in REFERENCES:
            found = widest_margin(env_id, rows, spec, reference)
            if found is None:
                cells += ["—", "—"]
                continue
            cleared[reference] += found.clears and not stale
            setting = ""
            if spec.get("baselines_per_cost"):
                setting = f" at {spec['cost_param']} = {found.rule['setting']:g}"
            cells += [
                rule_text(env_id, found.rule) + setting,
                f"{margin_text(found)} ({spec['cost_param']} = {found.learned['cost']:g})"
                + (f"; recorded at {stale}, not counted" if stale else ""),
            ]
        lines.append("| " + " | ".join(cells) + " |")
    not_counted = ""
    if stale_envs:
        not_counted = (
            f" The counts leave out {' and '.join(stale_envs)} table: the env has changed since it was recorded "
            "(its section names the revisions), so its margins are those of another revision until it is trained again."
        )
    return [
        f"**Against the papers, computed from the tables below** ({GOAL_2}): the learned policy clears the margin "
        f"over the best of the paper's own algorithms on {cleared['paper']} of {envs} envs, and over the best "
        f"scripted rule, ours included, on {cleared['any']} of {envs}.{not_counted} A rule is the paper's where "
        "its policy says "
        'where the paper describes it (`FROM_PAPER`, the column "from the paper" of each env page\'s baselines); '
        "the others are ours or references (`random`, `never`, `silent`). Each margin is the widest of the env's "
        "learned points over the best such rule of its setting (best by the metric; bold: cleared; the env's "
        "section gives both figures).",
        "",
        *lines,
        "",
    ]


def actions_paragraph(env_id: str, docs: Path | None, against: Sequence) -> list[str]:
    """What the shipped model chooses beside the rules it is compared with, from ``docs/learning/<Name>-v0-actions.json``
    (written by ``reproduce-learning`` from the config's comparison's ``actions_against``: ``[name, params]`` pairs,
    from which the paragraph writes the command's ``--against`` arguments)."""
    name = short_name(env_id)
    path = None if docs is None else docs / "learning" / f"{name}-actions.json"
    if path is None or not path.exists():
        return []
    profile = ActionProfile.from_json(json.loads(path.read_text()))
    seeds = profile.seeds
    if [baseline_label(rule, params) for rule, params in against] != profile.rules:
        raise ValueError(
            f"{path} holds the rules {profile.rules}, but the config's actions_against names {against}: rerun "
            "`mrcomm reproduce-learning` for this env (without --docs-only)"
        )
    arguments = " ".join(f"--against {shlex.quote(rule_argument(rule, params))}" for rule, params in against)
    return [
        "",
        f"What the shipped model chooses, from its actions on the table's {len(seeds)} held-out episodes "
        f"({profile.decisions:,} decisions). Each rule was asked at every state the learned policy reached, and only "
        f"the learned policy's actions were stepped (`mrcomm actions {name} --policy pretrained {arguments} "
        f"--episodes {len(seeds)} --seed {seeds[0]}`):",
        "",
        *profile_table(profile),
        *(
            [
                "",
                "The same decisions split by each robot's situation when it chose (the env's `decision_context`):",
                "",
                *context_table(profile),
            ]
            if profile.by_context
            else []
        ),
    ]


def read_rows(path: Path) -> list[dict]:
    """The comparison rows as ``reproduce-learning`` wrote them to ``docs/learning/<Name>-v0.csv``."""

    def number(text: str):
        return None if text == "" else float(text)

    rows = []
    for raw in csv.DictReader(open(path)):
        row = {k: number(v) for k, v in raw.items() if k not in ("policy", "env_revision")}
        row["policy"], row["n"] = raw["policy"], int(float(raw["n"]))
        if raw.get("env_revision"):  # the env revision the row was trained and evaluated at (tables since v0 rev 4)
            row["env_revision"] = raw["env_revision"]
        rows.append(row)
    return rows


def warm_start_sentence(docs: Path | None = None) -> str:
    """Which comparisons start from a clone of a scripted baseline (their config section's ``init_from``), read from
    the shipped configurations, for the page's header, and where each one's from-random-weights figures are: its
    table over kept curves (:func:`from_random_weights`) or its notes."""
    cloned = []
    for env_id in env_ids():
        try:
            spec = comparison_spec(env_id)
        except ValueError:  # no learning configuration
            continue
        teacher = comparison_teacher(spec)
        if teacher:
            where = "table reads kept curves of" if read_curves(env_id, docs, "scratch-curves") else "notes give"
            cloned.append(f"{short_name(env_id)}'s from a clone of `{teacher}`, whose {where} runs from random weights")
    if not cloned:
        return "every comparison here trains from random weights"
    return "every comparison here trains from random weights but " + "; ".join(cloned)


def write_learning_page(docs: Path, quick: bool = False) -> Path:
    """``docs/learning.md``: the header, every env's fragment ``docs/learning/<Name>-v0.md`` (registry order) and
    the footer."""
    sections = [
        (docs / "learning" / f"{short_name(e)}.md").read_text()
        for e in env_ids()
        if (docs / "learning" / f"{short_name(e)}.md").exists()
    ]
    header = LEARNING_HEADER.format(
        command="mrcomm reproduce-learning" + (" --quick" if quick else ""), starts=warm_start_sentence(docs)
    )
    summary = "\n".join(margins_table(docs)) + "\n" if sections else ""
    page = docs / "learning.md"
    atomic_write_text(page, header + summary + "\n".join(sections) + LEARNING_FOOTER)
    return page


def sweep_section(env_id: str, docs: Path, compared_algo: str | None = None) -> str:
    """The recorded hyperparameter sweep of ``env_id`` (``make sweep``: ``docs/learning/sweep-<Name>-v0.csv`` and
    its ``.json``), as a table of grid points ranked by their mean held-out score; empty when none is recorded.
    Where the comparison trains another config section (``compared_algo``) than the sweep tuned, it says so."""
    name = short_name(env_id)
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
    swept = meta.get("algo", "ppo")
    settings = default_config(env_id, swept)
    chosen = ", ".join(f"`{k}={json.dumps(settings.get(k, settings.get('env_kwargs', {}).get(k)))}`" for k in keys)
    lines += ["", f"`agents/configs/{name}.json`'s `{swept}` section trains with {chosen}."]
    if compared_algo is not None and compared_algo != swept:
        lines[-1] += (
            f" This sweep tuned the `{swept}` section; the comparison above trains the `{compared_algo}` section, "
            "whose settings no recorded sweep chose."
        )
    return "\n".join(lines) + "\n"


LEARNING_HEADER = """# Learned communication against the papers' algorithms, at equal bits

_Generated by `{command}` (`make learn`); do not edit by hand. Settings: `agents/configs/<Name>-v0.json`; the
recorded hyperparameter sweep under each env's section (`make sweep`) says which of its sections it tuned._

One policy is shared by every agent (parameter sharing): PPO through SB3 (`agents/vecenv.py`), or the batched
trainer's IPPO or MAPPO where the env's table says `learned (ippo)` or `learned (mappo)` (`agents/batched_ppo.py`;
MAPPO's critic also reads `env.state()`). For each env, the price of a
bit in the reward (the cost argument) is swept; each value is trained with several seeds and each trained
policy is evaluated on held-out episode seeds (deterministically unless the env's section says otherwise): its final
model, or where the env's section says so its best checkpoint, the one the run's own held-out evaluation while
training (`heldout/`, episodes from seed 30,000, apart from the table's) scored highest by return (`best.json`,
rl-zoo3's `best_model`). A
learned point's interval is over training seeds; a baseline's over episodes. Beside a learned point's mean, the
column "IQM" gives rliable's interquartile mean over its training seeds with a 95 % percentile-bootstrap
interval (`mrcomm_env/experiments/comparison.py`: with 3 seeds the IQM is the mean; "—" where the recorded table predates
the column). Each shipped model is the best run within the bits of the best scripted rule of its setting (where
the cost argument is the setting itself, RendezvousMapping's range, the best relative to that algorithm's metric);
its card (`agents/pretrained/<Name>-v0/card.json`) gives its held-out metric and bits beside that algorithm's,
and under `rl_phase` its run's own held-out evaluation at the start of the RL phase (agent-step 0: random
weights, or the clone of a warm start) and at its end.
Where an env has one, a **bound** row gives what no policy can pass on the same held-out episodes, computed from the
live env (`mrcomm_env/experiments/bounds.py`), with what it rules out of beating the best scripted rule by 10 %
on the metric or by 20 % on bits. A **reference** row (MultiHop's `oracle`) is no bound but a policy
with knowledge the learned policy's observation lacks, which shows whether the 10 % margin is there to be found.
**From random weights** says when each run that starts from random weights first reaches that algorithm's metric
at equal bits on its own held-out curve ({starts}).
**What the shipped model chooses** plays it on the table's held-out episodes and asks the paper's rules at every
state it reaches (`mrcomm actions`, `mrcomm_env/experiments/actions.py`): the share of each action, how often it
chose as each rule would, and where the env names each robot's situation, the same split by it.
While training, `progress.csv` and TensorBoard carry a held-out evaluation under `heldout/` (the env's metrics
and bits per robot; `agents/heldout.py`). The scripted baselines see more than the learned policy where the env's
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
