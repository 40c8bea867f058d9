"""Running a policy in an environment: episodes, evaluation summaries and the speed benchmark."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from mrcomm_env.core.stats import mean_ci95


def limit_threads() -> None:
    """One BLAS/torch thread per process: PPO here ran 45× slower with torch's default of 2 threads."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        import torch
    except ImportError:
        return
    torch.set_num_threads(1)


def run_episode(
    env,
    policy,
    seed: int | None,
    *,
    on_reset: Callable[[dict], None] | None = None,
    on_step: Callable[[int, dict, dict, dict], bool | None] | None = None,
) -> dict[str, float]:
    """Play one episode of ``policy`` from ``reset(seed)``; returns the env's metrics plus ``episode_return``.

    The one episode loop of the package (evaluation and the reproductions). Hooks for what a caller records
    along the way: ``on_reset(observations)`` once, after the env and the policy are reset, and
    ``on_step(step, observations, rewards, infos)`` after every step (``step`` counts from 0). When
    ``on_step`` returns True the episode ends there, before the env's own horizon (e.g. at a simulated time).
    """
    observations, _ = env.reset(seed=seed)
    views = env.local_views()
    policy.reset(views, seed)
    if on_reset is not None:
        on_reset(observations)
    episode_return = 0.0
    step = 0
    while env.agents:
        actions = policy.act(observations, views)
        observations, rewards, _, _, infos = env.step(actions)
        if rewards:
            episode_return += float(np.mean(list(rewards.values())))
        if on_step is not None and on_step(step, observations, rewards, infos):
            break
        step += 1
    metrics = {k: float(v) for k, v in env.metrics().items()}
    metrics["episode_return"] = episode_return
    return metrics


def evaluate(env_factory: Callable[[], Any], policy, episodes: int, seed: int, progress: bool = True) -> dict:
    """``episodes`` episodes with seeds ``seed, seed+1, …``; per metric the mean, 95 % CI and all values."""
    from tqdm.auto import tqdm

    env = env_factory()
    values: dict[str, list[float]] = {}
    for k in tqdm(range(episodes), desc="episodes", disable=not progress, leave=False):
        for name, value in run_episode(env, policy, seed + k).items():
            values.setdefault(name, []).append(value)
    env.close()
    summary = {}
    for name, vals in values.items():
        mean, half = mean_ci95(vals)
        summary[name] = {"mean": mean, "ci95": half, "values": vals}
    return summary


def steps_per_second(
    env, act: Callable[[dict], dict], seconds: float, seed: int, on_reset: Callable[[int], None] | None = None
) -> tuple[float, float]:
    """Env-steps/s and agent-steps/s of ``env`` driven by ``act`` for about ``seconds``, resets included."""
    on_reset = on_reset or (lambda s: None)
    steps = agent_steps = 0
    episode = 0
    start = time.perf_counter()
    observations, _ = env.reset(seed=seed)
    on_reset(seed)
    deadline = start + seconds
    while True:
        if not env.agents:
            episode += 1
            observations, _ = env.reset(seed=seed + episode)
            on_reset(seed + episode)
        actions = act(observations)
        agent_steps += len(actions)
        observations, *_ = env.step(actions)
        steps += 1
        if steps % 16 == 0 and time.perf_counter() >= deadline:
            break
    elapsed = time.perf_counter() - start
    return steps / elapsed, agent_steps / elapsed
