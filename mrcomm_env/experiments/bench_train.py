"""``mrcomm bench --train``: PPO agent-steps per second on every env against mpe2's ``simple_spread_v3`` trained the
same way, through SB3 and the agent-slot VecEnv (``--algo ppo``) or the batched trainer (``--algo ippo|mappo``),
with the share of wall time spent stepping the envs. Needs the "train" and "bench" extras; ``commands/bench.py``
imports it when ``--train`` or ``--train-shipped`` is given."""

from __future__ import annotations

import time
from functools import partial
from typing import Any

import numpy as np
import torch
from mpe2 import simple_spread_v3
from stable_baselines3 import PPO
from stable_baselines3.common.logger import Logger
from tqdm.auto import tqdm

from mrcomm_agents.batched_ppo import BatchedPPO, build_model, detached_normalizer, make_critic
from mrcomm_agents.training import algorithm_class
from mrcomm_agents.vecenv import AgentSlotVecEnv
from mrcomm_env.core.sharded import stepping_batch
from mrcomm_env.experiments.bench import BATCHED_BENCH_ALGORITHMS, TRAIN_SLOTS, shipped_training
from mrcomm_env.registry import make


def reference_env():
    """The reference every env is compared with: mpe2's ``simple_spread_v3``, 3 agents, discrete actions."""
    return simple_spread_v3.parallel_env(N=3, continuous_actions=False)


def train_section(
    targets: list[str],
    params: dict,
    timesteps: int,
    progress: bool = True,
    slots: int = TRAIN_SLOTS,
    shipped: bool = False,
    algo: str = "ppo",
    copies: int | None = None,
) -> dict[str, Any]:
    """PPO agent-steps/s through the agent-slot VecEnv on every target and on mpe2's ``simple_spread_v3``, with
    the share of wall time spent stepping the envs (the goal: our envs train at least as fast as the reference).
    ``slots``: about how many agent slots each VecEnv has (the reference: ``slots / 3`` copies of its 3 agents;
    each env: as many copies as come closest); more slots means more copies per batch.

    Each env is compared with the reference at about its own slot count (``reference_slots``): PPO's own cost per
    agent-step falls as its batches grow, so an env whose one copy fills more slots than asked for (MultiHop's 100
    robots) would otherwise be compared with a reference that runs on smaller batches. ``references`` holds the
    reference at every slot count measured; ``reference`` is the one at ``slots``.

    ``shipped``: also each env as its shipped training configuration runs it (:func:`shipped_training`: its env
    arguments, updated by ``params``, and its ``n_envs`` copies), in ``shipped[<id>]``, against the reference at
    about the same slot count. Every run trains the same PPO (:data:`BENCH_PPO`), MaskablePPO's configurations
    too, so that the figures compare the envs' stepping.

    ``algo`` ``ippo`` or ``mappo``: each env trains with the batched trainer instead (:func:`batched_throughput`,
    ``copies`` copies, by default :func:`bench_copies`), against the reference at ``slots`` (MPE2 + SB3 as a user
    runs it); ``ratio_ceiling`` is then the trainer's own speed, its agent-steps over the wall time outside the
    world's steps, against the same reference."""
    if algo in BATCHED_BENCH_ALGORITHMS:
        return _batched_train_section(targets, params, timesteps, progress, slots, shipped, algo, copies)

    references: dict[int, dict[str, Any]] = {}

    def reference_at(agent_slots: int) -> dict[str, Any]:
        copies = max(1, round(agent_slots / 3))
        if copies * 3 not in references:
            result = train_throughput([reference_env] * copies, timesteps)
            references[result["slots"]] = result
            print(f"train  reference simple_spread_v3: {_train_line(result)}")
        return references[copies * 3]

    out: dict[str, Any] = {"timesteps": timesteps, "reference": reference_at(slots)}
    slots = out["reference"]["slots"]
    out["envs"] = {}
    for env_id in tqdm(targets, desc="PPO throughput", leave=False, disable=not progress):
        # about as many agent slots as the reference, so the policy's batch (and its cost per agent-step) match
        copies = max(1, round(slots / make(env_id, **params).n_agents))
        result = train_throughput([lambda env_id=env_id: make(env_id, **params)] * copies, timesteps)
        result.update(_compared(result, reference_at(result["slots"])))
        out["envs"][env_id] = result
        print(f"train  {env_id}: {_train_line(result)}, {_ratio_line(result)}")
    if shipped:
        out["shipped"] = {}
        for env_id in tqdm(targets, desc="PPO throughput, shipped configurations", leave=False, disable=not progress):
            algo, env_kwargs, n_envs = shipped_training(env_id)
            kwargs = {**env_kwargs, **params}
            result = train_throughput([lambda env_id=env_id, kwargs=kwargs: make(env_id, **kwargs)] * n_envs, timesteps)
            result.update(shipped_algo=algo, env_kwargs=kwargs, n_envs=n_envs)
            result.update(_compared(result, reference_at(result["slots"])))
            out["shipped"][env_id] = result
            print(f"train  {env_id} as shipped ({n_envs} × {kwargs}): {_train_line(result)}, {_ratio_line(result)}")
    out["references"] = {str(k): v for k, v in sorted(references.items())}
    return out


