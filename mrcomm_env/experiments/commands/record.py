"""``mrcomm record``: one episode, several policies side by side, as a GIF or MP4."""

from __future__ import annotations

import argparse

from mrcomm_env.experiments.arguments import (
    check_writable_file,
    parse_params,
    positive_int,
    positive_seconds,
    seed_type,
)
from mrcomm_env.experiments.evaluation import limit_threads
from mrcomm_env.experiments.record import record_episode


def add_parser(command) -> None:
    p = command("record", help="record one episode, several policies side by side, as a GIF or MP4")
    p.add_argument("env_id")
    p.add_argument("--policy", action="append", required=True, help="a policy (repeat for panels side by side)")
    p.add_argument("--seed", type=seed_type, default=0, help="the episode's seed (the same for every panel)")
    p.add_argument("--out", required=True, help="episode.gif, or episode.mp4 with the video extra")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="environment argument (JSON value)")
    p.add_argument("--policy-param", action="append", metavar="KEY=VALUE", help="policy parameter (JSON value)")
    p.add_argument("--max-steps", type=positive_int, default=None, help="stop after this many steps")
    p.add_argument("--fps", type=positive_seconds, default=4.0, help="frames per second of the recording")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    limit_threads()
    out = check_writable_file(args.out, "--out")
    result = record_episode(
        args.env_id,
        args.policy,
        args.seed,
        out,
        params=parse_params(args.param),
        policy_params=parse_params(args.policy_param, "--policy-param"),
        max_steps=args.max_steps,
        fps=args.fps,
    )
    print(f"wrote {result['path']}: {result['frames']} frames, {result['bytes'] / 1e6:.2f} MB")
    return 0
