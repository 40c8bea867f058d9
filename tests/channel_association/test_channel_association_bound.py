"""The fewest emissions of any policy (``theory.fewest_emissions``) and the bound it gives docs/learning.md.

Expected values come from counting: with one observer, the cheapest codes are the cheapest distinct t-bit patterns
(sorted popcounts), and in any layout the program's code must finish the episode when played, and lose that when
two robots that must differ share a pattern.
"""

from __future__ import annotations

import numpy as np
import pytest

from mrcomm_baselines import make_policy
from mrcomm_env.channel_association.env import ChannelAssociationEnv
from mrcomm_env.channel_association.theory import fewest_emissions
from mrcomm_env.experiments.bounds import PatternPlayer, bound_paragraph, bound_rows, fewest_steps_code
from mrcomm_env.experiments.comparison import comparison_row
from mrcomm_env.experiments.evaluation import evaluate_policy, run_episode
from mrcomm_env.experiments.runs import comparison_spec

#: the comparison's field: 25 stationary robots (agents/configs/ChannelAssociation-v0.json)
FIELD = {"n_robots": 25, "mobile_fraction": 0.0, "max_cycles": 40}


def cheapest_patterns(count: int, steps: int, skip: int = 0) -> int:
    """Emissions of the ``count`` cheapest distinct ``steps``-bit patterns after the ``skip`` cheapest."""
    popcounts = sorted(bin(c).count("1") for c in range(1 << steps))
    return sum(popcounts[skip : skip + count])


def play(env, seed: int, patterns: np.ndarray) -> dict:
    player = PatternPlayer()
    player.patterns = patterns
    return run_episode(env, player, seed)


@pytest.mark.parametrize(("w", "v", "steps"), [(8, 8, 3), (8, 6, 3), (8, 6, 4), (12, 12, 4), (30, 20, 5)])
def test_one_observer_needs_its_cheapest_distinct_patterns(w, v, steps):
    # the observer sees v robots and hears w: the v visible ones need distinct patterns, and the w − v heard only
    # must each differ from all of them, which they do most cheaply by all staying silent together
    env = ChannelAssociationEnv(scene="neighborhood", w=w, v=v, max_cycles=steps + 2)
    env.reset(seed=3)
    emissions, patterns = fewest_emissions(env.tracked_robots(), env.n_agents, steps)
    expected = cheapest_patterns(v, steps) if v == w else cheapest_patterns(v, steps, skip=1)
    assert emissions == expected == patterns.sum()
    metrics = play(env, 3, patterns)
    assert metrics["completion_time"] <= steps and metrics["messages_sent"] == emissions


@pytest.mark.parametrize(("w", "v", "steps"), [(8, 8, 2), (8, 7, 2), (17, 16, 4), (16, 16, 3)])
def test_too_few_steps_have_no_code(w, v, steps):
    # more robots must differ pairwise (v, or v + 1 with a robot heard only) than 2^steps patterns
    env = ChannelAssociationEnv(scene="neighborhood", w=w, v=v, max_cycles=8)
    env.reset(seed=0)
    assert fewest_emissions(env.tracked_robots(), env.n_agents, steps) is None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_program_code_finishes_the_field_and_a_shared_pattern_does_not(seed):
    env = ChannelAssociationEnv(**FIELD)
    env.reset(seed=seed)
    tracked = env.tracked_robots()
    steps, patterns = fewest_steps_code(env)
    largest = max(len(visual) for _, _, visual in tracked)
    assert 2 ** (steps - 1) < largest <= 2**steps  # the clique of one observer sets the time
    assert fewest_emissions(tracked, env.n_agents, steps - 1) is None
    metrics = play(env, seed, patterns)
    assert metrics["completion_time"] == steps
    assert metrics["messages_sent"] == patterns.sum()
    # no cheaper than the cheapest distinct patterns of the largest group, which must all differ
    assert patterns.sum() >= cheapest_patterns(largest, steps)
    # copy one robot's pattern onto another robot that the same observer sees: that observer cannot tell them apart
    _, _, visual = max(tracked, key=lambda t: len(t[2]))
    shared = patterns.copy()
    shared[visual[1]] = shared[visual[0]]
    env.reset(seed=seed)
    assert play(env, seed, shared)["completion_time"] == -1  # not finished by the episode's end


def test_the_bound_is_below_id_bits_on_the_comparisons_episodes():
    spec = comparison_spec("mrcomm/ChannelAssociation-v0")
    seeds = [10_000, 10_001, 10_002]
    (bound,) = bound_rows("mrcomm/ChannelAssociation-v0", spec, seeds)
    id_bits = evaluate_policy(
        "mrcomm/ChannelAssociation-v0", FIELD, make_policy("mrcomm/ChannelAssociation-v0", "id_bits"), seeds, spec
    )
    assert bound["metric"] <= np.mean(id_bits["metric"])
    assert bound["bits"] <= np.mean(id_bits["bits"])
    assert bound["bound"] and bound["n"] == len(seeds)


def test_the_bound_paragraph_says_what_the_bound_rules_out():
    spec = {"metric": "completion_time", "bits_per": "episode", "cost_param": "emission_cost"}
    best = {**comparison_row("id_bits", None, [5.0] * 4, [13.0] * 4, 4), "setting": None}
    bound = {**comparison_row("bound", None, [5.0] * 4, [12.0] * 4, 4), "setting": None}
    learned = [{**comparison_row("learned", 0.1, [5.0] * 4, [12.6] * 4, 4), "setting": 0.1}]
    text = bound_paragraph(bound, best, learned, spec)
    assert "at most 4.5 at no more than 13.65 bits (impossible)" in text
    assert "at most 10.4 bits at 5 (impossible)" in text
    assert "5.0 % above the bound" in text  # 12.6 / 12 − 1
    # a bound that leaves room for 20 % fewer bits does not claim otherwise
    cheap = {**bound, "bits": 10.0}
    assert "at most 10.4 bits at 5 (not ruled out)" in bound_paragraph(cheap, best, learned, spec)
