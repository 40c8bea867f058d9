"""``mrcomm docs``: docs/envs/*.md (and missing recordings) from the live environments, or ``--check`` them."""

from __future__ import annotations

import argparse
from pathlib import Path

from mrcomm_env.experiments.docs import media_path, write_docs, write_media
from mrcomm_env.registry import env_ids


def add_parser(command) -> None:
    p = command("docs", help="generate docs/envs/*.md from the live environments")
    p.add_argument("--out", default="docs")
    p.add_argument("--check", action="store_true", help="exit 1 when the committed docs differ")
    p.add_argument("--media", action="store_true", help="record every env's GIF again (default: only missing ones)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    changed = write_docs(out, check=args.check)
    missing = [media_path(out, env_id) for env_id in env_ids() if not media_path(out, env_id).exists()]
    if args.check and (changed or missing):
        print("out of date: " + ", ".join(map(str, changed + missing)))
        return 1
    if not args.check:
        recorded = write_media(out, refresh=args.media)
        if recorded:
            print(f"recorded {', '.join(map(str, recorded))}")
    print("docs up to date" if args.check else f"wrote docs into {args.out}")
    return 0
