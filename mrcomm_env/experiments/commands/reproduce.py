"""``mrcomm reproduce``: the papers' experiments with the scripted baselines, and the report beside them."""

from __future__ import annotations

import argparse
import time

from mrcomm_env.experiments.arguments import check_writable_dir
from mrcomm_env.experiments.evaluation import limit_threads
from mrcomm_env.experiments.io import atomic_remove, atomic_write_text
from mrcomm_env.experiments.reproductions import run_reproduction
from mrcomm_env.experiments.sweep import add_runner_arguments, runner_from_args, using
from mrcomm_env.registry import canonical_id, env_ids, short_name

REPORT_NAME = "REPORT.md"


def add_parser(command) -> None:
    p = command("reproduce", help="the papers' experiments with the scripted baselines")
    p.add_argument("env_ids", nargs="*")
    p.add_argument("--all", action="store_true")
    p.add_argument("--quick", action="store_true", help="a reduced run that fits in a few minutes")
    p.add_argument(
        "--tiny",
        action="store_true",
        help="smoke-test sizes (seconds per env): every file is written, the numbers mean nothing",
    )
    p.add_argument("--out", default="results")
    add_runner_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    limit_threads()
    if args.all == bool(args.env_ids):
        raise ValueError("name environment ids or pass --all (not both)")
    targets = env_ids() if args.all else [canonical_id(e) for e in args.env_ids]
    out = check_writable_dir(args.out, "--out")
    report = out / REPORT_NAME
    # a REPORT.md describes the files of the run that wrote it: drop the old one before any file of this run
    # replaces one of that run's, so an interrupted run leaves no report at all rather than a wrong one
    atomic_remove(report)
    size = "tiny" if args.tiny else "quick" if args.quick else "full"
    sections = []
    runner = runner_from_args(args)
    with using(runner):  # one set of worker processes for every env's sweeps
        for env_id in targets:
            name = short_name(env_id)
            print(f"== reproducing {env_id} ({size}, {runner.backend}) ==", flush=True)
            start = time.perf_counter()
            # every Monte-Carlo sweep of the reproduction runs on this runner; each task's result is cached in
            # <out>/<env>/tasks, so a rerun after an interruption or a failed task skips what is done
            section = run_reproduction(env_id, out / name, quick=args.quick or args.tiny, tiny=args.tiny)
            # the report gives each env an H2; the section's own headings move one level down beneath it
            section = "\n".join("#" + line if line.startswith("#") else line for line in section.splitlines())
            elapsed = time.perf_counter() - start
            sections.append(f"## {env_id}\n\n_{size} run, {elapsed:.0f} s_\n\n{section}\n")
    command = " ".join(
        ["mrcomm reproduce", *(["--all"] if args.all else args.env_ids)]
        + (["--quick"] if args.quick else [])
        + (["--tiny"] if args.tiny else [])
        + ["--out", str(args.out)]
    )
    header = (
        "# mrcomm-env reproduction report\n\n"
        f"Command: `{command}`. Scripted baselines only. "
        "Each section puts the paper's numbers beside ours.\n\n"
    )
    atomic_write_text(report, header + "\n".join(sections))
    print(f"wrote {report}")
    return 0
