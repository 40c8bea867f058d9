"""``mrcomm race``: SB3 with an env's shipped settings against the batched trainer, held-out metric by wall time
(:mod:`mrcomm_env.experiments.race` does the work)."""

from __future__ import annotations

import argparse
from pathlib import Path

from mrcomm_env.experiments.arguments import positive_int
from mrcomm_env.experiments.evaluation import limit_threads
from mrcomm_env.registry import canonical_id, short_name


def add_parser(command) -> None:
    """``race``; ``command(name, **kw)`` adds a subcommand parser."""
    p = command(
        "race", help="SB3 with an env's shipped settings against the batched trainer: held-out metric by wall time"
    )
    p.add_argument("env_id")
    p.add_argument("--algo", choices=("ippo", "mappo"), default="ippo", help="the batched trainer's algorithm")
    p.add_argument("--seeds", type=positive_int, default=3, help="training seeds per trainer (0 … N−1)")
    p.add_argument("--out", default=None, help="folder (default results/race/<Name>)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mrcomm_env.experiments.race import race, race_configs, race_table  # the "train" extra: it trains

    limit_threads()
    env_id = canonical_id(args.env_id)
    race_configs(env_id, args.algo)  # a configuration that cannot race is refused before any training
    out = Path(args.out or f"results/race/{short_name(env_id)}")
    summary = race(env_id, args.seeds, out, args.algo, progress=not args.quiet)
    print(race_table(summary, args.algo), end="")
    print(f"wrote {out}/race.json, race.md, race.png, curves.csv")
    return 0
