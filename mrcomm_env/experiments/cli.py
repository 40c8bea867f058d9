"""The ``mrcomm`` command: list, evaluate, train, reproduce, reproduce-learning, bench and docs.

Errors are one line on stderr and a non-zero exit (2 for bad input, 1 for a failure during the work,
130 for Ctrl-C); ``--debug`` shows the traceback instead. Arguments, ``--param`` values and output paths
are all checked before the work starts, and every result file is written atomically
(:mod:`mrcomm_env.experiments.io`).
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from pathlib import Path

from tqdm.auto import tqdm

from mrcomm_baselines import default_policy, make_policy, policy_names
from mrcomm_env.core import backend
from mrcomm_env.experiments import bench
from mrcomm_env.experiments.arguments import (
    nonnegative_seconds,
    parse_params,
    positive_int,
    positive_seconds,
    seed_type,
)
from mrcomm_env.experiments.docs import media_path, write_docs, write_media
from mrcomm_env.experiments.evaluation import evaluate, limit_threads, make_any_policy, steps_per_second
from mrcomm_env.experiments.io import (
    atomic_remove,
    atomic_write_json,
    atomic_write_text,
    check_writable_dir,
    check_writable_file,
)
from mrcomm_env.experiments.learning_report import add_reproduce_learning_parser
from mrcomm_env.experiments.race import add_race_parser
from mrcomm_env.experiments.record import record_episode
from mrcomm_env.experiments.reproductions import module as reproduction_module
from mrcomm_env.experiments.reproductions import run_reproduction
from mrcomm_env.experiments.sweep import SweepError, add_runner_arguments, runner_from_args, using
from mrcomm_env.experiments.train import add_train_parser
from mrcomm_env.registry import canonical_id, env_class, env_ids, make, short_name

BENCH_REFERENCE = "mpe2 simple_spread_v3 (N=3, discrete actions, random actions)"
EXIT_BAD_INPUT = 2
EXIT_FAILURE = 1
EXIT_INTERRUPTED = 130  # 128 + SIGINT, what a shell reports for a program stopped by Ctrl-C


def _json_safe(obj):
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


# ---------------------------------------------------------------------------------------------- commands
def cmd_list(args) -> int:

    for env_id in env_ids():
        cls = env_class(env_id)
        print(f"{env_id}  —  {cls.DESCRIPTION}")
        policies = [f"{p}*" if p == default_policy(env_id) else p for p in policy_names(env_id)]
        print(f"    policies (* default): {', '.join(policies)}")
        print(f"    reproduction: {', '.join(reproduction_module(env_id).EXPERIMENTS)}")
    return 0


def cmd_evaluate(args) -> int:

    limit_threads()
    env_id = canonical_id(args.env_id)
    params = parse_params(args.param)
    policy_params = parse_params(args.policy_param, "--policy-param")
    json_path = check_writable_file(args.json, "--json") if args.json else None
    # everything a bad argument could break is built once before the first episode: the env with its
    # params, the policy with its params, and the policy's reset against this env (e.g. a mode it needs)
    policy = make_any_policy(env_id, args.policy, trust_pickle=args.trust_pickle, **policy_params)
    trained_on = getattr(policy, "env_kwargs", None)
    if trained_on is not None:
        # a learned model acts in the setting it was trained in (its spaces depend on the env's arguments): the
        # run's own env arguments are the default, and --param overrides them one by one
        params = {**trained_on, **params}
        print(f"learned model: its training setting with --param applied, {params}", file=sys.stderr)
    probe = make(env_id, **params)
    try:
        probe.reset(seed=args.seed)
        policy.reset(probe.local_views(), args.seed)
    finally:
        probe.close()
    if args.video:
        folder = check_writable_dir(args.video, "--video")
        name = f"{short_name(env_id)}-{args.policy.replace(':', '_').replace('/', '_')}.gif"
        video = record_episode(
            env_id, [args.policy], args.seed, folder / name, params, policy_params, trust_pickle=args.trust_pickle
        )
        print(f"recorded the first episode: {video['path']}", file=sys.stderr)
    metrics = evaluate(lambda: make(env_id, **params), policy, args.episodes, args.seed, progress=not args.quiet)
    width = max(len(name) for name in metrics)
    print(f"{env_id}  policy={args.policy}  episodes={args.episodes}  seed={args.seed}  params={params}")
    for name, m in metrics.items():
        print(f"  {name:<{width}}  {m['mean']:>14.6g} ± {m['ci95']:.3g}")
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
        atomic_write_json(json_path, _json_safe(record), indent=2, allow_nan=False)
        print(f"wrote {json_path}")
    return 0


def cmd_record(args) -> int:

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


REPORT_NAME = "REPORT.md"


def cmd_reproduce(args) -> int:

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
        "Each section puts the paper's numbers beside ours. "
        f"Compiled twins of hot loops: {backend.name()} (`{backend.VARIABLE}`; see docs/architecture.md).\n\n"
    )
    atomic_write_text(report, header + "\n".join(sections))
    print(f"wrote {report}")
    return 0


def cmd_bench(args) -> int:

    limit_threads()
    targets = [canonical_id(e) for e in args.env_ids] or env_ids()
    params = parse_params(args.param)
    out = check_writable_file(args.out, "--out")
    if args.sweep:
        return _bench_sweep(args, params, out)
    for env_id in targets:  # every target accepts the params, before the first timed run
        make(env_id, **params).close()
        if args.train_shipped:  # and has a shipped training configuration that accepts them too
            _, shipped_kwargs, _ = bench.shipped_training(env_id)
            make(env_id, **{**shipped_kwargs, **params}).close()
    runs = args.runs

    def median_of(measure, label):
        # one untimed warm-up run first: caches, lazily built tables and compiled kernels are then loaded,
        # as they are in any run longer than a few seconds
        if args.warmup > 0:
            measure(-1, args.warmup)
        samples = [measure(k) for k in tqdm(range(runs), desc=label, leave=False)]
        return statistics.median(s[0] for s in samples), statistics.median(s[1] for s in samples)

    from mpe2 import simple_spread_v3

    ref_env = simple_spread_v3.parallel_env(N=3, continuous_actions=False)
    space = ref_env.action_space(ref_env.possible_agents[0])
    space.seed(0)
    ref = median_of(
        lambda k, s=args.seconds: steps_per_second(
            ref_env, lambda obs: {a: space.sample() for a in obs}, s, seed=k % 10_000
        ),
        "simple_spread_v3",
    )
    print(f"reference {BENCH_REFERENCE}: {ref[0]:,.0f} env-steps/s, {ref[1]:,.0f} agent-steps/s")
    results = {"reference": {"name": BENCH_REFERENCE, "env_steps_per_s": ref[0], "agent_steps_per_s": ref[1]}}
    results["backend"] = backend.name()
    print(
        f"compiled twins of hot loops: {results['backend']} ({backend.VARIABLE}="
        f"{os.environ.get(backend.VARIABLE, 'auto')})"
    )
    results["envs"] = {}
    for env_id in targets:
        env = make(env_id, **params)
        policy_name = default_policy(env_id)
        policy = make_policy(env_id, policy_name)
        eps, aps = median_of(
            lambda k, s=args.seconds, env=env, policy=policy: _policy_speed(env, policy, s, k % 10_000), env_id
        )
        ratio = eps / ref[0]
        unit, per = env.STEP_UNIT[0], env.substeps_per_step()
        results["envs"][env_id] = {
            "policy": policy_name,
            "params": params,
            "n_agents": env.n_agents,
            "env_steps_per_s": eps,
            "agent_steps_per_s": aps,
            "ratio_to_reference": ratio,
            "unit": unit,
            "units_per_env_step": per,
            "units_per_s": eps * per,
            "ratio_per_unit": eps * per / ref[0],
        }
        line = (
            f"{env_id} [{policy_name}, N={env.n_agents}]: {eps:,.1f} env-steps/s, {aps:,.0f} agent-steps/s, "
            f"ratio {ratio:.2f}"
        )
        if per != 1:  # e.g. one env step = one TDMA frame of N slots: compare slots with the reference's steps
            line += f"; {eps * per:,.0f} {unit}s/s, ratio per {unit} {eps * per / ref[0]:.2f}"
        print(line)
        env.close()
    results["runs"] = runs
    results["seconds_per_run"] = args.seconds
    results["warmup_seconds"] = args.warmup

    results["extras"] = bench.extras_section(targets)
    if args.train or args.train_shipped:
        results["train"] = bench.train_section(
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
        results["batched"] = bench.batched_section(targets, params, tuple(args.copies), args.seconds, runs)
    atomic_write_json(out, results, indent=2)
    print(f"wrote {out} (median of {runs} runs of {args.seconds:g} s each)")
    return 0


def _bench_sweep(args, params: dict, out: Path) -> int:
    """``mrcomm bench --sweep``: the sweep runner's backends instead of env-steps/s (docs/scaling.md)."""

    if len(args.env_ids) > 1:
        raise ValueError(f"--sweep times one env, got {len(args.env_ids)}: {' '.join(args.env_ids)}")
    env_id = canonical_id(args.env_ids[0]) if args.env_ids else bench.SWEEP_ENV
    make(env_id, **params).close()  # bad --param values fail here, before the first timed run
    results = {"sweep": bench.sweep_section(env_id, bench.SWEEP_TASKS, args.runs, params)}
    atomic_write_json(out, _json_safe(results), indent=2)
    print(f"wrote {out} (median of {args.runs} runs per backend)")
    return 0


