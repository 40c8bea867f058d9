"""What a policy chooses, beside the rules it is compared with (``mrcomm actions``, and the action tables of
docs/learning.md).

The policy plays its episodes; at every state it reaches, each rule is asked too (the same observations and local
views), and only the policy's actions are stepped. So the rules are judged on the policy's states, not their own:
the tables say how often the policy chose as a rule would have, there. Each action is named by the env's
``action_label`` (a transfer mode, a sync protocol, a kind of Fig. 5 decision, the number of estimates selected);
where the env measures the items an action chooses (``action_measures``: MultiHop's age of each estimate a slot
would relay), their means are compared too.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields

import numpy as np
from gymnasium import spaces

from mrcomm_env.experiments.evaluation import run_episode
from mrcomm_env.registry import make


@dataclass
class ActionProfile:
    """Counts over the decisions (one per live agent and step) of ``policy`` and of each rule at the same states."""

    policy: str
    rules: list[str]
    #: the episodes' seeds
    seeds: list[int] = field(default_factory=list)
    #: action labels in table order: the env's action order for discrete actions, else by the number they start with
    labels: list[str] = field(default_factory=list)
    decisions: int = 0
    #: who (the policy or a rule) → label → decisions
    counts: dict[str, dict[str, int]] = field(default_factory=dict)
    #: rule → decisions where the policy's action equals the rule's
    same: dict[str, int] = field(default_factory=dict)
    #: multi-binary actions only: rule → [items both select, items the rule selects]
    shared_items: dict[str, list[int]] = field(default_factory=dict)
    #: multi-binary actions only: who → [sum of the selected items' places in the list (1 = first), items selected]
    selected_places: dict[str, list[int]] = field(default_factory=dict)
    #: where the env names each robot's situation (``decision_context``): situation → who → label → decisions
    by_context: dict[str, dict[str, dict[str, int]]] = field(default_factory=dict)
    #: situation → rule → decisions there where the policy's action equals the rule's
    same_by_context: dict[str, dict[str, int]] = field(default_factory=dict)
    #: where the env measures the items an action chooses (``action_measures``): measure → who → [sum, items]
    measures: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    #: the measures whose values are yes/no (their mean is a share)
    share_measures: list[str] = field(default_factory=list)

    def context_decisions(self, context: str) -> int:
        """The decisions taken in ``context``."""
        return sum(self.by_context[context][self.policy].values())

    def context_share(self, context: str, who: str, label: str) -> float:
        """The fraction of the decisions in ``context`` in which ``who`` chose an action named ``label``."""
        return self.by_context[context][who].get(label, 0) / self.context_decisions(context)

    def share(self, who: str, label: str) -> float:
        """The fraction of the decisions in which ``who`` chose an action named ``label``."""
        return self.counts[who].get(label, 0) / self.decisions if self.decisions else float("nan")

    def agreement(self, rule: str) -> float:
        """The fraction of the decisions in which the policy chose exactly what ``rule`` would have."""
        return self.same[rule] / self.decisions if self.decisions else float("nan")

    def item_overlap(self, rule: str) -> float | None:
        """Multi-binary actions: the fraction of the items ``rule`` selects that the policy selects too."""
        both, theirs = self.shared_items.get(rule, (0, 0))
        return both / theirs if rule in self.shared_items and theirs else None

    def mean_place(self, who: str) -> float | None:
        """Multi-binary actions: the mean place in the item list (1 = first) of the items ``who`` selected."""
        total, items = self.selected_places.get(who, (0, 0))
        return total / items if items else None

    def mean_measure(self, measure: str, who: str) -> float | None:
        """The mean of ``measure`` over the items ``who`` chose (None where it chose none)."""
        total, items = self.measures[measure].get(who, (0.0, 0))
        return total / items if items else None

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def from_json(cls, record: dict) -> ActionProfile:
        """The profile in ``record`` (:meth:`to_json`'s, or ``mrcomm actions --json``'s with its other keys)."""
        return cls(**{f.name: record[f.name] for f in fields(cls) if f.name in record})


class _Shadowed:
    """A policy that acts as ``policy`` and, at every state, also asks each rule and counts both in ``profile``."""

    def __init__(self, env, policy, rules: dict, profile: ActionProfile):
        self.env, self.policy, self.rules, self.profile = env, policy, rules, profile
        self.binary = isinstance(env.action_space(env.possible_agents[0]), spaces.MultiBinary)
        self.index = {agent: i for i, agent in enumerate(env.possible_agents)}  # decision_context's rows

    def reset(self, views, seed) -> None:
        self.policy.reset(views, seed)
        for rule in self.rules.values():
            rule.reset(views, seed)

    def act(self, observations: dict, views) -> dict:
        contexts = self.env.decision_context()  # the state the actions are chosen in, before it steps
        actions = self.policy.act(observations, views)
        asked = {name: rule.act(observations, views) for name, rule in self.rules.items()}
        p, label = self.profile, self.env.action_label
        for agent in observations:
            mine = np.asarray(actions[agent])
            counts = [p.counts]
            same = [p.same]
            if contexts is not None:
                context = contexts[self.index[agent]]
                if context not in p.by_context:
                    p.by_context[context] = {who: {} for who in p.counts}
                    p.same_by_context[context] = dict.fromkeys(self.rules, 0)
                counts.append(p.by_context[context])
                same.append(p.same_by_context[context])
            p.decisions += 1
            for table in counts:
                _count(table, p.policy, label(mine))
            self._measure(p.policy, agent, mine)
            if self.binary:
                _add_places(p.selected_places[p.policy], mine > 0.5)
            for name, theirs in asked.items():
                theirs_a = np.asarray(theirs[agent])
                if self.binary:  # select bits: what is selected is what counts
                    mine_b, theirs_b = mine > 0.5, theirs_a > 0.5
                    agrees = bool(np.array_equal(mine_b, theirs_b))
                    p.shared_items[name][0] += int(np.count_nonzero(mine_b & theirs_b))
                    p.shared_items[name][1] += int(np.count_nonzero(theirs_b))
                    _add_places(p.selected_places[name], theirs_b)
                else:
                    agrees = bool(np.array_equal(mine, theirs_a))
                for table, tally in zip(counts, same):
                    _count(table, name, label(theirs_a))
                    tally[name] += agrees
                self._measure(name, agent, theirs_a)
        return actions

    def _measure(self, who: str, agent: str, action: np.ndarray) -> None:
        p = self.profile
        for measure, values in self.env.action_measures(agent, action).items():
            values = np.asarray(values)
            if measure not in p.measures:
                p.measures[measure] = {name: [0.0, 0] for name in p.counts}
                if values.dtype == bool:
                    p.share_measures.append(measure)
            tally = p.measures[measure][who]
            tally[0] += float(values.sum())
            tally[1] += int(values.size)


def _add_places(tally: list[int], selected: np.ndarray) -> None:
    places = np.flatnonzero(selected) + 1
    tally[0] += int(places.sum())
    tally[1] += len(places)


def _count(counts: dict, who: str, label: str) -> None:
    counts[who][label] = counts[who].get(label, 0) + 1


def profile_actions(
    env_id: str, env_kwargs: dict, policy, rules: dict, seeds: list[int], policy_name: str = "learned"
) -> ActionProfile:
    """Play ``policy`` on the episodes ``seeds`` of ``env_id`` (``env_kwargs``), asking every rule of ``rules``
    (name → policy) at each state it reaches; returns the counts."""
    names = list(rules)
    if policy_name in names:
        raise ValueError(f"the acting policy's name {policy_name!r} is also a rule's; name one of them otherwise")
    env = make(env_id, **env_kwargs)
    profile = ActionProfile(policy=policy_name, rules=names, seeds=list(seeds))
    profile.counts = {policy_name: {}, **{n: {} for n in names}}
    profile.same = dict.fromkeys(names, 0)
    shadow = _Shadowed(env, policy, rules, profile)
    if shadow.binary:
        profile.shared_items = {n: [0, 0] for n in names}
        profile.selected_places = {who: [0, 0] for who in (policy_name, *names)}
    try:
        for seed in seeds:
            run_episode(env, shadow, seed)
        profile.labels = _table_order(env, profile.counts)
    finally:
        env.close()
    return profile


def _table_order(env, counts: dict[str, dict[str, int]]) -> list[str]:
    """Every label seen, in the env's action order for discrete actions; else by the number a label starts with."""
    seen = {label for per in counts.values() for label in per}
    space = env.action_space(env.possible_agents[0])
    if isinstance(space, spaces.Discrete):
        ordered = dict.fromkeys(env.action_label(a) for a in range(int(space.n)))
        return [label for label in ordered if label in seen]

    def key(label: str):
        head = label.split()[0]
        return (int(head), label) if head.isdigit() else (np.inf, label)

    return sorted(seen, key=key)


