"""BenchMARL's on-policy collection on every mrcomm task, the batched env beside the older one-wrapper-per-copy path.

    make bench-benchmarl                       # in .venv-benchmarl; writes results/bench-benchmarl.json
    python -m mrcomm_env.experiments.benchmarl_bench --num-envs 100 --tasks MAPSYNC MULTIHOP

Both paths run in one process with one config: BenchMARL's own ``Experiment`` (its default IPPO, MLP and
experiment configs, with ``on_policy_n_envs_per_worker`` and ``on_policy_collected_frames_per_batch`` set here)
built on the task as ``MrcommTask`` makes it (``num_envs`` copies as one batched TorchRL env) and as
``MrcommSerialClass`` makes it (one ``PettingZooWrapper`` per copy in BenchMARL's ``SerialEnv``). What is timed
is the experiment's own collector yielding batches (the env stepping and the policy acting, as in
``Experiment.run``), after one batch of warm-up (compiled kernels, first allocations). Frames are BenchMARL's:
one step of one copy, all robots together.

A third run bounds what any env could reach there: the batched env stepped once, then returning that step forever
(``EnvCostingNothing``), so that only BenchMARL's own work is left (its policy acting on every robot, the collector
storing each frame's observations and state). ``ceiling`` is that rate; ``ceiling / serial`` is the most an env that
costs nothing could gain over the older path, and ``batched / ceiling`` how close the batched env comes to it.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from mrcomm_env.experiments.io import atomic_write_json
from mrcomm_env.integrations import require
from mrcomm_env.integrations.benchmarl import ENV_ID_OF_TASK, MrcommClass, MrcommSerialClass, MrcommTask
from mrcomm_env.integrations.torchrl_batched import DONE_KEYS, GROUP, BatchedTorchRLEnv

EXTRA = "benchmarl"
_algorithms = require("benchmarl.algorithms", EXTRA)
_experiment = require("benchmarl.experiment", EXTRA)
_models = require("benchmarl.models", EXTRA)
torch = require("torch", EXTRA)

#: the config both paths share unless given: BenchMARL's default frames per batch, and copies enough that one
#: step of the batched env carries a useful amount of work (BenchMARL's own default of 10 suits VMAS on a GPU's
#: copies only when raised, as its VMAS users do)
NUM_ENVS = 100
FRAMES_PER_BATCH = 6_000
BATCHES = 3
GOAL = 20.0  # the ratio of the batched path to the older one


class EnvCostingNothing(BatchedTorchRLEnv):
    """The batched env stepped once; every later step returns that step's output again, with no episode ending:
    BenchMARL's collection with an env that takes no time (the ceiling of the bench)."""

    _held = None

    def _step(self, tensordict):
        if self._held is None:
            held = super()._step(tensordict)
            for key in DONE_KEYS:
                held[key].zero_()
                held[GROUP, key].zero_()
            self._held = held
        return self._held.copy()  # shallow: what the collector adds goes into the copy


class FreeTaskClass(MrcommClass):
    """A task whose env is :class:`EnvCostingNothing` over its batched env."""

    def get_env_fun(self, num_envs, continuous_actions, seed, device):
        config = dict(self.config)
        env_id = self.env_id
        return lambda: EnvCostingNothing(env_id, num_envs, device=device, seed=seed, **config)


def experiment(task, num_envs: int, frames_per_batch: int, folder: str):
    """BenchMARL's ``Experiment`` with its default IPPO, MLP and experiment configs, collecting ``frames_per_batch``
    frames from ``num_envs`` copies per batch, with nothing but collection and training (no evaluation, logging or
    checkpoints)."""
    config = _experiment.ExperimentConfig.get_from_yaml()
    config.on_policy_n_envs_per_worker = num_envs
    config.on_policy_collected_frames_per_batch = frames_per_batch
    config.max_n_frames = 100 * frames_per_batch
    config.evaluation = False
    config.render = False
    config.loggers = []
    config.create_json = False
    config.checkpoint_interval = 0
    config.save_folder = folder
    return _experiment.Experiment(
        task=task,
        algorithm_config=_algorithms.IppoConfig.get_from_yaml(),
        model_config=_models.MlpConfig.get_from_yaml(),
        critic_model_config=_models.MlpConfig.get_from_yaml(),
        seed=0,
        config=config,
    )