#: the batched trainer's settings in ``mrcomm bench --train --algo ippo|mappo``: copies for about 512 agent rows
#: (16–256) and minibatches of 8,192 rows, with BENCH_PPO's 64 steps and 4 epochs. They measure what the trainer can
#: do per agent-step; its learning defaults (``agents/batched_ppo.py`` ``DEFAULTS``: 128 rows, 2,048-row minibatches,
#: 10 epochs) spend more on each agent-step to learn more from it (docs/performance.md has both)
BENCH_BATCHED: dict[str, Any] = {"rows": 512, "batch_size": 8192}


def bench_copies(n_agents: int, copies: int | None = None) -> int:
    """The copies M of a batched bench run: ``copies``, else enough for ``BENCH_BATCHED["rows"]`` agent rows (16–256)."""
    if copies is not None:
        return copies
    return int(min(256, max(16, -(-BENCH_BATCHED["rows"] // max(1, n_agents)))))


def _batched_train_section(
    targets: list[str],
    params: dict,
    timesteps: int,
    progress: bool,
    slots: int,
    shipped: bool,
    algo: str,
    copies: int | None,
) -> dict[str, Any]:
    reference_result = train_throughput([reference_env] * max(1, round(slots / 3)), timesteps)
    print(f"train  reference simple_spread_v3: {_train_line(reference_result)}")
    out: dict[str, Any] = {"timesteps": timesteps, "algo": algo, "reference": reference_result, "envs": {}}
    runs: list[tuple[str, dict, str | None]] = [(env_id, dict(params), None) for env_id in targets]
    if shipped:
        out["shipped"] = {}
        for env_id in targets:
            _, env_kwargs, _ = shipped_training(env_id)
            runs.append((env_id, {**env_kwargs, **params}, "shipped"))
    for env_id, kwargs, where in tqdm(runs, desc=f"{algo} throughput", leave=False, disable=not progress):
        m = bench_copies(make(env_id, **kwargs).n_agents, copies)
        result = batched_throughput(env_id, kwargs, timesteps, algo, m)
        result.update(_compared(result, reference_result))
        label = f"{env_id} as shipped ({kwargs})" if where else env_id
        (out["shipped"] if where else out["envs"])[env_id] = {**result, "env_kwargs": kwargs} if where else result
        print(f"train  {label}: {_train_line(result)}, {_ratio_line(result)}")
    out["references"] = {str(reference_result["slots"]): reference_result}
    return out


def batched_throughput(env_id: str, env_kwargs: dict, timesteps: int, algo: str, copies: int, seed: int = 0) -> dict:
    """Agent-steps/s of the batched trainer (``agents/batched_ppo.py``) on ``copies`` copies, the share of wall time
    in the world's steps, and the trainer's own speed outside them. One untimed rollout and update first: every
    compiled kernel (the env's, torch's) is then warm, so a first run after a fresh install measures as the second.
    The timed part is whole rollouts, at least ``timesteps`` agent-steps and at least three rollouts."""
    torch.set_num_threads(1)
    probe = make(env_id, **env_kwargs)
    agent = probe.possible_agents[0]
    obs_space, act_space = probe.observation_space(agent), probe.action_space(agent)
    settings = {
        "n_steps": BENCH_PPO["n_steps"],
        "n_epochs": BENCH_PPO["n_epochs"],
        "batch_size": BENCH_BATCHED["batch_size"],
    }
    model = build_model(
        algorithm_class(algo, probe), "MlpPolicy", BENCH_PPO["policy_kwargs"], obs_space, act_space, settings, seed
    )
    model.set_logger(Logger(folder=None, output_formats=[]))
    critic = critic_optimizer = None
    if algo == "mappo":
        net_arch = BENCH_PPO["policy_kwargs"]["net_arch"]
        obs_dim = int(np.prod(obs_space.shape or (1,)))
        critic, critic_optimizer = make_critic(probe.n_agents, obs_dim, net_arch, model.lr_schedule(1))
    probe.close()
    # as `mrcomm train` steps them: in two processes where the copies step one after another (core.sharded)
    batch = stepping_batch(partial(make, env_id, **env_kwargs), copies, copy=False)
    trainer = BatchedPPO(
        model, batch, detached_normalizer(obs_space.shape, model.gamma), seed, critic, critic_optimizer
    )
    per_rollout = trainer.steps * trainer.rows
    trainer.learn(per_rollout)  # the warm-up rollout and update
    rollouts = max(3, -(-timesteps // per_rollout))
    in_world = Stopwatch()
    batch.step = in_world.timing(batch.step)  # type: ignore[method-assign]
    done = model.num_timesteps
    start = time.perf_counter()
    trainer.learn(done + rollouts * per_rollout)
    wall = time.perf_counter() - start
    batch.close()
    return {
        "algo": algo,
        **_throughput(model.num_timesteps - done, wall, in_world.seconds, trainer.rows),
        "copies": copies,
        "minibatch": int(model.batch_size),
        "update_threads": trainer.update_threads,
        "env_workers": getattr(batch, "workers", 1),
    }


class Stopwatch:
    """The wall time spent inside the callables it wraps (the env's side of a training step)."""

    def __init__(self) -> None:
        self.seconds = 0.0

    def timing(self, function):
        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - start

        return timed


def _throughput(steps: int, wall: float, in_env: float, slots: int) -> dict[str, Any]:
    """A training run's speed: agent-steps/s, the share of wall time stepping the env(s), and the trainer's own
    speed (agent-steps over the wall time outside the env's stepping; see _compared)."""
    return {
        "agent_steps_per_s": steps / wall,
        "env_step_share": in_env / wall,
        "ppo_agent_steps_per_s": steps / (wall - in_env),
        "agent_steps": steps,
        "seconds": wall,
        "slots": slots,
    }


def _compared(result: dict, reference: dict) -> dict[str, Any]:
    """An env's PPO run against the reference's at about its slot count.

    ``ratio_ceiling`` is the ratio the env would reach if its stepping took no time: its agent-steps over PPO's own
    wall time (the wall time outside ``step_wait``) against the reference's agent-steps/s. PPO's own work per
    agent-step is about the same for every env at a slot count (the same network, batches and epochs), so this is
    close to one number per slot count, 1 / (1 − the reference's env share): a goal ratio above it cannot be met by
    making the env faster, only by more slots (larger batches make PPO's share of each agent-step smaller). It is
    an upper bound, as a free env would still lay out its slots."""
    return {
        "reference_slots": reference["slots"],
        "reference_agent_steps_per_s": reference["agent_steps_per_s"],
        "ratio_to_reference": result["agent_steps_per_s"] / reference["agent_steps_per_s"],
        "ratio_ceiling": result["ppo_agent_steps_per_s"] / reference["agent_steps_per_s"],
    }


def _ratio_line(result: dict) -> str:
    return (
        f"ratio {result['ratio_to_reference']:.2f}, {result['ratio_ceiling']:.2f} if the env took no time "
        f"(to the reference at {result['reference_slots']} slots)"
    )


#: the PPO settings every env (and the reference) trains with in ``mrcomm bench --train``: the same work per
#: agent-step everywhere, so the figures compare the envs and not the settings
BENCH_PPO: dict[str, Any] = {"n_steps": 64, "n_epochs": 4, "policy_kwargs": {"net_arch": [64, 64]}}


def train_throughput(env_fns, timesteps: int, seed: int = 0) -> dict[str, Any]:
    """PPO agent-steps/s through ``AgentSlotVecEnv`` over ``env_fns`` and the share of wall time in env stepping (the
    VecEnv's ``step_wait``: the copies' steps and their slots' observations, rewards and infos)."""
    torch.set_num_threads(1)
    venv = AgentSlotVecEnv(env_fns)
    # the env's side of a PPO step: every copy stepped (one batch for mrcomm envs, env.step for the reference) and
    # its results laid out as SB3's slots
    in_env = Stopwatch()
    venv.step_wait = in_env.timing(venv.step_wait)
    # one minibatch per epoch: the gradient work per agent-step is then the same whatever the slot count
    batch = BENCH_PPO["n_steps"] * venv.num_envs
    model = PPO("MlpPolicy", venv, seed=seed, device="cpu", verbose=0, batch_size=batch, **BENCH_PPO)
    # a logger with no outputs: without one, SB3 makes an empty <tmp>/SB3-<time> folder on every learn()
    model.set_logger(Logger(folder=None, output_formats=[]))
    # one untimed rollout first, so that compiled kernels (MapSync's world) are warm before timing: a first run
    # after a fresh install then measures as the second
    model.learn(total_timesteps=batch)
    in_env.seconds = 0.0
    done = model.num_timesteps
    start = time.perf_counter()
    model.learn(total_timesteps=timesteps, reset_num_timesteps=False)
    wall = time.perf_counter() - start
    venv.close()
    return _throughput(model.num_timesteps - done, wall, in_env.seconds, venv.num_envs)


def _train_line(result: dict) -> str:
    return (
        f"{result['agent_steps_per_s']:,.0f} PPO agent-steps/s ({result['slots']} slots), "
        f"{100 * result['env_step_share']:.0f} % of wall time stepping the envs"
    )
