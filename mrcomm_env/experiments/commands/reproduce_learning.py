"""``mrcomm reproduce-learning``: learned policies against every baseline at equal bits, into docs/learning.md
(:mod:`mrcomm_env.experiments.comparison` trains and scores, :mod:`mrcomm_env.experiments.learning_report` renders)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from mrcomm_env.experiments.bounds import bound_rows
from mrcomm_env.experiments.comparison import curve_rows, export_pretrained, heldout_seeds, reproduce_learning
from mrcomm_env.experiments.evaluation import limit_threads
from mrcomm_env.experiments.io import atomic_write_csv, atomic_write_text
from mrcomm_env.experiments.learning_report import (
    learning_section,
    plot_comparison,
    plot_curves,
    read_rows,
    sweep_section,
    write_learning_page,
)
from mrcomm_env.experiments.runs import comparison_spec
from mrcomm_env.experiments.sweep import add_runner_arguments, runner_from_args, using
from mrcomm_env.registry import canonical_id, env_ids, make, short_name


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
    p.add_argument(
        "--record-scratch",
        metavar="RUN",
        help="record the held-out curve of RUN, a run from random weights, as the env's from-scratch table "
        "(docs/learning/<Name>-v0-scratch.csv) and re-render its section; one env only",
    )
    p.add_argument("--quiet", action="store_true")
    add_runner_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mrcomm_agents.training import CONFIG_DIR  # extra "train"

    limit_threads()
    targets = [canonical_id(e) for e in args.env_ids] or [
        e for e in env_ids() if (CONFIG_DIR / f"{short_name(e)}.json").exists()
    ]
    out = Path(args.out)
    docs = Path(args.docs)
    (docs / "learning").mkdir(parents=True, exist_ok=True)
    if args.record_scratch is not None:
        if len(targets) != 1:
            raise ValueError("--record-scratch takes one env id: the env of the run")
        record_scratch(targets[0], Path(args.record_scratch), docs)
    # no training: re-render every section from its recorded table (e.g. after ``make sweep`` or --record-scratch)
    if args.docs_only or args.record_scratch is not None:
        for env_id in targets:
            name = short_name(env_id)
            table = docs / "learning" / f"{name}.csv"
            if not table.exists():
                continue
            rows, spec = read_rows(table), comparison_spec(env_id)
            bounds = bound_rows(env_id, spec, heldout_seeds(spec))
            section = learning_section(env_id, rows, spec, f"learning/{name}.png", docs, bounds)
            atomic_write_text(docs / "learning" / f"{name}.md", section + sweep_section(env_id, docs))
        print(f"wrote {write_learning_page(docs)}")
        return 0
    with using(runner_from_args(args, progress=not args.quiet)):  # one set of workers for every env
        for env_id in targets:
            name = short_name(env_id)
            rows, spec = reproduce_learning(env_id, out / name, quick=args.quick, progress=not args.quiet)
            atomic_write_csv(docs / "learning" / f"{name}.csv", rows)
            if spec.get("scratch_run"):
                record_scratch(env_id, Path(spec["scratch_run"]), docs)
            curves = curve_rows(spec["tasks"], spec)
            if curves:
                atomic_write_csv(docs / "learning" / f"{name}-curves.csv", curves)
                plot_curves(curves, spec, f"{env_id}: learning curves", docs / "learning" / f"{name}-curves.png")
            figure = docs / "learning" / f"{name}.png"
            plot_comparison(rows, spec, f"{env_id}: learned vs scripted at equal bits", figure)
            bounds = bound_rows(env_id, spec, heldout_seeds(spec))
            section = learning_section(env_id, rows, spec, f"learning/{name}.png", docs, bounds)
            section += sweep_section(env_id, docs)
            # one fragment per env: rerunning one env keeps the others' sections in the page
            atomic_write_text(docs / "learning" / f"{name}.md", section)
            if args.export_pretrained:
                print(f"shipped {spec['best_run']} as {export_pretrained(spec['best_run'], env_id, spec['shipped'])}")
    page = write_learning_page(docs, quick=args.quick)
    print(f"wrote {page}")
    return 0


def record_scratch(env_id: str, run_dir: Path, docs: Path) -> Path:
    """Write ``run_dir``'s held-out curve (a run from random weights of ``env_id``) as the env's from-scratch table's
    source, ``docs/learning/<Name>-v0-scratch.csv``; the price of a bit is the run's value of the comparison's cost
    argument (the env's default where the run did not set it)."""
    config_path = run_dir / "config.json"
    if not config_path.exists():
        raise ValueError(f"--record-scratch: {run_dir} is not a run folder (it has no config.json)")
    config = json.loads(config_path.read_text())
    if canonical_id(config["env_id"]) != env_id:
        raise ValueError(f"--record-scratch: {run_dir} trained {config['env_id']}, not {env_id}")
    if config.get("init_from"):
        raise ValueError(f"--record-scratch: {run_dir} starts from a clone ({config['init_from']}), not random weights")
    spec = comparison_spec(env_id)
    cost_param = spec["cost_param"]
    probe = make(env_id, **config["env_kwargs"])
    cost = float(getattr(probe.cfg, cost_param))
    probe.close()
    rows = curve_rows([{"out": run_dir, "cost": cost, "seed": config["seed"]}], spec)
    if not rows:
        raise ValueError(f"--record-scratch: {run_dir}/progress.csv has no held-out evaluation")
    path = docs / "learning" / f"{short_name(env_id)}-scratch.csv"
    atomic_write_csv(path, rows)
    return path