def collection_rate(task, num_envs: int, frames_per_batch: int, batches: int) -> dict:
    """Frames per second of the experiment's collector on ``task``: ``batches`` batches after one of warm-up."""
    with tempfile.TemporaryDirectory() as folder:
        run = experiment(task, num_envs, frames_per_batch, folder)
        batch_iter = iter(run.collector)
        next(batch_iter)  # warm-up: compiled kernels, first allocations
        start = time.perf_counter()
        frames = 0
        for _ in range(batches):
            frames += next(batch_iter).numel()
        seconds = time.perf_counter() - start
        run.collector.shutdown()
    return {"frames": frames, "seconds": seconds, "frames_per_s": frames / seconds}


def bench(tasks: list[str], num_envs: int, frames_per_batch: int, batches: int) -> dict:
    results = {}
    for name in tasks:
        yaml_task = MrcommTask[name].get_from_yaml()
        serial_task = MrcommSerialClass(name, dict(yaml_task.config))
        serial = collection_rate(serial_task, num_envs, frames_per_batch, batches)
        batched = collection_rate(yaml_task, num_envs, frames_per_batch, batches)
        ceiling = collection_rate(FreeTaskClass(name, dict(yaml_task.config)), num_envs, frames_per_batch, batches)
        ratio = batched["frames_per_s"] / serial["frames_per_s"]
        results[ENV_ID_OF_TASK[name]] = {
            "config": yaml_task.config,
            "serial": serial,
            "batched": batched,
            "ceiling": ceiling,
            "ratio": ratio,
            "ratio_ceiling": ceiling["frames_per_s"] / serial["frames_per_s"],
            "share_of_ceiling": batched["frames_per_s"] / ceiling["frames_per_s"],
        }
        print(
            f"{ENV_ID_OF_TASK[name]:32s} serial {serial['frames_per_s']:8,.0f}  batched {batched['frames_per_s']:8,.0f}"
            f"  ceiling {ceiling['frames_per_s']:8,.0f} frames/s   batched/serial {ratio:5.1f}x  ceiling/serial "
            f"{results[ENV_ID_OF_TASK[name]]['ratio_ceiling']:5.1f}x  batched/ceiling "
            f"{results[ENV_ID_OF_TASK[name]]['share_of_ceiling']:4.0%}",
            flush=True,
        )
    return {
        "num_envs": num_envs,
        "frames_per_batch": frames_per_batch,
        "batches": batches,
        "torch_threads": torch.get_num_threads(),
        "goal_ratio": GOAL,
        "tasks": results,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m mrcomm_env.experiments.benchmarl_bench", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--tasks", nargs="+", default=list(ENV_ID_OF_TASK), choices=list(ENV_ID_OF_TASK))
    parser.add_argument("--num-envs", type=int, default=NUM_ENVS, help=f"copies per path (default {NUM_ENVS})")
    parser.add_argument(
        "--frames-per-batch", type=int, default=FRAMES_PER_BATCH, help=f"frames per batch (default {FRAMES_PER_BATCH})"
    )
    parser.add_argument("--batches", type=int, default=BATCHES, help=f"timed batches per path (default {BATCHES})")
    parser.add_argument("--out", default="results/bench-benchmarl.json", help="the JSON written (atomically)")
    args = parser.parse_args(argv)
    for name in ("num_envs", "frames_per_batch", "batches"):
        if getattr(args, name) < 1:
            print(f"mrcomm benchmarl bench: argument '--{name.replace('_', '-')}' must be ≥ 1", file=sys.stderr)
            return 2
    result = bench(args.tasks, args.num_envs, args.frames_per_batch, args.batches)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out, result, indent=2)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
