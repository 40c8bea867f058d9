"""Bounds that no policy can pass, beside the learned and scripted rows of docs/learning.md.

Where beating a paper's algorithm by the comparison's margin is impossible, the page says so with a bound computed
from the live env on the comparison's own held-out episodes, and shows how close the learned policy gets.

* AsyncCL-v0: the delay of the flood (``scheme2_qinf``: every link carries all its receiver lacks), which no policy
  can undercut, and the bits of delivering each packet of the steps the flood completes once to every other robot,
  which no policy that completes them can send less than (headers not counted).
* ChannelAssociation-v0: the fewest steps in which any emissions can make every i-state final, and the fewest
  emissions that do it in that many steps (:func:`mrcomm_env.channel_association.theory.fewest_emissions`, an
  integer program over the layout, which a policy does not even see). The bound's code is played in the env, so its
  row is measured as every other row is.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from mrcomm_baselines import make_policy
from mrcomm_env.channel_association.theory import fewest_emissions
from mrcomm_env.experiments.comparison import comparison_row, metric_interval
from mrcomm_env.experiments.evaluation import bits_per_agent, run_episode
from mrcomm_env.registry import make


class PatternPlayer:
    """Plays fixed emission patterns, one row per robot (``patterns[i, t]``: robot i emits at step t), silent after
    them. The env lists its agents in robot order and every robot acts until the episode ends, so the i-th
    observation is robot i's."""

    def __init__(self) -> None:
        self.patterns = np.zeros((0, 0), dtype=bool)
        self.step = 0

    def reset(self, views, seed) -> None:
        self.step = 0

    def act(self, observations: dict, views) -> dict:
        t = self.step
        self.step += 1
        return {agent: int(t < self.patterns.shape[1] and self.patterns[i, t]) for i, agent in enumerate(observations)}


def fewest_steps_code(env) -> tuple[int, np.ndarray]:
    """The fewest steps t in which emissions can finish the episode ``env`` was just reset to, and the patterns with
    the fewest emissions that do so in t steps. t starts at ⌈log2 g⌉ for the largest group g of robots that must
    differ (fewer steps cannot give them distinct patterns) and grows while the program finds no code."""
    tracked = env.tracked_robots()
    largest = max((len(visual) + (len(set(wireless) - set(visual)) > 0) for _, wireless, visual in tracked), default=1)
    steps = max(math.ceil(math.log2(max(largest, 1))), 0)
    while (code := fewest_emissions(tracked, env.n_agents, steps)) is None:
        steps += 1
    return steps, code[1]


def channel_association_bound(env_id: str, env_kwargs: dict, seeds: list[int], spec: dict) -> list[dict]:
    """One row per bound: the fewest steps and, in that many steps, the fewest bits per robot of any policy, each
    episode's oracle code played from ``reset(seed)`` (its metrics are the env's own)."""
    env = make(env_id, **env_kwargs)
    player = PatternPlayer()

    def load_code(observations: dict) -> None:
        _, player.patterns = fewest_steps_code(env)

    metric, bits = [], []
    for seed in seeds:
        metrics = run_episode(env, player, seed, on_reset=load_code)
        metric.append(float(metrics[spec["metric"]]))
        bits.append(bits_per_agent(env, metrics, spec.get("bits_per", "step")))
    env.close()
    label = "bound: fewest steps, then fewest emissions (any policy; integer program)"
    row = comparison_row(label, None, metric, bits, len(seeds))
    return [{**row, "setting": None, "bound": True}]


