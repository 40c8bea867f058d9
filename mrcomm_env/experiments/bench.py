"""The parts of ``mrcomm bench`` beyond env-steps/s: training throughput, documented limits, env-specific timings.

Speed and memory goals are checked here, by measurement, never by timed unit tests.
"""

from __future__ import annotations

from typing import Any

from mrcomm_env.registry import make


def train_section(targets: list[str], params: dict, timesteps: int, progress: bool = True) -> dict[str, Any]:
    """PPO agent-steps/s through the agent-slot VecEnv on every target and on mpe2's ``simple_spread_v3``, with
    the share of wall time spent in ``env.step`` (the goal: our envs train at least as fast as the reference)."""
    from tqdm.auto import tqdm

    from mrcomm_env.experiments.learning import train_throughput

    def reference():
        from mpe2 import simple_spread_v3

        return simple_spread_v3.parallel_env(N=3, continuous_actions=False)

    out = {"timesteps": timesteps, "reference": train_throughput([reference] * 4, timesteps)}
    print(f"train  reference simple_spread_v3: {_train_line(out['reference'])}")
    slots = out["reference"]["slots"]
    out["envs"] = {}
    for env_id in tqdm(targets, desc="PPO throughput", leave=False, disable=not progress):
        # about as many agent slots as the reference, so the policy's batch (and its cost per agent-step) match
        copies = max(1, round(slots / make(env_id, **params).n_agents))
        result = train_throughput([lambda env_id=env_id: make(env_id, **params)] * copies, timesteps)
        result["ratio_to_reference"] = result["agent_steps_per_s"] / out["reference"]["agent_steps_per_s"]
        out["envs"][env_id] = result
        print(f"train  {env_id}: {_train_line(result)}, ratio {result['ratio_to_reference']:.2f}")
    return out


def _train_line(result: dict) -> str:
    return (
        f"{result['agent_steps_per_s']:,.0f} PPO agent-steps/s ({result['slots']} slots), "
        f"{100 * result['env_step_share']:.0f} % of wall time in env.step"
    )


def limits_section(targets: list[str], seconds: float) -> dict[str, Any]:
    """Steps/s and peak memory of every documented maximum (``LIMIT_CONFIGS``), each in a fresh process."""
    from mrcomm_env.experiments.limits import limit_configs, measure_limit

    out = {}
    for env_id in targets:
        for name, config in limit_configs(env_id).items():
            result = measure_limit(env_id, config, seconds=seconds)
            out[f"{env_id}:{name}"] = {"config": config, **result}
            print(
                f"limit  {env_id} {name}: {result.get('steps_per_s', float('nan')):,.2f} steps/s, "
                f"peak {result.get('peak_rss_mb', float('nan')):,.0f} MB"
            )
    return out


def extras_section(targets: list[str]) -> dict[str, Any]:
    """Env-specific timings a reproduction module offers as ``benchmarks() -> {name: value}``."""
    from mrcomm_env.experiments.reproductions import module

    out = {}
    for env_id in targets:
        measure = getattr(module(env_id), "benchmarks", None)
        if measure is None:
            continue
        out[env_id] = measure()
        for name, value in out[env_id].items():
            print(
                f"extra  {env_id} {name}: {value:.6g}"
                if isinstance(value, float)
                else f"extra  {env_id} {name}: {value}"
            )
    return out