def profile_table(profile: ActionProfile) -> list[str]:
    """Markdown: the share of decisions per action, for the policy and each rule, then how often the policy chose
    what each rule would have (and, for multi-binary actions, how many of the rule's selected items it selected)."""
    who = [profile.policy, *profile.rules]
    lines = [
        "| action | " + " | ".join(f"`{w}`" for w in who) + " |",
        "| --- |" + " --- |" * len(who),
    ]
    for label in profile.labels:
        lines.append(f"| {label} | " + " | ".join(_percent(profile.share(w, label)) for w in who) + " |")
    lines.append(
        f"| the same action as `{profile.policy}` | — | "
        + " | ".join(_percent(profile.agreement(r)) for r in profile.rules)
        + " |"
    )
    if profile.shared_items:
        lines.append(
            f"| of the rule's selected items, also selected by `{profile.policy}` | — | "
            + " | ".join(_percent(profile.item_overlap(r)) for r in profile.rules)
            + " |"
        )
    if profile.selected_places:
        places = [profile.mean_place(w) for w in who]
        lines.append(
            "| mean place of a selected item in the list (1 = first) | "
            + " | ".join("—" if v is None else f"{v:.1f}" for v in places)
            + " |"
        )
    for measure in profile.measures:
        means = [profile.mean_measure(measure, w) for w in who]
        shown = _percent if measure in profile.share_measures else (lambda v: "—" if v is None else f"{v:.1f}")
        kind = "share" if measure in profile.share_measures else "mean"
        lines.append(f"| {measure}, {kind} | " + " | ".join(shown(v) for v in means) + " |")
    return lines


def context_table(profile: ActionProfile) -> list[str]:
    """Markdown: the same shares within each situation the env names (most decisions first); empty where it names
    none."""
    if not profile.by_context:
        return []
    who = [profile.policy, *profile.rules]
    lines = [
        "| situation (decisions) | action | " + " | ".join(f"`{w}`" for w in who) + " |",
        "| --- | --- |" + " --- |" * len(who),
    ]
    for context in sorted(profile.by_context, key=lambda c: (-profile.context_decisions(c), c)):
        seen = {label for per in profile.by_context[context].values() for label in per}
        head = f"{context} ({profile.context_decisions(context):,})"
        for label in (label for label in profile.labels if label in seen):
            shares = " | ".join(_percent(profile.context_share(context, w, label)) for w in who)
            lines.append(f"| {head} | {label} | {shares} |")
            head = ""
        agreement = " | ".join(
            _percent(profile.same_by_context[context][r] / profile.context_decisions(context)) for r in profile.rules
        )
        lines.append(f"|  | the same action as `{profile.policy}` | — | {agreement} |")
    return lines


def _percent(value: float | None) -> str:
    return "—" if value is None or not np.isfinite(value) else f"{100.0 * value:.1f} %"
