"""``mrcomm bench``: env-steps/s against MPE2's ``simple_spread_v3``, and with flags training throughput, limits,
batches and the sweep runner (``experiments/bench.py`` measures; a benchmark, not a test)."""

from __future__ import annotations

import argparse
from pathlib import Path

from mrcomm_env.experiments import bench
from mrcomm_env.experiments.arguments import (
    check_writable_file,
    nonnegative_seconds,
    parse_params,
    positive_int,
    positive_seconds,
)
from mrcomm_env.experiments.evaluation import limit_threads
from mrcomm_env.experiments.io import atomic_write_json
from mrcomm_env.registry import canonical_id, env_ids, make


def add_parser(command) -> None:
    p = command("bench", help="env-steps/s against mpe2 simple_spread_v3 (a benchmark, not a test)")
    p.add_argument("env_ids", nargs="*")
    p.add_argument("--param", action="append", metavar="KEY=VALUE")
    p.add_argument("--runs", type=positive_int, default=3)
    p.add_argument("--seconds", type=positive_seconds, default=3.0, help="length of each run")
    p.add_argument(
        "--warmup", type=nonnegative_seconds, default=1.0, help="length of one untimed run before them (0: none)"
    )
    p.add_argument("--train", action="store_true", help="also PPO agent-steps/s through the training VecEnv")
    p.add_argument("--train-timesteps", type=positive_int, default=20_000, help="PPO agent-steps per env (--train)")
    p.add_argument(
        "--train-slots",
        type=positive_int,
        default=bench.TRAIN_SLOTS,
        help=f"about this many agent slots per VecEnv (--train; default {bench.TRAIN_SLOTS}: 4 copies of the "
        "reference); more slots step more copies per batch",
    )
    p.add_argument(
        "--train-shipped",
        action="store_true",
        help="--train, and also each env as its shipped training configuration runs it (agents/configs: env "
        "arguments and n_envs), against the reference at the same slot count",
    )
    p.add_argument(
        "--algo",
        choices=("ppo", *bench.BATCHED_BENCH_ALGORITHMS),
        default="ppo",
        help="--train's trainer: ppo (SB3 through the agent-slot VecEnv, the default) or the batched trainer's ippo "
        "or mappo (agents/batched_ppo.py), each against MPE2 + SB3 at --train-slots",
    )
    p.add_argument(
        "--train-copies",
        type=positive_int,
        default=None,
        metavar="M",
        help="--algo ippo/mappo: copies per world (default: about 512 agent rows, 16–256 copies)",
    )
    p.add_argument("--limits", action="store_true", help="also steps/s and peak memory at every documented maximum")
    p.add_argument(
        "--batched",
        action="store_true",
        help="also raw agent-steps/s and peak memory of M copies stepped as one batch (mrcomm_env.make_batched)",
    )
    p.add_argument(
        "--copies",
        type=positive_int,
        nargs="+",
        default=list(bench.BATCHED_COPIES),
        metavar="M",
        help="batch sizes for --batched (default: 1 64 1024)",
    )
    p.add_argument(
        "--sweep",
        action="store_true",
        help="instead: wall time of 16 seeded episodes of one env (default AsyncCL-v0) on --workers 1, "
        "--workers 2 and Ray with 2 CPUs, speed-ups and each backend's overhead (docs/scaling.md)",
    )
    p.add_argument("--out", default="results/bench.json")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    limit_threads()
    targets = [canonical_id(e) for e in args.env_ids] or env_ids()
    params = parse_params(args.param)
    out = check_writable_file(args.out, "--out")
    if args.sweep:
        return _sweep(args, params, out)
    for env_id in targets:  # every target accepts the params, before the first timed run
        make(env_id, **params).close()
        if args.train_shipped:  # and has a shipped training configuration that accepts them too
            _, shipped_kwargs, _ = bench.shipped_training(env_id)
            make(env_id, **{**shipped_kwargs, **params}).close()
    reference = bench.reference_section(args.seconds, args.runs, args.warmup)
    results = {"reference": reference}
    results["envs"] = bench.speed_section(targets, params, reference, args.seconds, args.runs, args.warmup)
    results["runs"] = args.runs
    results["seconds_per_run"] = args.seconds
    results["warmup_seconds"] = args.warmup
    results["extras"] = bench.extras_section(targets)
    if args.train or args.train_shipped:
        from mrcomm_env.experiments import bench_train  # the "train" extra: it trains

        results["train"] = bench_train.train_section(
            targets,
            params,
            args.train_timesteps,
            slots=args.train_slots,
            shipped=args.train_shipped,
            algo=args.algo,
            copies=args.train_copies,
        )
    if args.limits:
        results["limits"] = bench.limits_section(targets, args.seconds)
    if args.batched:
        results["batched"] = bench.batched_section(targets, params, tuple(args.copies), args.seconds, args.runs)
    atomic_write_json(out, results, indent=2)
    print(f"wrote {out} (median of {args.runs} runs of {args.seconds:g} s each)")
    return 0


def _sweep(args: argparse.Namespace, params: dict, out: Path) -> int:
    """``mrcomm bench --sweep``: the sweep runner's backends instead of env-steps/s (docs/scaling.md)."""
    if len(args.env_ids) > 1:
        raise ValueError(f"--sweep times one env, got {len(args.env_ids)}: {' '.join(args.env_ids)}")
    env_id = canonical_id(args.env_ids[0]) if args.env_ids else bench.SWEEP_ENV
    make(env_id, **params).close()  # bad --param values fail here, before the first timed run
    results = {"sweep": bench.sweep_section(env_id, bench.SWEEP_TASKS, args.runs, params)}
    atomic_write_json(out, results, indent=2)
    print(f"wrote {out} (median of {args.runs} runs per backend)")
    return 0
