"""IPPO and MAPPO on M copies of an env stepped as arrays (``mrcomm train ID --algo ippo|mappo``).

SB3's PPO steps a VecEnv of agent slots and pays Python per slot and per step, and small minibatches; on this
2-core machine it caps training at 2.6–3.4× MPE2 ``simple_spread`` + SB3 even when the env costs nothing
(docs/performance.md). :class:`BatchedPPO` keeps SB3's *pieces* and replaces its loop:

* the **world** is :class:`~mrcomm_env.core.batched.BatchedEnv`: M copies exchanged as whole arrays, actions
  ``(M, N, …)`` in, observations ``(M, N, D)``, rewards ``(M, N)`` and ends ``(M,)`` out, ended copies reset by
  the world itself; no Python per agent, and per copy only where an episode ends;
* the **policy** is SB3's own (``MlpPolicy``, our :class:`~mrcomm_agents.policies.CandidatePolicy`, or
  sb3-contrib's masked policy where the env masks actions) inside an SB3 ``PPO``/``MaskablePPO`` object that is
  never given an env: the run folder's ``model.zip`` is then SB3's archive, saved and loaded by
  ``agents/artifacts.py`` without pickles, and ``mrcomm evaluate --policy ippo:RUN``, pretrained export and the
  warm start work on it unchanged;
* the **rollout** goes into buffers allocated once (``(T, M·N, …)``); observations and returns are normalised as
  SB3's ``VecNormalize`` does, with a VecNormalize that has no VenEnv under it, so ``vecnormalize.json`` is the
  same file as an SB3 run's;
* **GAE** is one reverse pass over the T steps, each step vectorised over all M·N agent rows (Schulman et al.
  2016, eq. 16; SB3's ``RolloutBuffer.compute_returns_and_advantage`` writes the same recursion per step);
* the **update** is PPO's clipped objective (Schulman et al. 2017, eq. 7) with SB3's defaults and meanings
  (``clip_range``, ``ent_coef``, ``vf_coef``, ``max_grad_norm``, ``target_kl``, advantages normalised per
  minibatch), over minibatches of ``batch_size`` rows (2,048 by default, 10 epochs: on CPU fewer and larger
  minibatches cost less per agent-step, 8,192 rows and 4 epochs about a third, but learn less from each, and the
  defaults reached SB3's quality first in wall time: docs/performance.md);
* **threads**: one torch thread while the world steps and the policy acts on M·N rows, ``update_threads`` (two
  by default on a machine with two cores or more) for the update, where the matrix products are large enough to
  gain from the second core (docs/performance.md has the measurement).

**IPPO** (de Witt et al. 2020): every agent acts and is criticised on its own observation, one network shared by
all (parameter sharing). **MAPPO** (Yu et al. 2022): the same actor; the critic is a separate network reading the
env's global ``state()`` beside the agent's own observation (the agent-specific global state of Yu et al. §4).
In every mrcomm env ``state()`` is every robot's observation concatenated (``MrcommParallelEnv.state_is_joint_observation``), so the
critic's input is built from the rollout's own observation rows, normalised with the same statistics; an env
that defines another ``state()`` is refused for ``mappo`` at construction.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.utils import update_learning_rate
from stable_baselines3.common.vec_env import VecNormalize
from torch import nn

from mrcomm_agents.heldout import sb3_masks
from mrcomm_env.core.base import MrcommParallelEnv, mask_info_keys
from mrcomm_env.core.batched import BatchedEnv
from mrcomm_env.core.sharded import ShardedBatchedEnv

#: the algorithms of this module (``mrcomm train --algo``)
BATCHED_ALGORITHMS = ("ippo", "mappo")
#: documented defaults: steps per copy per rollout T, minibatch rows, epochs; the copies M default to
#: :func:`default_copies`. Chosen on MapSync's shipped problem (docs/performance.md): 8,192-row minibatches and 4
#: epochs train fastest per agent-step but take about 10 × the agent-steps to a given return; 2,048 rows and 10
#: epochs (40 gradient steps per 8,192 agent-steps, SB3's shipped MapSync run takes 40 per 4,096) reach SB3's
#: return first in wall time
DEFAULTS: dict[str, Any] = {"n_steps": 64, "batch_size": 2048, "n_epochs": 10}
#: agent rows (copies × agents) the default number of copies aims at, and its bounds. More rows per step act
#: faster (MapSync's 2 robots: 80,000 agent-steps/s at 64 copies, 122,000 at 256, measured here) but update the
#: policy less often per agent-step: 128 rows learned MapSync's shipped problem fastest in wall time
DEFAULT_ROWS = 128
COPIES_RANGE = (16, 256)


def default_copies(n_agents: int) -> int:
    """The copies M of a run that does not set ``n_envs``: enough for :data:`DEFAULT_ROWS` agent rows, within
    :data:`COPIES_RANGE` (MapSync's 2 robots: 64 copies; AsyncCL's 5: 26; ChannelAssociation's 12 and more: 16)."""
    lo, hi = COPIES_RANGE
    return int(min(hi, max(lo, -(-DEFAULT_ROWS // max(1, int(n_agents))))))


#: the episodes over which ``rollout/ep_rew_mean`` and ``ep_len_mean`` are averaged, as SB3's logger does
EPISODE_WINDOW = 100


def masks_actions(env: MrcommParallelEnv) -> bool:
    """Whether ``env`` masks infeasible actions (``action_masks()``), which the batched trainer reads from the info
    columns ``action_mask_<i>`` of every step."""
    return callable(getattr(env, "action_masks", None))


def check_env(env: MrcommParallelEnv, algo: str) -> None:
    """Refuse, at construction, an env the batched trainer cannot train on, naming why."""
    if algo not in BATCHED_ALGORITHMS:
        raise ValueError(f"argument 'algo' must be one of {', '.join(BATCHED_ALGORITHMS)}, got {algo!r}")
    obs_space, act_space = env.observation_space(env.possible_agents[0]), env.action_space(env.possible_agents[0])
    if not isinstance(obs_space, spaces.Box) or len(obs_space.shape) != 1:
        raise ValueError(f"{algo} needs flat Box observations; {env.ENV_ID} has {obs_space}")
    if not isinstance(act_space, (spaces.Discrete, spaces.MultiBinary, spaces.MultiDiscrete, spaces.Box)):
        raise ValueError(
            f"{algo} needs Discrete, MultiBinary, MultiDiscrete or Box actions; {env.ENV_ID} has {act_space}"
        )
    if algo == "mappo" and not env.state_is_joint_observation():
        raise ValueError(
            "mappo's critic reads state() as every robot's observation concatenated "
            f"(MrcommParallelEnv.state_is_joint_observation); {type(env).__name__} defines its own state(): use ippo"
        )


def detached_normalizer(obs_shape: tuple[int, ...], gamma: float) -> VecNormalize:
    """SB3's ``VecNormalize`` settings and statistics (observations and returns) without a VecEnv under it: the
    batched trainer updates its statistics itself, and ``agents/artifacts.py`` saves it as any SB3 run's."""
    normalizer = VecNormalize.__new__(VecNormalize)
    normalizer.__setstate__(
        {
            "norm_obs": True,
            "norm_reward": True,
            "training": True,
            "clip_obs": 10.0,
            "clip_reward": 10.0,
            "gamma": float(gamma),
            "epsilon": 1e-8,
            "observation_space": spaces.Box(-np.inf, np.inf, obs_shape, np.float32),
            "action_space": None,
            "norm_obs_keys": None,
            "old_obs": np.array([]),
            "old_reward": np.array([]),
            "returns": np.zeros(0),
        }
    )
    normalizer.__dict__.update(obs_rms=RunningMeanStd(shape=obs_shape), ret_rms=RunningMeanStd(shape=()))
    return normalizer


class CentralCritic(nn.Module):
    """MAPPO's critic: an MLP (tanh, as SB3's) on (the global state of the agent's copy, the agent's own observation)
    → V. Its first layer is a linear map of the concatenation, computed as W_s·state + W_o·obs: the state's part once
    per copy and added to each of its N agents' rows, so the concatenation (N times the state, N·(N·D + D) numbers
    per copy: 25 GB a minibatch for MultiHop's 100 robots) is never built."""

    def __init__(self, n_agents: int, obs_dim: int, net_arch: list[int]):
        super().__init__()
        self.n_agents, self.obs_dim = int(n_agents), int(obs_dim)
        first, *rest = list(net_arch) or [64]
        self.state_layer = nn.Linear(self.n_agents * self.obs_dim, first)
        self.own_layer = nn.Linear(self.obs_dim, first, bias=False)
        layers: list[nn.Module] = [nn.Tanh()]
        width = first
        for hidden in rest:
            layers += [nn.Linear(width, hidden), nn.Tanh()]
            width = hidden
        layers.append(nn.Linear(width, 1))
        self.head = nn.Sequential(*layers)

    def state_of(self, obs: torch.Tensor) -> torch.Tensor:
        """The global state of each copy, ``(K, N·D)``, from its agents' rows ``(K·N, D)`` ordered copy by copy: every
        robot's observation concatenated, which is ``env.state()`` in every mrcomm env (``check_env``)."""
        return obs.reshape(-1, self.n_agents * self.obs_dim)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """V of each row of ``obs`` ``(K·N, D)``, rows ordered copy by copy."""
        per_copy = self.state_layer(self.state_of(obs))
        hidden = per_copy.repeat_interleave(self.n_agents, dim=0) + self.own_layer(obs)
        return self.head(hidden).squeeze(-1)


def make_critic(n_agents: int, obs_dim: int, net_arch: list[int], learning_rate: float, state=None):
    """MAPPO's (critic, its Adam optimizer), restored from ``state`` (:meth:`BatchedPPO.critic_state`) if given."""
    critic = CentralCritic(n_agents, obs_dim, list(net_arch))
    optimizer = torch.optim.Adam(critic.parameters(), lr=learning_rate, eps=1e-5)
    if state is not None:
        critic.load_state_dict(state["critic"])
        optimizer.load_state_dict(state["optimizer"])
    return critic, optimizer


@dataclass
class RolloutStats:
    """What one rollout adds to the log: the seconds its world's steps took (``time/env_step_seconds``)."""

    seconds_stepping: float = 0.0


class BatchedPPO:
    """PPO over a :class:`BatchedEnv` with an SB3 model's policy (see the module docstring).

    :param model: an SB3 ``PPO`` or ``MaskablePPO`` built by :func:`build_model` (or loaded from a run); its
        hyperparameters (``n_steps`` = T, ``batch_size``, ``n_epochs``, ``gamma``, …) are the trainer's.
    :param batch: the world of M copies.
    :param normalizer: a VecNormalize without a VecEnv (:func:`detached_normalizer`, or a run's statistics), or
        None for raw observations and rewards.
    :param seed: seeds the world's copies (copy i gets ``seed + i``) and the minibatch order.
    :param critic: MAPPO's :class:`CentralCritic` (None: IPPO, the policy's own value head).
    """

    def __init__(
        self,
        model,
        batch: BatchedEnv | ShardedBatchedEnv,
        normalizer: VecNormalize | None,
        seed: int,
        critic: CentralCritic | None = None,
        critic_optimizer: torch.optim.Optimizer | None = None,
        update_threads: int | None = None,
    ):
        self.model, self.policy, self.batch, self.normalizer = model, model.policy, batch, normalizer
        self.critic, self.critic_optimizer = critic, critic_optimizer
        self.m, self.n = batch.n_copies, batch.n_agents
        self.rows = self.m * self.n
        self.steps = int(model.n_steps)
        self.obs_dim = int(np.prod(batch.observation_space.shape or (1,)))  # a flat Box (check_env)
        self.action_space = batch.action_space
        self.update_threads = update_threads or max(1, min(2, os.cpu_count() or 1))
        self.generator = torch.Generator().manual_seed(int(seed))
        t, rows = self.steps, self.rows
        act_shape = self.action_space.shape or ()
        self.buf_obs = np.zeros((t, rows, self.obs_dim), dtype=np.float32)
        self.buf_actions = np.zeros((t, rows, *act_shape), dtype=np.float32)
        self.buf_log_probs = np.zeros((t, rows), dtype=np.float32)
        self.buf_values = np.zeros((t, rows), dtype=np.float32)
        self.buf_rewards = np.zeros((t, rows), dtype=np.float32)
        self.buf_starts = np.zeros((t, rows), dtype=np.float32)
        self.advantages = np.zeros((t, rows), dtype=np.float32)
        observations, infos = batch.reset(seed=int(seed))
        self.masks = mask_info_keys(infos)
        self.next_masks = self._mask_rows(infos) if self.masks else None
        self.buf_masks = np.zeros((t, *self.next_masks.shape), dtype=bool) if self.next_masks is not None else None
        self.next_obs = self._observe(observations)
        self.next_starts = np.ones(rows, dtype=np.float32)
        self.discounted = np.zeros(rows)  # VecNormalize's running discounted return per agent row
        self.episode_return = np.zeros(self.m)
        self.episode_length = np.zeros(self.m, dtype=np.int64)
        self.episodes: deque[tuple[float, int]] = deque(maxlen=EPISODE_WINDOW)
        #: seconds since the last :meth:`learn` started, at its last rollout's row (``time/time_elapsed``)
        self.elapsed = 0.0
        #: agent-steps until which only the critic learns (``critic_warmup`` after a warm start)
        self.critic_warmup_until = 0
        #: kickstarting (:meth:`kickstart`): the frozen teacher policy, its starting weight and the agent-steps over
        #: which the weight falls to 0; the teacher's choices at the rollout's states, and the rollout's weight
        self.teacher: Any = None
        self.kickstart_coef, self.kickstart_steps = 0.0, 1
        self.buf_teacher_actions: np.ndarray | None = None
        self.rollout_kickstart_weight = 0.0

    def kickstart(self, teacher, coef: float, steps: int) -> None:
        """Kickstarting (Schmitt et al. 2018, with the teacher's mode in place of its distribution): every update
        adds ``w`` × the policy's negative log-likelihood of ``teacher``'s deterministic choice at each state of the
        rollout (a policy of the same observation and action spaces, e.g. a warm start's clone, never trained
        here), with ``w = coef × max(0, 1 − agent-steps at the rollout's start / steps)``. The mode rather than the
        whole distribution: the policies compared here act by their mode, and it serves every action distribution
        alike (a subset draw has no closed-form cross-entropy)."""
        self.teacher, self.kickstart_coef, self.kickstart_steps = teacher, float(coef), int(steps)
        self.buf_teacher_actions = np.zeros_like(self.buf_actions)

    def kickstart_weight(self, agent_steps: int) -> float:
        """The weight of the kickstarting loss for a rollout that starts after ``agent_steps``."""
        if self.teacher is None:
            return 0.0
        return self.kickstart_coef * max(0.0, 1.0 - agent_steps / self.kickstart_steps)

    # ------------------------------------------------------------------ observations and values
    def _observe(self, observations: np.ndarray) -> np.ndarray:
        """``(M, N, D)`` raw observations → ``(M·N, D)`` float32 as the policy sees them (updating the statistics)."""
        raw = observations.reshape(self.rows, self.obs_dim)
        if self.normalizer is None:
            return raw.astype(np.float32)
        if self.normalizer.training:
            self.normalizer.obs_rms.update(raw)
        return self._normalized(raw)

    def _normalized(self, raw: np.ndarray) -> np.ndarray:
        """VecNormalize's ``normalize_obs`` in float32: (x − mean) / √(var + ε), clipped. VecNormalize computes in
        float64 and the policy then sees float32, so the two differ by float32 rounding only; at a thousand rows of
        500 features this is a third of the time (MultiHop)."""
        normalizer = self.normalizer
        if normalizer is None:
            return raw.astype(np.float32)
        rms: Any = normalizer.obs_rms  # a RunningMeanStd: Box observations (check_env)
        mean = rms.mean.astype(np.float32)
        scale = (1.0 / np.sqrt(rms.var + normalizer.epsilon)).astype(np.float32)
        out = np.subtract(raw, mean, dtype=np.float32)
        out *= scale
        return np.clip(out, -normalizer.clip_obs, normalizer.clip_obs, out=out)

    def _mask_rows(self, infos: dict[str, np.ndarray], rows: int | None = None) -> np.ndarray:
        """The info columns' masks of ``rows`` agent rows (all by default) as the policy reads them (sb3_masks)."""
        rows = self.rows if rows is None else rows
        return sb3_masks(np.stack([infos[k].reshape(rows) > 0.5 for k in self.masks], axis=1), self.action_space)

    def actor_distribution(self, obs: torch.Tensor, masks):
        """The policy's action distribution on ``obs`` (masked if ``masks`` is not None), from the actor alone (SB3's
        ``get_distribution``): MAPPO's values come from its own critic, so the policy's value branch, which SB3's
        ``forward`` and ``evaluate_actions`` compute too, is skipped. The same actions, log-probabilities and
        random draws as theirs."""
        return self._distribution(self.policy, obs, masks)

    @staticmethod
    def _distribution(policy, obs: torch.Tensor, masks):
        if masks is None:
            return policy.get_distribution(obs)
        return policy.get_distribution(obs, action_masks=masks)

    def _values(self, obs: torch.Tensor) -> torch.Tensor:
        if self.critic is not None:
            return self.critic(obs)
        return self.policy.predict_values(obs).flatten()

    # ------------------------------------------------------------------ rollout
    def collect(self) -> RolloutStats:
        """One rollout of T steps of every copy into the buffers, then the advantages (GAE)."""
        with _unvalidated_distributions():
            return self._collect()

    def _collect(self) -> RolloutStats:
        stats = RolloutStats()
        policy, gamma = self.policy, float(self.model.gamma)
        policy.set_training_mode(False)
        torch.set_num_threads(1)
        self.rollout_kickstart_weight = self.kickstart_weight(self.model.num_timesteps)
        env_actions_dtype = np.int64 if isinstance(self.action_space, (spaces.Discrete, spaces.MultiDiscrete)) else None
        for t in range(self.steps):
            obs = self.next_obs
            self.buf_obs[t] = obs
            self.buf_starts[t] = self.next_starts
            obs_t = torch.from_numpy(obs)
            if self.buf_masks is not None:
                self.buf_masks[t] = self.next_masks
            with torch.no_grad():
                if self.critic is not None:
                    distribution = self.actor_distribution(obs_t, self.next_masks)
                    actions = distribution.get_actions(deterministic=False)
                    log_probs = distribution.log_prob(actions)
                    values = self.critic(obs_t)
                elif self.buf_masks is not None:
                    actions, values, log_probs = policy(obs_t, action_masks=self.next_masks)
                else:
                    actions, values, log_probs = policy(obs_t)
            actions_np = actions.numpy()
            self.buf_actions[t] = actions_np.reshape(self.buf_actions[t].shape)
            if self.rollout_kickstart_weight > 0.0 and self.buf_teacher_actions is not None:
                with torch.no_grad():
                    taught = self._distribution(self.teacher, obs_t, self.next_masks).get_actions(deterministic=True)
                self.buf_teacher_actions[t] = taught.numpy().reshape(self.buf_teacher_actions[t].shape)
            self.buf_log_probs[t] = log_probs.numpy()
            self.buf_values[t] = values.flatten().numpy()
            env_actions = self._env_actions(actions_np, env_actions_dtype)
            acted = time.perf_counter()
            step = self.batch.step(env_actions)
            stats.seconds_stepping += time.perf_counter() - acted
            raw_rewards = step.rewards.reshape(self.rows)
            ended_copies = step.ended
            ended_rows = np.repeat(ended_copies, self.n)
            self.buf_rewards[t] = self._scaled_rewards(raw_rewards, ended_rows)
            self.episode_return += step.rewards.mean(axis=1)
            self.episode_length += 1
            self.next_obs = self._observe(step.observations)
            if self.buf_masks is not None:
                self.next_masks = self._mask_rows(step.infos)
            for i in np.flatnonzero(ended_copies).tolist():
                self.episodes.append((float(self.episode_return[i]), int(self.episode_length[i])))
                if self.next_masks is not None:
                    self.next_masks[i * self.n : (i + 1) * self.n] = self._mask_rows(step.reset_infos[i], self.n)
            self.episode_return[ended_copies] = 0.0
            self.episode_length[ended_copies] = 0
            self._bootstrap_truncated(step, t, gamma)
            self.next_starts = ended_rows.astype(np.float32)
        with torch.no_grad():
            last_values = self._values(torch.from_numpy(self.next_obs)).numpy()
        self._advantages(last_values, gamma, float(self.model.gae_lambda))
        return stats

    def _env_actions(self, actions: np.ndarray, dtype) -> np.ndarray:
        space = self.action_space
        shaped = actions.reshape(self.m, self.n, *(space.shape or ()))
        if isinstance(space, spaces.Box):
            return np.clip(shaped, space.low, space.high).astype(space.dtype)
        if isinstance(space, spaces.MultiBinary):
            return shaped.astype(space.dtype)
        return shaped.astype(dtype)

    def _scaled_rewards(self, raw: np.ndarray, ended_rows: np.ndarray) -> np.ndarray:
        """Rewards in the units the critic learns: divided by the running std of the discounted return, clipped
        (``VecNormalize.normalize_reward``, with its ``returns`` bookkeeping)."""
        normalizer = self.normalizer
        if normalizer is None or not normalizer.norm_reward:
            return raw.astype(np.float32)
        if normalizer.training:
            self.discounted = self.discounted * normalizer.gamma + raw
            normalizer.ret_rms.update(self.discounted)
        scaled = np.clip(
            raw / np.sqrt(normalizer.ret_rms.var + normalizer.epsilon), -normalizer.clip_reward, normalizer.clip_reward
        )
        self.discounted[ended_rows] = 0.0
        return scaled.astype(np.float32)

    def _bootstrap_truncated(self, step, t: int, gamma: float) -> None:
        """A copy cut off by ``max_cycles`` did not end by itself: its last reward gets γ·V(final observation), as
        SB3 does for ``TimeLimit.truncated``."""
        cut = np.flatnonzero(step.truncated & ~step.terminated)
        if not len(cut):
            return
        final = np.concatenate([step.final_observations[i].reshape(self.n, self.obs_dim) for i in cut])
        with torch.no_grad():
            values = self._values(torch.from_numpy(self._normalized(final))).numpy()
        rows = (cut[:, None] * self.n + np.arange(self.n)).ravel()
        self.buf_rewards[t, rows] += gamma * values

    def _advantages(self, last_values: np.ndarray, gamma: float, lam: float) -> None:
        """GAE (Schulman et al. 2016, eq. 16): one reverse pass over T, vectorised over the M·N rows. A step's
        successor belongs to the same episode unless the next step starts one (``buf_starts``)."""
        next_advantage = np.zeros(self.rows, dtype=np.float32)
        next_values = last_values.astype(np.float32)
        next_continues = 1.0 - self.next_starts
        for t in range(self.steps - 1, -1, -1):
            delta = self.buf_rewards[t] + gamma * next_values * next_continues - self.buf_values[t]
            next_advantage = delta + gamma * lam * next_continues * next_advantage
            self.advantages[t] = next_advantage
            next_values, next_continues = self.buf_values[t], 1.0 - self.buf_starts[t]

    # ------------------------------------------------------------------ update
    def update(self, progress_remaining: float, critic_only: bool = False) -> dict[str, float]:
        with _unvalidated_distributions():
            return self._update(progress_remaining, critic_only)

    def _update(self, progress_remaining: float, critic_only: bool = False) -> dict[str, float]:
        """``n_epochs`` passes of PPO's clipped objective over the rollout in minibatches; returns SB3's ``train/``
        statistics. ``critic_only``: the value loss alone (a warm start's critic warm-up: the actor's parameters get
        no gradient, so the optimizer leaves them as they are)."""
        model, policy = self.model, self.policy
        torch.set_num_threads(self.update_threads)
        policy.set_training_mode(True)
        model._current_progress_remaining = progress_remaining  # SB3 saves it with the model
        # SB3's own learning-rate step (BaseAlgorithm._update_learning_rate) through its public pieces
        learning_rate = model.lr_schedule(progress_remaining)
        model.logger.record("train/learning_rate", learning_rate)
        optimizers = [policy.optimizer] + ([self.critic_optimizer] if self.critic_optimizer is not None else [])
        for optimizer in optimizers:
            update_learning_rate(optimizer, learning_rate)
        clip_range = float(model.clip_range(progress_remaining))
        clip_range_vf = None if model.clip_range_vf is None else float(model.clip_range_vf(progress_remaining))
        data = self._rollout_tensors()
        total = self.steps * self.rows
        if self.critic is not None:
            # the critic needs a whole copy's rows (its state): minibatches are drawn as (step, copy) blocks
            blocks, block_rows = self.steps * self.m, self.n
        else:
            blocks, block_rows = total, 1
        blocks_per_batch = max(1, min(int(model.batch_size), total) // block_rows)
        params = [p for optimizer in optimizers for group in optimizer.param_groups for p in group["params"]]
        logs: dict[str, list[float]] = {k: [] for k in ("pg", "vf", "ent", "kl", "clip", "kick")}
        kickstart = data["teacher_actions"] is not None and not critic_only
        for _ in range(int(model.n_epochs)):
            order = torch.randperm(blocks, generator=self.generator)
            for lo in range(0, blocks, blocks_per_batch):
                chosen = order[lo : lo + blocks_per_batch]
                idx = chosen if block_rows == 1 else (chosen[:, None] * block_rows + torch.arange(block_rows)).flatten()
                pg_loss, vf_loss, ent_loss, ratio, log_ratio = self._losses(data, idx, clip_range, clip_range_vf)
                with torch.no_grad():
                    approx_kl = float(torch.mean((ratio - 1) - log_ratio))
                    logs["clip"].append(float(torch.mean((torch.abs(ratio - 1) > clip_range).float())))
                if model.target_kl is not None and approx_kl > 1.5 * model.target_kl:
                    break  # SB3's rule: the policy moved too far from the one that collected the rollout
                loss = model.vf_coef * vf_loss
                if not critic_only:
                    loss = loss + pg_loss + model.ent_coef * ent_loss
                if kickstart:
                    masks = None if data["masks"] is None else data["masks"][idx]
                    distribution = self.actor_distribution(data["obs"][idx], masks)
                    kick_loss = -distribution.log_prob(data["teacher_actions"][idx]).mean()
                    loss = loss + self.rollout_kickstart_weight * kick_loss
                    logs["kick"].append(kick_loss.item())
                for optimizer in optimizers:
                    optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(params, model.max_grad_norm)
                for optimizer in optimizers:
                    optimizer.step()
                for key, value in (("pg", pg_loss), ("vf", vf_loss), ("ent", ent_loss)):
                    logs[key].append(value.item())
                logs["kl"].append(approx_kl)
            else:
                continue
            break  # the target KL stopped this epoch, and so the update
        policy.set_training_mode(False)
        torch.set_num_threads(1)
        # SB3's explained_variance(values, returns): 1 − Var[returns − values] / Var[returns]
        explained = 1 - float(np.var(self.advantages)) / max(float(np.var(self.advantages + self.buf_values)), 1e-12)
        return {
            "train/policy_gradient_loss": _mean(logs["pg"]),
            "train/value_loss": _mean(logs["vf"]),
            "train/entropy_loss": _mean(logs["ent"]),
            "train/approx_kl": _mean(logs["kl"]),
            "train/clip_fraction": _mean(logs["clip"]),
            "train/clip_range": clip_range,
            **({} if clip_range_vf is None else {"train/clip_range_vf": clip_range_vf}),  # as SB3's PPO logs it
            "train/explained_variance": explained,
            **(
                {
                    # the weight this update applied (none in a critic-only update)
                    "train/kickstart_weight": self.rollout_kickstart_weight if kickstart else 0.0,
                    "train/kickstart_loss": _mean(logs["kick"]),
                }
                if self.teacher is not None
                else {}
            ),
        }

    def _rollout_tensors(self) -> dict[str, Any]:
        """The rollout's buffers as flat tensors over its T·M·N rows (views, no copies), and the returns."""
        total = self.steps * self.rows
        actions = self._action_rows(self.buf_actions)
        values = torch.from_numpy(self.buf_values.reshape(total))
        advantages = torch.from_numpy(self.advantages.reshape(total))
        return {
            "obs": torch.from_numpy(self.buf_obs.reshape(total, self.obs_dim)),
            "actions": actions,
            "log_probs": torch.from_numpy(self.buf_log_probs.reshape(total)),
            "values": values,
            "advantages": advantages,
            "returns": advantages + values,
            "masks": None if self.buf_masks is None else self.buf_masks.reshape(total, -1),
            "teacher_actions": None
            if self.rollout_kickstart_weight <= 0.0 or self.buf_teacher_actions is None
            else self._action_rows(self.buf_teacher_actions),
        }

    def _action_rows(self, buffer: np.ndarray) -> torch.Tensor:
        """A ``(T, M·N, …)`` action buffer as a tensor of T·M·N rows, as the policy's ``log_prob`` takes them."""
        actions = torch.from_numpy(buffer.reshape(self.steps * self.rows, *buffer.shape[2:]))
        if isinstance(self.action_space, spaces.Discrete):
            actions = actions.long().flatten()
        return actions

    def _losses(self, data: dict[str, Any], idx: torch.Tensor, clip_range: float, clip_range_vf: float | None):
        """PPO's losses on the rows ``idx``: (policy, value, entropy, ratio, log ratio), as SB3's PPO.train."""
        policy, model = self.policy, self.model
        obs = data["obs"][idx]
        masks = None if data["masks"] is None else data["masks"][idx]
        if self.critic is not None:
            distribution = self.actor_distribution(obs, masks)
            log_prob, entropy = distribution.log_prob(data["actions"][idx]), distribution.entropy()
            values = self.critic(obs)
        elif masks is not None:
            values, log_prob, entropy = policy.evaluate_actions(obs, data["actions"][idx], action_masks=masks)
        else:
            values, log_prob, entropy = policy.evaluate_actions(obs, data["actions"][idx])
        values = values.flatten()
        advantages = data["advantages"][idx]
        if model.normalize_advantage and len(advantages) > 1:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        log_ratio = log_prob - data["log_probs"][idx]
        ratio = torch.exp(log_ratio)
        clipped = torch.clamp(ratio, 1 - clip_range, 1 + clip_range)
        pg_loss = -torch.min(advantages * ratio, advantages * clipped).mean()
        if clip_range_vf is not None:
            old = data["values"][idx]
            values = old + torch.clamp(values - old, -clip_range_vf, clip_range_vf)
        vf_loss = nn.functional.mse_loss(data["returns"][idx], values)
        ent_loss = -torch.mean(-log_prob) if entropy is None else -torch.mean(entropy)
        return pg_loss, vf_loss, ent_loss, ratio, log_ratio

    def critic_state(self) -> dict[str, Any] | None:
        """MAPPO's critic and its optimizer's state (tensors and plain containers), or None for IPPO."""
        if self.critic is None or self.critic_optimizer is None:
            return None
        return {"critic": self.critic.state_dict(), "optimizer": self.critic_optimizer.state_dict()}

    # ------------------------------------------------------------------ the loop
    def learn(
        self,
        total_timesteps: int,
        on_rollout_start: Callable[[], None] | None = None,
        on_rollout_end: Callable[[], None] | None = None,
        on_steps: Callable[[int], None] | None = None,
    ) -> None:
        """Train until ``model.num_timesteps`` (agent-steps: every agent row of every copy counts once, as SB3
        counts slots) reaches ``total_timesteps``. ``on_rollout_start`` runs before each rollout (checkpoints),
        ``on_rollout_end`` after each update, with the rollout's row recorded but not yet dumped (held-out
        evaluation); ``on_steps(n)`` reports progress."""
        model = self.model
        start_steps, started = model.num_timesteps, time.perf_counter()
        iteration = 0
        while model.num_timesteps < total_timesteps:
            if on_rollout_start is not None:
                on_rollout_start()
            rollout_start = time.perf_counter()
            stats = self.collect()
            collected = self.steps * self.rows
            model.num_timesteps += collected
            if on_steps is not None:
                on_steps(collected)
            collect_seconds = time.perf_counter() - rollout_start
            critic_only = model.num_timesteps - collected < self.critic_warmup_until
            logs = self.update(1.0 - min(1.0, model.num_timesteps / max(total_timesteps, 1)), critic_only)
            iteration += 1
            elapsed = time.perf_counter() - started
            self.elapsed = elapsed
            logger = model.logger
            for key, value in logs.items():
                logger.record(key, value)
            if self.episodes:
                logger.record("rollout/ep_rew_mean", float(np.mean([r for r, _ in self.episodes])))
                logger.record("rollout/ep_len_mean", float(np.mean([n for _, n in self.episodes])))
            logger.record("time/iterations", iteration)
            logger.record("time/fps", int((model.num_timesteps - start_steps) / max(elapsed, 1e-9)))
            logger.record("time/time_elapsed", elapsed)
            logger.record("time/total_timesteps", model.num_timesteps)
            logger.record("time/collect_seconds", collect_seconds)
            logger.record("time/env_step_seconds", stats.seconds_stepping)
            if on_rollout_end is not None:
                on_rollout_end()
            logger.dump(model.num_timesteps)


@contextlib.contextmanager
def _unvalidated_distributions() -> Iterator[None]:
    """torch's distributions check their arguments on every construction (a tenth of MultiHop's rollout, for logits
    the network has just computed); off while the trainer runs, then as it was."""
    before = torch.distributions.Distribution._validate_args
    torch.distributions.Distribution.set_default_validate_args(False)
    try:
        yield
    finally:
        torch.distributions.Distribution.set_default_validate_args(before)


def _mean(values: list[float]) -> float:
    return float(np.mean(values)) if values else float("nan")


def build_model(algorithm, policy, policy_kwargs: dict, observation_space, action_space, hyperparams: dict, seed: int):
    """An SB3 ``PPO``/``MaskablePPO`` with the run's policy and hyperparameters but no env: its ``policy`` is what
    :class:`BatchedPPO` trains, and ``agents/artifacts.py`` saves it as any SB3 model."""
    settings = {k: v for k, v in hyperparams.items() if k != "policy_kwargs"}
    for key, value in DEFAULTS.items():
        settings.setdefault(key, value)
    model = algorithm(
        policy,
        env=None,
        seed=seed,
        device="cpu",
        verbose=0,
        policy_kwargs=policy_kwargs,
        _init_setup_model=False,
        **settings,
    )
    model.observation_space, model.action_space, model.n_envs = observation_space, action_space, 1
    model._setup_model()
    return model
