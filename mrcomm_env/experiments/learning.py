"""``mrcomm train`` and the policy names ``evaluate`` accepts: scripted baselines and learned models alike."""

from __future__ import annotations

import argparse
from pathlib import Path

from mrcomm_env.registry import canonical_id


def make_any_policy(env_id: str, name: str, **params):
    """A scripted baseline by name, or a learned model: ``ppo:PATH``, ``maskable_ppo:PATH``, ``dqn:PATH``,
    ``pretrained``. Unknown names raise ``ValueError`` listing both kinds."""
    from baselines import make_policy, policy_names

    if name in policy_names(env_id):
        return make_policy(env_id, name, **params)
    try:
        from agents.learned import is_learned, load_policy
    except ImportError:
        if ":" in name or name == "pretrained":
            raise ValueError("learned policies need the training extra: pip install 'mrcomm-env[train]'") from None
        raise
    if is_learned(name):
        if params:
            raise ValueError(f"a learned policy takes no --policy-param, got {sorted(params)}")
        return load_policy(name, env_id)
    raise ValueError(
        f"unknown policy {name!r} for {canonical_id(env_id)}; valid policies are: "
        f"{', '.join(policy_names(env_id))}, pretrained, or ALGO:RUN_FOLDER with ALGO ppo, maskable_ppo or dqn"
    )


def add_train_parser(sub) -> None:
    p = sub.add_parser("train", help="train one shared SB3 policy for every agent of an env")
    p.add_argument("env_id")
    p.add_argument("--algo", default="ppo", help="ppo, maskable_ppo or dqn")
    p.add_argument("--timesteps", type=int, default=None, help="agent-steps (default: the env's tuned config)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=False, help="run folder (default runs/<Name>-<algo>-s<seed>)")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="environment argument (JSON value)")
    p.add_argument("--config", metavar="FILE", help="JSON settings overriding agents/configs/<Name>-v0.json")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train)


def cmd_train(args: argparse.Namespace) -> int:
    from agents.training import (
        TrainConfig,
        default_config,
        load_config_file,
        split_settings,
        train,
    )
    from mrcomm_env.experiments.cli import parse_params
    from mrcomm_env.experiments.evaluation import limit_threads
    from mrcomm_env.registry import short_name

    limit_threads()
    env_id = canonical_id(args.env_id)
    out = Path(args.out or f"runs/{short_name(env_id)}-{args.algo}-s{args.seed}")
    if args.resume:
        train(None, out, resume=True, progress=not args.quiet)
        print(f"resumed and finished {out}")
        return 0
    settings = default_config(env_id, args.algo)
    if args.config:
        settings = {**settings, **load_config_file(args.config, args.algo)}
    run, hyper = split_settings(settings)
    env_kwargs = {**run.pop("env_kwargs", {}), **parse_params(args.param)}
    timesteps = args.timesteps if args.timesteps is not None else run.pop("timesteps", 200_000)
    run.pop("timesteps", None)
    config = TrainConfig(
        env_id=env_id, algo=args.algo, timesteps=timesteps, seed=args.seed, env_kwargs=env_kwargs,
        hyperparams=hyper, **run,
    )
    train(config, out, progress=not args.quiet)
    print(f"wrote {out}/model.zip, {out}/config.json, {out}/progress.csv")
    return 0
