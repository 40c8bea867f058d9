"""Warm start: clone a scripted policy's decisions into a learned policy before PPO fine-tunes it.

``mrcomm train ID --init-from baseline:NAME`` runs this between building the model and ``learn()``: PPO then
starts at the teacher's level and only has to improve on it (issue: learned communication at least as good as
the papers' algorithms). The teacher is any :class:`mrcomm_env.core.policy.Policy` (the experiments layer
resolves ``baseline:NAME``; this package never imports the scripted baselines).

Behaviour cloning with DAgger (Ross, Gordon & Bagnell 2011): round 0 rolls out the teacher; each later round
rolls out the learner itself, sampling its own actions, and labels every state it visits with the teacher's
action there, so the learner is trained on the states its own mistakes lead to, not only on the teacher's.
Every round trains on everything gathered so far: the policy by the log-likelihood of the teacher's actions
(any SB3 action distribution: Discrete, MultiBinary, Box), the critic by the discounted returns of the rollouts,
in the units VecNormalize gives the rewards, so that PPO's first advantages are not noise.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize

from mrcomm_agents.heldout import normalized, sb3_masks, uses_masks
from mrcomm_env.core.policy import Policy
from mrcomm_env.registry import make

#: rollouts per DAgger round, rounds, and passes over the gathered data after each round
EPISODES_PER_ROUND = 8
ROUNDS = 4
EPOCHS = 8
BATCH = 512


@dataclass
class CloneReport:
    """What the warm start did: samples, and per round the share of the learner's (sampled) action elements (each
    select bit, each discrete choice) that agree with the teacher's, on the learner's own rollouts (round 0: the
    teacher's)."""

    samples: int
    agreement: list[float]
    seconds: float

    def as_dict(self) -> dict[str, Any]:
        return {"samples": self.samples, "agreement": self.agreement, "seconds": self.seconds}


def _rollout(model, venv, teacher: Policy, env_id: str, env_kwargs: dict, seed: int, learner_acts: bool):
    """One episode: (observations, teacher actions, executed actions, rewards, action masks or None) per step,
    agents stacked."""
    env = make(env_id, **env_kwargs)
    observations, _ = env.reset(seed=seed)
    views = env.local_views()
    teacher.reset(views, seed)
    masked = uses_masks(model) and callable(getattr(env, "action_masks", None))
    steps = []
    while env.agents:
        agents = list(observations)
        obs = np.stack([observations[a] for a in agents]).astype(np.float32)
        masks = sb3_masks(env.action_masks(), model.action_space) if masked else None
        labels = teacher.act(observations, views)
        label_array = np.stack([np.asarray(labels[a]) for a in agents])
        if masks is not None:  # an action the teacher takes is one it can take: never a log-probability of −∞
            if label_array.ndim == 2:  # MultiBinary: the value of every bit the teacher set
                masks.reshape(len(agents), -1, 2)[..., 1] |= label_array > 0.5
            else:
                masks[np.arange(len(agents)), label_array.astype(np.int64)] = True
        if learner_acts:
            extra = {"action_masks": masks} if masks is not None else {}
            chosen, _ = model.predict(normalized(venv, obs), deterministic=False, **extra)
            actions = {a: chosen[i] for i, a in enumerate(agents)}
        else:
            actions = labels
        executed = np.stack([np.asarray(actions[a]) for a in agents])
        observations, rewards, _, _, _ = env.step(actions)
        steps.append((obs, label_array, executed, np.array([rewards[a] for a in agents], dtype=np.float64), masks))
    env.close()
    return steps


def _returns(steps, gamma: float) -> np.ndarray:
    """Discounted return from every step of one episode, per agent: (T, N)."""
    rewards = np.stack([s[3] for s in steps])
    out = np.zeros_like(rewards)
    running = np.zeros(rewards.shape[1])
    for t in range(len(rewards) - 1, -1, -1):
        running = rewards[t] + gamma * running
        out[t] = running
    return out


def clone(model, venv, teacher: Policy, env_id: str, env_kwargs: dict, seed: int) -> CloneReport:
    """Train ``model``'s policy and critic on ``teacher``'s decisions (DAgger); see the module docstring."""

    start = time.perf_counter()
    policy = model.policy
    gamma = float(model.gamma)
    optimizer = torch.optim.Adam(policy.parameters(), lr=1e-3)
    rng = np.random.default_rng(seed)
    data_obs, data_act, data_ret, data_mask = [], [], [], []
    agreement = []
    for round_index in range(ROUNDS):
        agree = total = 0
        for episode in range(EPISODES_PER_ROUND):
            episode_seed = 1_000_000 + seed * 10_000 + round_index * EPISODES_PER_ROUND + episode
            steps = _rollout(model, venv, teacher, env_id, env_kwargs, episode_seed, learner_acts=round_index > 0)
            obs = np.concatenate([s[0] for s in steps])
            labels = np.concatenate([s[1] for s in steps])
            executed = np.concatenate([s[2] for s in steps])
            agree += int((labels.reshape(len(labels), -1) == executed.reshape(len(executed), -1)).sum())
            total += labels.size
            returns = _returns(steps, gamma).reshape(-1)
            if isinstance(venv, VecNormalize):
                venv.obs_rms.update(obs)
                venv.ret_rms.update(returns)
            data_obs.append(obs)
            data_act.append(labels)
            data_ret.append(returns)
            if steps[0][4] is not None:
                data_mask.append(np.concatenate([s[4] for s in steps]))
        agreement.append(agree / max(total, 1))
        _fit(policy, optimizer, venv, data_obs, data_act, data_ret, data_mask, rng)
    return CloneReport(sum(len(o) for o in data_obs), agreement, time.perf_counter() - start)


def _fit(policy, optimizer, venv, data_obs, data_act, data_ret, data_mask, rng) -> None:
    obs = normalized(venv, np.concatenate(data_obs))
    masks = np.concatenate(data_mask) if data_mask else None
    actions = np.concatenate(data_act)
    returns = np.concatenate(data_ret)
    if isinstance(venv, VecNormalize):  # the critic learns returns in the units VecNormalize gives rewards
        returns = returns / np.sqrt(venv.ret_rms.var + venv.epsilon)
    obs_t = torch.as_tensor(obs, dtype=torch.float32)
    act_t = torch.as_tensor(actions, dtype=torch.float32)
    ret_t = torch.as_tensor(returns, dtype=torch.float32)
    policy.set_training_mode(True)
    for _ in range(EPOCHS):
        order = rng.permutation(len(obs))
        for lo in range(0, len(order), BATCH):
            idx = torch.as_tensor(order[lo : lo + BATCH])
            if masks is None:
                values, log_prob, _ = policy.evaluate_actions(obs_t[idx], act_t[idx])
            else:
                values, log_prob, _ = policy.evaluate_actions(
                    obs_t[idx], act_t[idx], action_masks=masks[order[lo : lo + BATCH]]
                )
            loss = -log_prob.mean() + 0.5 * torch.nn.functional.mse_loss(values.flatten(), ret_t[idx])
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), 0.5)
            optimizer.step()
    policy.set_training_mode(False)


