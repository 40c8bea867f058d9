"""``mrcomm reproduce-learning``: learned policies against every baseline at equal bits, into docs/learning.md
(:mod:`mrcomm_env.experiments.comparison` trains and scores, :mod:`mrcomm_env.experiments.learning_report` renders)."""

from __future__ import annotations

import argparse
from pathlib import Path

from mrcomm_env.experiments.evaluation import limit_threads
from mrcomm_env.experiments.io import atomic_write_csv, atomic_write_json, atomic_write_text
from mrcomm_env.experiments.runs import agent_config_dir, comparison_spec
from mrcomm_env.experiments.sweep import add_runner_arguments, runner_from_args, using
from mrcomm_env.registry import canonical_id, env_ids, env_revision, short_name


def add_parser(command) -> None:
    """``reproduce-learning``; ``command(name, **kw)`` adds a subcommand parser."""
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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # the "train" extra: the comparison trains, and the page reads the shipped models' cards
    from mrcomm_env.experiments import bounds, comparison, learning_report

    limit_threads()
    targets = [canonical_id(e) for e in args.env_ids] or [
        e for e in env_ids() if (agent_config_dir() / f"{short_name(e)}.json").exists()
    ]
    out = Path(args.out)
    docs = Path(args.docs)
    (docs / "learning").mkdir(parents=True, exist_ok=True)
    # no training: re-render every section from its recorded table (e.g. after ``make sweep``)
    if args.docs_only:
        for env_id in targets:
            name = short_name(env_id)
            table = docs / "learning" / f"{name}.csv"
            if not table.exists():
                continue
            rows, spec = learning_report.read_rows(table), comparison_spec(env_id)
            bound_table = bounds.bound_rows(env_id, spec, comparison.heldout_seeds(spec))
            section = learning_report.learning_section(env_id, rows, spec, f"learning/{name}.png", docs, bound_table)
            atomic_write_text(
                docs / "learning" / f"{name}.md", section + learning_report.sweep_section(env_id, docs, spec["algo"])
            )
        print(f"wrote {learning_report.write_learning_page(docs)}")
        return 0
    with using(runner_from_args(args, progress=not args.quiet)):  # one set of workers for every env
        for env_id in targets:
            name = short_name(env_id)
            rows, spec = comparison.reproduce_learning(env_id, out / name, quick=args.quick, progress=not args.quiet)
            # each row says which revision of the env it was trained and evaluated at (the page flags a table the env
            # has changed since)
            revision = env_revision(env_id)
            atomic_write_csv(docs / "learning" / f"{name}.csv", [{**row, "env_revision": revision} for row in rows])
            curves = comparison.curve_rows(spec["tasks"], spec)
            if curves:
                atomic_write_csv(docs / "learning" / f"{name}-curves.csv", curves)
                learning_report.plot_curves(
                    curves, spec, f"{env_id}: learning curves", docs / "learning" / f"{name}-curves.png"
                )
            figure = docs / "learning" / f"{name}.png"
            learning_report.plot_comparison(rows, spec, f"{env_id}: learned vs scripted at equal bits", figure)
            profile = comparison.shipped_actions(env_id, spec)
            if profile is not None:
                atomic_write_json(docs / "learning" / f"{name}-actions.json", profile.to_json(), indent=2)
            bound_table = bounds.bound_rows(env_id, spec, comparison.heldout_seeds(spec))
            section = learning_report.learning_section(env_id, rows, spec, f"learning/{name}.png", docs, bound_table)
            section += learning_report.sweep_section(env_id, docs, spec["algo"])
            # one fragment per env: rerunning one env keeps the others' sections in the page
            atomic_write_text(docs / "learning" / f"{name}.md", section)
            if args.export_pretrained:
                print(
                    f"shipped {spec['best_run']} as {comparison.export_pretrained(spec['best_run'], env_id, spec['shipped'])}"
                )
    page = learning_report.write_learning_page(docs, quick=args.quick)
    print(f"wrote {page}")
    return 0
