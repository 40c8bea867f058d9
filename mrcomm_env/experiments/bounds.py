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
* MultiHop-v0: the weighted age of slots that carry every estimate their sender holds (a lower bound on the metric
  only; more room per slot is not a policy's to take, so its bits bound nothing), and a reference that is no
  bound: an **oracle** schedule that knows every robot's table (:class:`TableOracle`), what a policy could reach
  with knowledge of its neighbours' tables beyond what it heard (the comparison's ``observe_heard``).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from mrcomm_baselines import make_policy
from mrcomm_env.channel_association.theory import fewest_emissions
from mrcomm_env.experiments.comparison import (
    BITS_MARGIN,
    BITS_SLACK,
    METRIC_MARGIN,
    comparison_row,
    metric_interval,
)
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


def multihop_flood_ages(env, frames: int) -> float:
    """Eq. (1)'s weighted age, averaged over ``frames`` frame ends as the env averages it, of slots that carry every
    estimate their sender holds, over the episode ``env`` was just reset to (its links, slot order, slot time and
    weights). A robot's estimate of j is only ever replaced by a fresher one (a stamp moves forward), and every
    stamp a schedule can deliver by a slot is delivered by this one, so no policy's table is fresher at any frame
    end: the average is a lower bound for every policy at the env's slot size. Static links only."""
    if env.cfg.scene != "grid":
        raise ValueError(f"the flood bound needs static links (scene 'grid'); got scene {env.cfg.scene!r}")
    weights = env.world_arrays()["weights"]
    links = env.adj.astype(bool)
    diagonal = np.eye(env.n_agents, dtype=bool)
    stamps = np.where(diagonal, 0.0, -np.inf)  # as at reset: own estimate only
    t, total = float(env.t), 0.0
    for _ in range(frames):
        for sender in env.tdma.order.tolist():
            stamps[sender, sender] = t  # a robot's own estimate is current when it sends (t_ii = t)
            t += env.slot_dur
            receivers = links[sender]
            stamps[receivers] = np.maximum(stamps[receivers], stamps[sender])
        stamps[diagonal] = t
        ages = np.where(np.isfinite(stamps), t - stamps, t)  # an estimate never received: its age since the start
        total += float((weights * ages).sum()) / float(weights.sum())
    return total / max(frames, 1)


def check_setting(env) -> None:
    """MultiHop's references speak the ``relative`` layout (select bits over ranked candidates) on static links."""
    if env.cfg.layout != "relative" or env.cfg.scene != "grid":
        raise ValueError("MultiHop's references need the 'relative' layout on the static 'grid' scene")


def select_bits(chosen: np.ndarray, views, observations: dict) -> dict:
    """Each robot's chosen estimates (``chosen[i, j]``: robot i relays j) as the env's action: select bits over its
    ranked candidates."""
    selected = np.take_along_axis(chosen, views.team("candidates"), axis=1).astype(np.int8)
    return {agent: selected[i] for i, agent in enumerate(observations)}


class TableOracle:
    """A MultiHop schedule that knows every robot's table: at each frame it replays the frame in TDMA order and
    gives each sender the ``m − 1`` estimates whose eq. (1)-weighted freshness its receivers gain most, as they will
    hold them at its slot (greedy per slot, so not optimal; an estimate no receiver gains from is not sent). Its
    choices are the env's own select bits over each robot's ranked candidates (the ``relative`` layout)."""

    def __init__(self, env) -> None:
        check_setting(env)
        self.env = env

    def reset(self, views, seed) -> None:
        pass  # it keeps nothing: every frame starts from the env's tables

    def act(self, observations: dict, views) -> dict:
        env, n = self.env, self.env.n_agents
        weights, links = env.world_arrays()["weights"], env.adj.astype(bool)
        stamps = np.where(env.stamps > -np.inf, env.stamps, 0.0)  # never received: as old as the start (the metric)
        known = env.stamps > -np.inf
        chosen = np.zeros((n, n), dtype=bool)
        t = float(env.t)
        for sender in env.tdma.order.tolist():
            stamps[sender, sender], known[sender, sender] = t, True
            receivers = np.flatnonzero(links[sender])
            gain = (weights[receivers] * np.maximum(stamps[sender] - stamps[receivers], 0.0)).sum(axis=0)
            gain[sender] = 0.0
            gain[~known[sender]] = 0.0
            top = np.argsort(-gain, kind="stable")[: env.m - 1]
            top = top[gain[top] > 0.0]
            chosen[sender, top] = True
            sent = np.concatenate([[sender], top])
            for r in receivers:
                stamps[r, sent] = np.maximum(stamps[r, sent], stamps[sender, sent])
                known[r, sent] |= known[sender, sent]
            t += env.slot_dur
        return select_bits(chosen, views, observations)


