"""Running a policy in an environment: the policies ``--policy`` names, episodes, evaluation summaries, the
scores the learned-against-scripted comparison uses, and the speed benchmark."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from mrcomm_baselines import make_policy, policy_names
from mrcomm_env.core.stats import mean_ci95
from mrcomm_env.registry import canonical_id, make


def make_any_policy(env_id: str, name: str, trust_pickle: bool = False, **params):
    """A scripted baseline by name, or a learned model: ``ppo:PATH``, ``maskable_ppo:PATH``, ``dqn:PATH``, ``ippo:PATH``,
    ``pretrained``. Unknown names raise ``ValueError`` listing both kinds. ``trust_pickle``: a learned model's run
    may be one written before the formats that load without running code (``--trust-pickle``)."""
    if name in policy_names(env_id):
        return make_policy(env_id, name, **params)
    try:
        from mrcomm_agents.learned import is_learned, load_policy  # extra "train" (SB3, torch)
    except ImportError:
        if ":" in name or name == "pretrained":
            raise ValueError("learned policies need the training extra: pip install 'mrcomm-env[train]'") from None
        raise
    if is_learned(name):
        return load_policy(name, env_id, trust_pickle=trust_pickle, **params)
    raise ValueError(
        f"unknown policy {name!r} for {canonical_id(env_id)}; valid policies are: "
        f"{', '.join(policy_names(env_id))}, pretrained, or ALGO:RUN_FOLDER with ALGO ppo, maskable_ppo, dqn, ippo or mappo"
    )


def baseline_label(name: str, params: dict) -> str:
    """A baseline's name in the comparison's table: ``name`` and its parameters (``periodic_sketch period=1``)."""
    return name + (" " + ", ".join(f"{k}={v}" for k, v in params.items()) if params else "")


def acting_setting(policy, params: dict) -> dict:
    """The env arguments ``policy`` acts in: a learned model's own training setting (its spaces depend on the env's
    arguments) with ``params`` (``--param``) applied one by one, said on stderr; a scripted policy's, ``params``."""
    trained_on = getattr(policy, "env_kwargs", None)
    if trained_on is None:
        return params
    params = {**trained_on, **params}
    print(f"learned model: its training setting with --param applied, {params}", file=sys.stderr)
    return params


def prepared_policy(
    env_id: str, name: str, params: dict, policy_params: dict, seed: int, trust_pickle: bool = False
) -> tuple[str, dict, Any]:
    """``(canonical id, env arguments, policy)`` for ``mrcomm evaluate``: every part a bad argument could break, built
    once before the first episode. The threads are limited first (:func:`limit_threads`); the policy named ``name``
    with ``policy_params`` is made, the env arguments it acts in are ``params`` over its own (:func:`acting_setting`),
    and it is reset once against that env seeded ``seed`` (where it refuses an env, e.g. a mode it needs)."""
    limit_threads()
    env_id = canonical_id(env_id)
    policy = make_any_policy(env_id, name, trust_pickle=trust_pickle, **policy_params)
    params = acting_setting(policy, params)
    probe = make(env_id, **params)
    try:
        probe.reset(seed=seed)
        policy.reset(probe.local_views(), seed)
    finally:
        probe.close()
    return env_id, params, policy


def limit_threads() -> None:
    """One BLAS/torch thread per process: PPO here ran 45× slower with torch's default of 2 threads."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        import torch  # extra "train"
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


def bits_per_agent(env, metrics: dict, per: str = "step") -> float:
    """Bits sent per agent, per step (``per="step"``) or over the whole episode (``"episode"``: for envs whose
    episodes end when the task is done, where a per-step rate would hide that a slow policy sends longer)."""
    steps = max(env.step_count, 1) if per == "step" else 1
    return float(metrics["bits_sent"]) / (env.n_agents * steps)


def evaluate_policy(env_id: str, env_kwargs: dict, policy, seeds: list[int], spec: dict) -> dict[str, list[float]]:
    """Per episode: the task metric ``spec["metric"]``, bits per agent (per step or per episode) and the return.

    ``spec["unfinished"]``: the value a metric that reports −1 or nan for "not done within the episode" (a
    completion time) counts as, so that never finishing is not mistaken for finishing at once. Without it, a
    metric among the env's ``UNREACHED_TIMES`` counts as the episode's length (``counted_time``, as the held-out
    evaluation of training counts it), so that no episode is left out of an average."""
    env = make(env_id, **env_kwargs)
    out: dict[str, list[float]] = {"metric": [], "bits": [], "return": []}
    for seed in seeds:
        metrics = run_episode(env, policy, seed)
        value = float(metrics[spec["metric"]])
        if "unfinished" in spec and not value >= 0:  # −1 or nan: not done within the episode
            value = float(spec["unfinished"])
        value = env.counted_time(spec["metric"], value)
        out["metric"].append(value)
        out["bits"].append(bits_per_agent(env, metrics, spec.get("bits_per", "step")))
        out["return"].append(float(metrics["episode_return"]))
    env.close()
    return out


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