def critic_parameters(policy) -> set[int]:
    """The ids of the critic's parameters: SB3's ``value_net`` and every extractor layer named for the value
    (``mlp_extractor.value_net`` of an MlpPolicy; ``value_candidates``, ``value_own``, ``value_head`` of a candidate
    policy). Everything else (the shared features, the actor, its action head) is the actor's."""
    return {id(p) for name, p in policy.named_parameters() if "value" in name.split(".")[0] or ".value" in name}


class CriticWarmup(BaseCallback):
    """For the first ``steps`` agent-steps of PPO after a warm start, only the critic learns: the actor's
    parameters are frozen. A cloned actor with a critic fitted to another policy's returns gets noisy advantages,
    and PPO's first updates then move it away from the teacher's level before the critic has caught up."""

    def __init__(self, steps: int):
        super().__init__()
        self.steps = int(steps)
        self.frozen: list[torch.nn.Parameter] = []

    def _on_training_start(self) -> None:
        if self.num_timesteps >= self.steps:
            return
        critic = critic_parameters(self.model.policy)
        self.frozen = [p for p in self.model.policy.parameters() if id(p) not in critic and p.requires_grad]
        for parameter in self.frozen:
            parameter.requires_grad_(False)

    def _on_rollout_start(self) -> None:
        if self.frozen and self.num_timesteps >= self.steps:
            self._release()

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        self._release()

    def _release(self) -> None:
        for parameter in self.frozen:
            parameter.requires_grad_(True)
        self.frozen = []
