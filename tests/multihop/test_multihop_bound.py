"""MultiHop's bound and oracle in docs/learning.md.

The bound (slots that carry every estimate their sender holds) is checked against the env itself where the env can
play it: with a slot as large as the robot count, the ``flooding`` baseline sends every estimate it holds, so the
recursion and the env must give the same weighted age. At the comparison's slot size no policy may score below it.
The oracle is a schedule that knows every robot's table: above the bound, and better than a rule that guesses what
its neighbours hold.
"""

from __future__ import annotations

import pytest

from mrcomm_baselines import make_policy
from mrcomm_env.experiments.bounds import TableOracle, bound_paragraph, multihop_flood_ages
from mrcomm_env.experiments.comparison import comparison_row
from mrcomm_env.experiments.evaluation import run_episode
from mrcomm_env.multihop.env import MultiHopEnv

#: the comparison's setting (agents/configs/MultiHop-v0.json), fewer frames
SETTING = {"grid_side": 6, "slot_size": 4, "max_cycles": 20}


@pytest.mark.parametrize("seed", [3, 11])
def test_the_flood_recursion_is_the_env_when_a_slot_holds_every_estimate(seed):
    env = MultiHopEnv(grid_side=4, slot_size=16, max_cycles=15)
    metrics = run_episode(env, make_policy("mrcomm/MultiHop-v0", "flooding"), seed)
    env.reset(seed=seed)
    assert multihop_flood_ages(env, 15) == pytest.approx(metrics["weighted_mean_age"], rel=1e-12)


@pytest.mark.parametrize("name", ["age_aware", "location_based", "flooding", "no_hop", "random"])
def test_no_policy_scores_below_the_flood_bound(name):
    env = MultiHopEnv(**SETTING)
    for seed in (0, 7):
        metrics = run_episode(env, make_policy("mrcomm/MultiHop-v0", name), seed)
        env.reset(seed=seed)
        bound = multihop_flood_ages(env, SETTING["max_cycles"])
        # the same sums in the same order where a schedule matches the flood; any slack is the policy's
        assert metrics["weighted_mean_age"] >= bound * (1 - 1e-12)


def test_the_oracle_beats_age_aware_by_knowing_the_tables():
    env = MultiHopEnv(**SETTING)
    oracle = run_episode(env, TableOracle(env), 2)
    assert env.ledger.total_bits.max() <= SETTING["max_cycles"] * env.m * env.cfg.bits_per_estimate  # its slots' room
    age_aware = run_episode(env, make_policy("mrcomm/MultiHop-v0", "age_aware"), 2)
    env.reset(seed=2)
    bound = multihop_flood_ages(env, SETTING["max_cycles"])
    assert bound <= oracle["weighted_mean_age"] < age_aware["weighted_mean_age"]


def test_the_oracle_refuses_a_layout_it_cannot_speak():
    with pytest.raises(ValueError, match="relative"):
        TableOracle(MultiHopEnv(grid_side=4, slot_size=3, layout="absolute"))


def test_paragraphs_say_what_a_metric_bound_and_an_oracle_show():
    spec = {"metric": "weighted_mean_age", "bits_per": "step", "cost_param": "lam"}
    best = {**comparison_row("age_aware", None, [46.0] * 4, [760.0] * 4, 4), "setting": None}
    bound = {**comparison_row("bound", None, [12.0] * 4, [6912.0] * 4, 4), "bits_bound": False}
    text = bound_paragraph(bound, best, [], spec)
    assert "bounds the weighted_mean_age only" in text and "(not ruled out)" in text
    assert "6912" not in text  # its bits are not a bound, so the paragraph does not quote them
    learned = [{**comparison_row("ppo", 0.0, [44.0] * 4, [760.0] * 4, 4), "cost": 0.0}]
    oracle = {**comparison_row("oracle: knows", None, [31.0] * 4, [762.0] * 4, 4), "oracle": True}
    text = bound_paragraph(oracle, best, learned, spec)
    assert "reachable with `oracle`'s knowledge" in text
    assert "13 % of the way" in text  # (46 - 44) / (46 - 31)
    behind = [{**learned[0], "metric": 47.0}]  # worse than age_aware: no share of the way, and no negative one
    text = bound_paragraph(oracle, best, behind, spec)
    assert "reaches 47: not below `age_aware`'s 46" in text and "of the way" not in text
    slow = {**oracle, "metric": 43.0}
    assert "not reached by `oracle` either" in bound_paragraph(slow, best, learned, spec)
    costly = {**oracle, "bits": 900.0}
    assert "not reached by `oracle` either" in bound_paragraph(costly, best, learned, spec)