def asynccl_bound(env_id: str, env_kwargs: dict, seeds: list[int], spec: dict) -> list[dict]:
    """The flood's delay and, below every policy that completes the same steps, the bits of its packets delivered
    once. Information moves one hop per step (eq. (4)–(5)) and the flood moves all of it, so robot i's row of robot
    j is, after every exchange, as fresh as any policy can make it; eq. (7)'s delay is therefore the fewest. To
    complete step k robot i needs M_k^j of every other robot j, and each of those packets reaches it over some link
    at least once: Σ_i Σ_(j≠i) Σ_(k ≤ c_i) bits(M_k^j), over the robots' complete frontiers c_i at the end."""
    env = make(env_id, **env_kwargs)
    flood = make_policy(env_id, "scheme2_qinf")
    n = env.n_agents
    cumulative = np.zeros(n)  # per robot j, bits of its packets of steps 0 … t
    per_step: list[np.ndarray] = []  # (n,) cumulative bits after each step's packets

    def first_packets(observations: dict) -> None:
        cumulative[:] = env.tables.packet_bits(0)
        per_step[:] = [cumulative.copy()]

    def new_packets(step: int, observations: dict, rewards: dict, infos: dict) -> None:
        cumulative[:] += env.tables.packet_bits(env.tables.t)
        per_step.append(cumulative.copy())

    metric, bits = [], []
    for seed in seeds:
        metrics = run_episode(env, flood, seed, on_reset=first_packets, on_step=new_packets)
        metric.append(float(metrics[spec["metric"]]))
        held = np.stack(per_step)  # held[k, j]: bits of robot j's packets of steps 0 … k
        delivered = 0.0
        for i, frontier in enumerate(env.tables.c):
            if frontier >= 0:
                delivered += float(held[frontier].sum() - held[frontier, i])
        bits.append(delivered / (n * max(env.step_count, 1)))
    env.close()
    label = "bound: the flood's delay, the fewest for the steps it completes; their packets delivered once (no headers)"
    row = comparison_row(label, None, metric, bits, len(seeds))
    return [{**row, "setting": None, "bound": True}]


#: the margins by which a learned policy beats a paper algorithm in #42: a task metric 10 % better at no more than
#: 5 % more bits, or 20 % fewer bits at a task metric not worse
METRIC_MARGIN, BITS_SLACK, BITS_MARGIN = 0.10, 0.05, 0.20


def bound_paragraph(bound: dict, best: dict, learned: list[dict], spec: dict) -> str:
    """What a bound row rules out, in numbers, for a metric where lower is better: the margins against the best
    paper algorithm ``best`` that no policy can reach, and how far the learned points that are not worse than
    ``best`` (beyond the intervals) sit from the bound."""
    metric, per = spec["metric"], spec.get("bits_per", "step")
    target = best["metric"] * (1.0 - METRIC_MARGIN)
    fewer_bits = best["bits"] * (1.0 - BITS_MARGIN)
    faster = "impossible" if bound["metric"] > target else "not ruled out"
    cheaper = "impossible" if bound["metric"] == best["metric"] and bound["bits"] > fewer_bits else "not ruled out"
    text = (
        f"**Bound** (the last row, on the same held-out episodes): no policy reaches a {metric} below "
        f"{bound['metric']:.4g}, and none reaches {bound['metric']:.4g} with fewer than {bound['bits']:.4g} bits per "
        f"agent per {per}. Beating `{best['policy']}` ({best['metric']:.4g} at {best['bits']:.4g} bits) by #42's "
        f"margins needs a {metric} of at most {target:.4g} at no more than {best['bits'] * (1 + BITS_SLACK):.4g} bits "
        f"({faster}), or at most {fewer_bits:.4g} bits at {best['metric']:.4g} ({cheaper})."
    )
    best_high = metric_interval(best)[1]
    not_worse = [r for r in learned if metric_interval(r)[0] <= best_high]
    if not_worse:
        closest = min(not_worse, key=lambda r: r["bits"])
        text += (
            f" The learned points whose {metric} is not worse than `{best['policy']}`'s send down to "
            f"{closest['bits']:.4g} bits ({spec['cost_param']} = {closest['cost']:g}): "
            f"{100 * (closest['bits'] / bound['bits'] - 1):.1f} % above the bound, where `{best['policy']}` is "
            f"{100 * (best['bits'] / bound['bits'] - 1):.1f} % above it."
        )
    return text


#: env id → the function giving its bound rows (env id, the comparison's env arguments, its held-out seeds, its spec)
BOUNDS: dict[str, Callable[[str, dict, list[int], dict], list[dict]]] = {
    "mrcomm/AsyncCL-v0": asynccl_bound,
    "mrcomm/ChannelAssociation-v0": channel_association_bound,
}


def bound_rows(env_id: str, spec: dict, seeds: list[int]) -> list[dict]:
    """The env's bound rows on the comparison's held-out ``seeds`` (none for an env without a bound)."""
    bound = BOUNDS.get(env_id)
    if bound is None:
        return []
    env_kwargs = spec["settings"].get(spec["algo"], {}).get("env_kwargs", {})
    return bound(env_id, env_kwargs, seeds, spec)