def _policy_speed(env, policy, seconds: float, seed: int) -> tuple[float, float]:

    views = env.local_views()
    return steps_per_second(
        env, lambda obs: policy.act(obs, views), seconds, seed=seed, on_reset=lambda s: policy.reset(views, s)
    )


def cmd_docs(args) -> int:

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


# ---------------------------------------------------------------------------------------------- parser
class UsageError(ValueError):
    """A command line argparse rejects (unknown flag, bad value); reported as one line like any ValueError."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        # argparse would print the usage block and exit; one line, and the caller decides about exiting
        raise UsageError(f"{message} (see '{self.prog} --help')")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="mrcomm", description="Multi-robot communication environments.")
    parser.add_argument("--debug", action="store_true", help="show the full traceback of an error")
    sub = parser.add_subparsers(dest="command", required=True)

    def command(name: str, **kwargs) -> argparse.ArgumentParser:
        p = sub.add_parser(name, **kwargs)
        # accepted after the command name too; SUPPRESS keeps a --debug given before it
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
        return p

    command("list", help="environment ids, policies and reproductions").set_defaults(func=cmd_list)

    p = command("evaluate", help="run a policy for K episodes; mean ± 95%% CI of every metric")
    p.add_argument("env_id")
    p.add_argument("--policy", required=True)
    p.add_argument("--episodes", type=positive_int, default=10)
    p.add_argument("--seed", type=seed_type, default=0, help="seed of the first episode (integer ≥ 0)")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="environment argument (JSON value)")
    p.add_argument("--policy-param", action="append", metavar="KEY=VALUE", help="policy parameter (JSON value)")
    p.add_argument("--json", metavar="PATH")
    p.add_argument("--video", metavar="DIR", help="also record the first episode into DIR/<Name>-<policy>.gif")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument(
        "--trust-pickle",
        action="store_true",
        help="load a learned model's run written before the safe formats (it unpickles: only a run you made)",
    )
    p.set_defaults(func=cmd_evaluate)

    p = command("record", help="record one episode, several policies side by side, as a GIF or MP4")
    p.add_argument("env_id")
    p.add_argument("--policy", action="append", required=True, help="a policy (repeat for panels side by side)")
    p.add_argument("--seed", type=seed_type, default=0, help="the episode's seed (the same for every panel)")
    p.add_argument("--out", required=True, help="episode.gif, or episode.mp4 with the video extra")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="environment argument (JSON value)")
    p.add_argument("--policy-param", action="append", metavar="KEY=VALUE", help="policy parameter (JSON value)")
    p.add_argument("--max-steps", type=positive_int, default=None, help="stop after this many steps")
    p.add_argument("--fps", type=positive_seconds, default=4.0, help="frames per second of the recording")
    p.set_defaults(func=cmd_record)

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
    p.set_defaults(func=cmd_reproduce)

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
    p.set_defaults(func=cmd_bench)

    add_train_parser(command)
    add_race_parser(command)
    add_reproduce_learning_parser(command)

    p = command("docs", help="generate docs/envs/*.md from the live environments")
    p.add_argument("--out", default="docs")
    p.add_argument("--check", action="store_true", help="exit 1 when the committed docs differ")
    p.add_argument("--media", action="store_true", help="record every env's GIF again (default: only missing ones)")
    p.set_defaults(func=cmd_docs)
    return parser


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())  # numpy and others put newlines into messages
    return text or type(exc).__name__


def _error(message: str) -> None:
    print(f"mrcomm: error: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:

    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv  # known before parsing, so that even a parse error can show its traceback
    try:
        args = build_parser().parse_args(argv)
        args.argv = argv  # the command as given, for the records a command writes (e.g. a sweep's)
        debug = args.debug
        return args.func(args)
    except KeyboardInterrupt:
        if debug:
            raise
        print("mrcomm: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (ValueError, OverflowError) as exc:  # bad input: argument, --param, seed, path, a value out of range
        if debug:
            raise
        _error(_one_line(exc))
        return EXIT_BAD_INPUT
    except SweepError as exc:  # a task failed twice: its message names it with its arguments
        if debug:
            raise
        _error(f"{_one_line(exc)} (finished tasks are cached: rerun the same command to resume)")
        return EXIT_FAILURE
    except MemoryError as exc:
        if debug:
            raise
        _error(f"out of memory: {_one_line(exc)}; try fewer robots or a smaller --param (see the env's limits)")
        return EXIT_FAILURE
    except Exception as exc:  # anything else is a failure during the work: one line, traceback with --debug
        if debug:
            raise
        _error(f"{type(exc).__name__}: {_one_line(exc)} (run with --debug for the traceback)")
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
