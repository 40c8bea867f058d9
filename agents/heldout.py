"""Held-out evaluation while training: the env's own metrics and bits, logged beside SB3's training statistics.

PPO's training return mixes the task with the price of a bit, and is measured on the episodes it trains on. A
user who tunes what and when to communicate wants to see the trade-off itself move: every ``eval_every``
agent-steps, :class:`HeldOutEvaluation` plays ``eval_episodes`` whole episodes on seeds no training run or
comparison uses (:data:`HELDOUT_SEEDS` on), with the policy as it is then, and records under ``heldout/``

* every scalar of the env's ``metrics()`` (its paper metric among them: ``mean_delay``, ``completion_time``,
  ``disagreement``, ``weighted_mean_age``, ``iterations_to_half_info``), averaged over the episodes; a time
  that was never reached (the env's ``UNREACHED_TIMES``, −1 or NaN) counts as the episode's length;
* ``bits_per_agent_step``: bits sent per robot per step, and ``bits_per_agent_episode``;
* ``episode_return``;

and ``time/training_seconds``, the wall time training had taken when the evaluation started, the evaluations
excluded, over every session of a resumed run (:class:`TrainingClock`; what ``mrcomm race`` compares trainers by),
and ``time/heldout_seconds``, the seconds this session's evaluations took.

They reach ``progress.csv`` and TensorBoard with the rollout's own row (``tensorboard --logdir runs/``).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize

from mrcomm_env.registry import make

#: first episode seed of the held-out evaluation (comparisons use 10000+, sweeps 20000+)
HELDOUT_SEEDS = 30_000
PREFIX = "heldout/"
#: the log's running total of seconds spent evaluating, which ``time/time_elapsed`` includes
SECONDS_KEY = "time/heldout_seconds"
#: the wall time training has taken when an evaluation starts, evaluations excluded (to the microsecond: SB3 logs
#: ``time/time_elapsed`` in whole seconds)
TRAINING_SECONDS_KEY = "time/training_seconds"


def normalized(venv, observations: np.ndarray) -> np.ndarray:
    """The observations as the policy sees them in training (VecNormalize's running statistics, when on)."""
    if isinstance(venv, VecNormalize):
        return np.asarray(venv.normalize_obs(observations))
    return observations


def uses_masks(model) -> bool:
    """MaskablePPO: its distribution is over the allowed actions only, so it is given the env's masks."""
    return type(model).__name__ == "MaskablePPO"


def sb3_masks(masks, action_space) -> np.ndarray:
    """An env's action masks as sb3-contrib's masked distributions read them. For a MultiBinary action an env masks
    each bit by whether it may be *set* (K columns: MultiHop's ``mask_unheld``); sb3-contrib masks both values of
    every bit (2K columns: may be 0, may be 1), and a bit may always stay 0. Other masks pass unchanged."""
    masks = np.asarray(masks, dtype=bool)
    if isinstance(action_space, spaces.MultiBinary) and masks.shape[-1] == int(np.prod(action_space.shape)):
        both = np.ones((*masks.shape, 2), dtype=bool)
        both[..., 1] = masks
        return both.reshape(*masks.shape[:-1], 2 * masks.shape[-1])
    return masks


def team_actions(model, venv, env, observations: dict, deterministic: bool) -> dict:
    """One shared-policy decision for every live agent of ``env`` (a PettingZoo parallel env)."""
    agents = list(observations)
    obs = normalized(venv, np.stack([observations[a] for a in agents]).astype(np.float32))
    extra = {}
    if uses_masks(model) and callable(getattr(env, "action_masks", None)):
        extra["action_masks"] = sb3_masks(env.action_masks(), model.action_space)
    chosen, _ = model.predict(obs, deterministic=deterministic, **extra)
    return {a: chosen[i] for i, a in enumerate(agents)}


def evaluate_episodes(model, venv, env_id: str, env_kwargs: dict, seeds, deterministic: bool) -> dict[str, float]:
    """Mean over the episodes of each scalar metric, bits per agent (per step and per episode) and the return."""
    env = make(env_id, **env_kwargs)
    totals: dict[str, list[float]] = {}
    for seed in seeds:
        observations, _ = env.reset(seed=int(seed))
        episode_return = 0.0
        while env.agents:
            observations, rewards, _, _, _ = env.step(team_actions(model, venv, env, observations, deterministic))
            episode_return += float(np.mean(list(rewards.values()))) if rewards else 0.0
        metrics = env.metrics()
        row = {k: float(v) for k, v in metrics.items() if np.isscalar(v) and not isinstance(v, str)}
        for name in env.UNREACHED_TIMES:  # never reached: counted at the episode's length
            if name in row:
                row[name] = env.counted_time(name, row[name])
        bits = float(metrics.get("bits_sent", env.bits_sent()))
        row["bits_per_agent_episode"] = bits / env.n_agents
        row["bits_per_agent_step"] = bits / (env.n_agents * max(env.step_count, 1))
        row["episode_return"] = episode_return
        for key, value in row.items():
            totals.setdefault(key, []).append(value)
    env.close()
    return {key: float(np.mean(values)) for key, values in totals.items()}


def record_heldout(
    logger, model, venv, env_id: str, env_kwargs: dict, episodes: int, deterministic: bool
) -> tuple[float, dict[str, float]]:
    """Evaluate ``model`` on ``episodes`` held-out episodes and record the means under ``heldout/`` in ``logger``;
    returns the seconds it took and the means. ``venv``: the training VecNormalize (or a detached one) whose
    statistics normalise the observations. torch's global generator, which SB3 samples actions from, is saved and
    restored: training draws nothing less."""
    start = time.perf_counter()
    state = torch.get_rng_state()
    try:
        seeds = range(HELDOUT_SEEDS, HELDOUT_SEEDS + episodes)
        means = evaluate_episodes(model, venv, env_id, env_kwargs, seeds, deterministic)
    finally:
        torch.set_rng_state(state)
    for key, value in means.items():
        logger.record(PREFIX + key, value)
    return time.perf_counter() - start, means


class TrainingClock:
    """Training's own wall time over a run's sessions: the seconds the sessions before a resume trained (``before``,
    from the checkpoint resumed; :mod:`mrcomm_agents.training` keeps it in ``state.json``), plus this session's
    since :meth:`start`, without the held-out evaluations (``evaluating``, which the caller adds up)."""

    def __init__(self, before: float = 0.0) -> None:
        self.before = float(before)
        self.started: float | None = None
        self.evaluating = 0.0

    def start(self) -> None:
        self.started = time.perf_counter()

    def seconds(self) -> float:
        if self.started is None:
            return self.before
        return self.before + max(time.perf_counter() - self.started - self.evaluating, 0.0)


class HeldOutEvaluation(BaseCallback):
    """When a new run starts (agent-step 0), when a rollout ends and ``every`` agent-steps have passed since the
    last time, and once more when training ends: see the module docstring.

    The evaluation draws no random number from the training: it saves and restores torch's global generator,
    which SB3 samples actions from, so a run with evaluation trains exactly as one without. ``on_evaluated(means,
    final)``, if given, receives each evaluation's means; ``final`` is True for the one after the last update (a
    rollout's evaluation scores the policy that collected it, before the update on it)."""

    def __init__(
        self,
        env_id: str,
        env_kwargs: dict,
        every: int,
        episodes: int,
        deterministic: bool,
        clock: TrainingClock,
        on_evaluated: Callable[[dict[str, float], bool], None] | None = None,
    ):
        super().__init__()
        self.env_id, self.env_kwargs = env_id, dict(env_kwargs)
        self.every, self.episodes, self.deterministic = int(every), int(episodes), bool(deterministic)
        #: seconds spent in held-out evaluations since training started (inside ``time/time_elapsed``)
        self.seconds = 0.0
        #: training's own time, started by the caller when learning starts
        self.clock = clock
        self.on_evaluated = on_evaluated
        self.next_at = self.every

    def _on_training_start(self) -> None:
        self.next_at = (self.num_timesteps // self.every + 1) * self.every
        if self.num_timesteps == 0:  # a new run: the starting point of the curve (a warm start's clone, or chance)
            self._evaluate()
            self._dump()

    def _dump(self) -> None:
        self.logger.record("time/total_timesteps", self.num_timesteps)
        # seconds since learn() started, as SB3's own rows count them
        self.logger.record("time/time_elapsed", max((time.time_ns() - self.model.start_time) / 1e9, 0.0))
        self.logger.dump(self.num_timesteps)

    def _evaluate(self, final: bool = False) -> None:
        self.logger.record(TRAINING_SECONDS_KEY, self.clock.seconds() if self.num_timesteps else 0.0)
        spent, means = record_heldout(
            self.logger, self.model, self.training_env, self.env_id, self.env_kwargs, self.episodes, self.deterministic
        )
        self.seconds += spent
        self.clock.evaluating += spent
        self.logger.record(SECONDS_KEY, self.seconds)
        if self.on_evaluated is not None:
            self.on_evaluated(means, final)

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        if self.num_timesteps >= self.next_at:
            self._evaluate()
            self.next_at = (self.num_timesteps // self.every + 1) * self.every

    def _on_training_end(self) -> None:
        # one more row: the final policy's evaluation (a rollout's row shows the policy that collected it, before
        # the update on it), with the last update's statistics, which SB3 records after its last dump and drops
        self._evaluate(final=True)
        self._dump()