def multihop_bound(env_id: str, env_kwargs: dict, seeds: list[int], spec: dict) -> list[dict]:
    """The flood's bound on the weighted age (its bits are those of slots as large as the robot count, which no
    policy can send: they bound nothing) and the oracle's row, played in the env as every other row is."""
    env = make(env_id, **env_kwargs)
    flood, flood_bits = [], []
    for seed in seeds:
        env.reset(seed=seed)
        flood.append(multihop_flood_ages(env, env.cfg.max_cycles))
        flood_bits.append(float(env.n_agents * env.cfg.bits_per_estimate))
    label = "bound: every slot carries every estimate its sender holds (metric only; those bits no slot holds)"
    rows = [{**comparison_row(label, None, flood, flood_bits, len(seeds)), "setting": None, "bound": True}]
    rows[0]["bits_bound"] = False
    references = {"oracle: knows every robot's table, greedy per slot (not a bound)": TableOracle(env)}
    for label, policy in references.items():
        metric, bits = [], []
        for seed in seeds:
            metrics = run_episode(env, policy, seed)
            metric.append(float(metrics[spec["metric"]]))
            bits.append(bits_per_agent(env, metrics, spec.get("bits_per", "step")))
        rows.append({**comparison_row(label, None, metric, bits, len(seeds)), "setting": None, "oracle": True})
    env.close()
    return rows


def bound_paragraph(bound: dict, best: dict, learned: list[dict], spec: dict) -> str:
    """What a bound row rules out, in numbers, for a metric where lower is better: the margins against the best
    scripted rule ``best`` that no policy can reach, and how far the learned points that are not worse than
    ``best`` (beyond the intervals) sit from the bound. A row with ``bits_bound`` False bounds the metric only; an
    ``oracle`` row is no bound at all (:func:`oracle_paragraph`)."""
    if bound.get("oracle"):
        return oracle_paragraph(bound, best, learned, spec)
    metric, per = spec["metric"], spec.get("bits_per", "step")
    target = best["metric"] * (1.0 - METRIC_MARGIN)
    fewer_bits = best["bits"] * (1.0 - BITS_MARGIN)
    faster = "impossible" if bound["metric"] > target else "not ruled out"
    if not bound.get("bits_bound", True):
        return (
            f"**Bound** (on the same held-out episodes): no policy reaches a {metric} below {bound['metric']:.4g}; "
            f"it bounds the {metric} only, not the bits. Beating `{best['policy']}` ({best['metric']:.4g} at "
            f"{best['bits']:.4g} bits) by 10 % needs a {metric} of at most {target:.4g} at no more than "
            f"{best['bits'] * (1 + BITS_SLACK):.4g} bits ({faster}), and 20 % fewer bits, at most {fewer_bits:.4g} "
            f"bits at {best['metric']:.4g} (not ruled out: the bound says nothing of bits)."
        )
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


def oracle_paragraph(reference: dict, best: dict, learned: list[dict], spec: dict) -> str:
    """What a reference row with knowledge the learned policy lacks shows, for a metric where lower is better: whether
    it reaches #42's 10 % margin over ``best`` within its bits, and how much of the gap to it the best learned point
    within those bits has closed."""
    metric, per = spec["metric"], spec.get("bits_per", "step")
    name = reference["policy"].split(":")[0]
    target = best["metric"] * (1.0 - METRIC_MARGIN)
    slack_bits = best["bits"] * (1 + BITS_SLACK)
    reaches = reference["metric"] <= target and reference["bits"] <= slack_bits
    text = (
        f"**Reference `{name}`** (not a bound, on the same held-out episodes): a {metric} of "
        f"{reference['metric']:.4g} at {reference['bits']:.4g} bits per agent per {per}, "
        f"{100 * (1 - reference['metric'] / best['metric']):.1f} % below `{best['policy']}`'s {best['metric']:.4g} at "
        f"{best['bits']:.4g} bits. #42's 10 % margin ({target:.4g} at no more than {slack_bits:.4g} bits) is "
        + (
            f"reachable with `{name}`'s knowledge, which the learned policy's observation does not give."
            if reaches
            else f"not reached by `{name}` either."
        )
    )
    budget = [r for r in learned if r["bits"] <= slack_bits]
    if budget and reference["metric"] < best["metric"]:
        top = min(budget, key=lambda r: r["metric"])
        closed = (best["metric"] - top["metric"]) / (best["metric"] - reference["metric"])
        where = (
            f"{100 * closed:.0f} % of the way from `{best['policy']}` to `{name}`"
            if closed >= 0
            else f"not below `{best['policy']}`'s {best['metric']:.4g}"
        )
        text += (
            f" The best learned point within those bits ({spec['cost_param']} = {top['cost']:g}) reaches "
            f"{top['metric']:.4g}: {where}."
        )
    return text


#: env id → the function giving its bound rows (env id, the comparison's env arguments, its held-out seeds, its spec)
BOUNDS: dict[str, Callable[[str, dict, list[int], dict], list[dict]]] = {
    "mrcomm/AsyncCL-v0": asynccl_bound,
    "mrcomm/ChannelAssociation-v0": channel_association_bound,
    "mrcomm/MultiHop-v0": multihop_bound,
}


def bound_rows(env_id: str, spec: dict, seeds: list[int]) -> list[dict]:
    """The env's bound rows on the comparison's held-out ``seeds`` (none for an env without a bound)."""
    bound = BOUNDS.get(env_id)
    if bound is None:
        return []
    env_kwargs = spec["settings"].get(spec["algo"], {}).get("env_kwargs", {})
    return bound(env_id, env_kwargs, seeds, spec)
