"""``mrcomm train`` (one shared policy for every agent of an env, or a sweep over seeds and a grid of settings) and
``mrcomm convert-run`` (a run folder written before the safe formats, rewritten): their parsers and runs. The sweep
itself is :mod:`mrcomm_env.experiments.train`; the training, :mod:`mrcomm_agents.training` (extra "train")."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from mrcomm_env.experiments.arguments import parse_params, positive_int, seed_type, split_values
from mrcomm_env.experiments.evaluation import limit_threads
from mrcomm_env.experiments.runs import train_settings
from mrcomm_env.experiments.sweep import add_runner_arguments
from mrcomm_env.registry import canonical_id, short_name


def add_parser(command) -> None:
    """``train``; ``command(name, **kw)`` adds a subcommand parser."""
    p = command("train", help="train one shared SB3 policy for every agent of an env")
    p.add_argument("env_id")
    p.add_argument(
        "--algo",
        default=None,
        help="ppo (default), maskable_ppo or dqn (SB3); ippo or mappo (the batched trainer, agents/batched_ppo.py)",
    )
    p.add_argument("--timesteps", type=positive_int, default=None, help="agent-steps (default: the env's config)")
    p.add_argument("--seed", type=seed_type, default=None, help="training seed (default 0)")
    p.add_argument("--out", required=False, help="run folder (default runs/<Name>-<algo>-s<seed>)")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="environment argument (JSON value)")
    p.add_argument("--config", metavar="FILE", help="JSON settings overriding agents/configs/<Name>-v0.json")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    p.add_argument(
        "--init-from",
        metavar="baseline:NAME",
        help="warm start: clone that scripted policy's decisions (DAgger) before PPO fine-tunes (agents/warm_start.py)",
    )
    p.add_argument(
        "--seeds", type=seed_list, metavar="S,S,…", help="train one run per seed (a sweep; instead of --seed)"
    )
    p.add_argument(
        "--grid",
        action="append",
        metavar="KEY=V,V,…",
        help="sweep KEY over the values (repeatable: every combination); KEY is a hyperparameter of --algo, a "
        "run setting (n_envs, net_arch, timesteps, …) or else an environment argument",
    )
    p.add_argument(
        "--eval-episodes",
        type=positive_int,
        default=5,
        help="sweeps: held-out episodes each run is scored on (seeds 20000+, apart from reproduce-learning's)",
    )
    p.add_argument(
        "--update-threads",
        type=positive_int,
        default=None,
        metavar="N",
        help="ippo/mappo: torch threads of the update (default min(2, cores)); 1 for each of two trainings sharing "
        "two cores (the trained bits depend on N, so it is kept with the run)",
    )
    p.add_argument(
        "--env-workers",
        type=positive_int,
        default=None,
        metavar="K",
        help="ippo/mappo: processes that step the copies, this one included (default: 2 on two or more cores where "
        "the env's copies step one after another, as AsyncCL's and RendezvousMapping's do, else 1); the trained bits "
        "do not depend on K",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument(
        "--trust-pickle",
        action="store_true",
        help="with --resume: a run written before the safe formats (it unpickles: only a run you made)",
    )
    add_runner_arguments(p)
    p.set_defaults(func=run)

    p = command(
        "convert-run",
        help="rewrite a run folder written before the safe formats (vecnormalize.pkl, pickles in model.zip)",
    )
    p.add_argument("run", help="the run folder (its checkpoints are converted too)")
    p.add_argument(
        "--trust-pickle",
        action="store_true",
        help="unpickle the run's vecnormalize.pkl to convert it: only for a run you made",
    )
    p.set_defaults(func=convert)


def convert(args: argparse.Namespace) -> int:
    from mrcomm_agents.training import convert_run  # extra "train"

    done = convert_run(Path(args.run), trust_pickle=args.trust_pickle)
    print(f"converted {len(done)} file(s) of {args.run}" if done else f"{args.run} is already in the safe formats")
    for path in done:
        print(f"  {path}")
    return 0


def seed_list(text: str) -> list[int]:
    """``0,1,2`` → [0, 1, 2]: distinct integers ≥ 0."""
    seeds = [seed_type(part.strip()) for part in text.split(",") if part.strip()]
    if not seeds or len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"--seeds takes distinct integers ≥ 0 separated by commas, got {text!r}")
    return seeds


def parse_grid(pairs: list[str] | None) -> dict[str, list]:
    """``["lam=0.01,0.1", "learning_rate=3e-4,1e-3"]`` → {key: [values]} (values read as JSON where possible)."""
    grid: dict[str, list] = {}
    for pair in pairs or []:
        key, sep, text = pair.partition("=")
        key = key.strip()
        if not sep or not key or not text.strip():
            raise ValueError(f"--grid takes KEY=V1,V2,…, got {pair!r}")
        if key in grid:
            raise ValueError(f"--grid names {key!r} twice")
        values = []
        for item in split_values(text):
            try:
                values.append(json.loads(item))
            except json.JSONDecodeError:
                values.append(item)
        grid[key] = values
    return grid


def run(args: argparse.Namespace) -> int:
    from mrcomm_agents.training import TrainConfig, train  # extra "train"
    from mrcomm_env.experiments.train import train_sweep  # the "train" extra, as above

    limit_threads()
    env_id = canonical_id(args.env_id)
    explicit = {"algo": args.algo, "seed": args.seed}  # None where the user named nothing
    args.algo = args.algo or "ppo"
    args.seed = 0 if args.seed is None else args.seed
    name = short_name(env_id)
    out = Path(args.out or f"runs/{name}-{args.algo}-s{args.seed}")
    if args.trust_pickle and not args.resume:
        raise ValueError("--trust-pickle applies to --resume only: a new run writes no pickle")
    if args.resume:
        for flag, value in (
            ("--config", args.config),
            ("--grid", args.grid),
            ("--seeds", args.seeds),
            ("--init-from", args.init_from),
            ("--update-threads", args.update_threads),
            ("--env-workers", args.env_workers),
        ):
            if value:
                raise ValueError(f"{flag} cannot be used with --resume: a resumed run keeps its own settings")
        requested = {"env_id": env_id, **explicit, "env_kwargs": parse_params(args.param), "timesteps": args.timesteps}
        train(None, out, resume=True, progress=not args.quiet, requested=requested, trust_pickle=args.trust_pickle)
        print(f"resumed and finished {out}")
        return 0
    params = parse_params(args.param)
    base, teacher = train_settings(
        env_id,
        args.algo,
        params,
        args.timesteps,
        args.config,
        init_from=args.init_from,
        update_threads=args.update_threads,
        env_workers=args.env_workers,
    )
    if args.seeds is not None or args.grid:
        sweep_out = Path(args.out or f"runs/{name}-{args.algo}-sweep")
        return train_sweep(base, args.seeds or [args.seed], parse_grid(args.grid), sweep_out, args)
    config = TrainConfig(seed=args.seed, **base)
    train(config, out, progress=not args.quiet, teacher=teacher)
    print(f"wrote {out}/model.zip, {out}/config.json, {out}/progress.csv")
    return 0
