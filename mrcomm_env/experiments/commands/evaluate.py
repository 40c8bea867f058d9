"""``mrcomm evaluate``: a policy for K episodes, the mean ± 95 % CI of every metric."""

from __future__ import annotations

import argparse
import sys
from functools import partial

from mrcomm_env.experiments.arguments import (
    add_episode_arguments,
    check_writable_dir,
    check_writable_file,
    parse_params,
)
from mrcomm_env.experiments.evaluation import evaluate, prepared_policy
from mrcomm_env.experiments.io import atomic_write_json
from mrcomm_env.experiments.record import record_episode
from mrcomm_env.registry import make, short_name


def add_parser(command) -> None:
    p = command("evaluate", help="run a policy for K episodes; mean ± 95%% CI of every metric")
    p.add_argument("env_id")
    p.add_argument("--policy", required=True)
    add_episode_arguments(p)
    p.add_argument("--policy-param", action="append", metavar="KEY=VALUE", help="policy parameter (JSON value)")
    p.add_argument("--json", metavar="PATH")
    p.add_argument("--video", metavar="DIR", help="also record the first episode into DIR/<Name>-<policy>.gif")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # down through each module once: the arguments and output paths checked, the policy built against its env and
    # its episodes played, the first one recorded where asked, the summary written
    params = parse_params(args.param)
    policy_params = parse_params(args.policy_param, "--policy-param")
    json_path = check_writable_file(args.json, "--json") if args.json else None
    video_dir = check_writable_dir(args.video, "--video") if args.video else None
    env_id, params, policy = prepared_policy(
        args.env_id, args.policy, params, policy_params, args.seed, trust_pickle=args.trust_pickle
    )
    metrics = evaluate(partial(make, env_id, **params), policy, args.episodes, args.seed, progress=not args.quiet)
    width = max(len(name) for name in metrics)
    print(f"{env_id}  policy={args.policy}  episodes={args.episodes}  seed={args.seed}  params={params}")
    for name, m in metrics.items():
        print(f"  {name:<{width}}  {m['mean']:>14.6g} ± {m['ci95']:.3g}")
    if video_dir is not None:
        name = f"{short_name(env_id)}-{args.policy.replace(':', '_').replace('/', '_')}.gif"
        video = record_episode(
            env_id, [args.policy], args.seed, video_dir / name, params, policy_params, trust_pickle=args.trust_pickle
        )
        print(f"recorded the first episode: {video['path']}", file=sys.stderr)
    if json_path is not None:
        record = {
            "env": env_id,
            "policy": args.policy,
            "episodes": args.episodes,
            "seed": args.seed,
            "params": params,
            "policy_params": policy_params,
            "metrics": metrics,
        }
        # NaN (a metric undefined in an episode, e.g. a subgraph that never completed) becomes null: strict JSON
        atomic_write_json(json_path, record, indent=2)
        print(f"wrote {json_path}")
    return 0
