"""``mrcomm actions``: a policy's choices beside the rules asked at the states it reaches."""

from __future__ import annotations

import json
import shlex

import numpy as np
import pytest

from mrcomm_baselines import default_policy, make_policy
from mrcomm_env.experiments import actions as actions_module
from mrcomm_env.experiments.actions import ActionProfile, context_table, profile_actions, profile_table
from mrcomm_env.experiments.arguments import parse_params, rule_argument, split_values
from mrcomm_env.experiments.cli import main
from mrcomm_env.experiments.evaluation import run_episode
from mrcomm_env.experiments.learning_report import actions_paragraph
from mrcomm_env.registry import env_ids, make

MAPSYNC = "mrcomm/MapSync-v0"
MULTIHOP = "mrcomm/MultiHop-v0"
SMALL_MULTIHOP = {"grid_side": 3, "max_cycles": 8}


class Recording:
    """A policy that plays ``inner`` and keeps every action it returned, to compare two runs of one episode."""

    def __init__(self, inner):
        self.inner, self.taken = inner, []

    def reset(self, views, seed):
        self.inner.reset(views, seed)

    def act(self, observations, views):
        actions = self.inner.act(observations, views)
        self.taken.append({agent: np.asarray(a).tolist() for agent, a in actions.items()})
        return actions


def test_asking_rules_does_not_change_the_episode_the_policy_plays():
    # the `random` rule draws from its own generator at every state: if asking it touched the env or the
    # policy, the policy's actions (the age-aware rule's choices on what the env shows it) would differ
    alone, shadowed = Recording(make_policy(MULTIHOP, "age_aware")), Recording(make_policy(MULTIHOP, "age_aware"))
    env = make(MULTIHOP, **SMALL_MULTIHOP)
    run_episode(env, alone, seed=3)
    rules = {"random": make_policy(MULTIHOP, "random"), "flooding": make_policy(MULTIHOP, "flooding")}
    profile_actions(MULTIHOP, SMALL_MULTIHOP, shadowed, rules, [3])
    assert shadowed.taken == alone.taken and len(alone.taken) == SMALL_MULTIHOP["max_cycles"]


def test_a_rule_asked_beside_itself_agrees_everywhere_and_counts_every_decision():
    rules = {"age_aware": make_policy(MULTIHOP, "age_aware"), "no_hop": make_policy(MULTIHOP, "no_hop")}
    profile = profile_actions(MULTIHOP, SMALL_MULTIHOP, make_policy(MULTIHOP, "age_aware"), rules, [0, 1])
    robots = SMALL_MULTIHOP["grid_side"] ** 2
    assert profile.decisions == 2 * robots * SMALL_MULTIHOP["max_cycles"]  # every robot decides every frame
    for who in ("learned", "age_aware", "no_hop"):
        assert sum(profile.counts[who].values()) == profile.decisions
    assert profile.agreement("age_aware") == 1.0 and profile.item_overlap("age_aware") == 1.0
    assert profile.mean_place("learned") == profile.mean_place("age_aware")
    assert 1.0 <= profile.mean_place("age_aware") <= robots - 1
    # no_hop sends only the robot's own estimate: it selects no candidate, so no place and no agreement
    assert profile.mean_place("no_hop") is None and profile.share("no_hop", "0 selected") == 1.0
    assert profile.item_overlap("no_hop") is None and profile.agreement("no_hop") == profile.share(
        "learned", "0 selected"
    )
    assert profile.counts["learned"] == profile.counts["age_aware"]
    # select bits: each label counts the selected candidates, at most one per other robot
    assert all(0 <= int(label.split()[0]) <= robots - 1 for label in profile.labels)
    assert [int(label.split()[0]) for label in profile.labels] == sorted(int(x.split()[0]) for x in profile.labels)


def test_agreeing_with_a_rule_that_never_syncs_is_idling():
    # `never` idles at every state, so the policy chose as it would exactly where the policy idled
    rules = {"never": make_policy(MAPSYNC, "never")}
    policy = make_policy(MAPSYNC, "periodic_sketch", period=2)
    profile = profile_actions(MAPSYNC, {"max_cycles": 12}, policy, rules, [0, 1, 2], policy_name="every other")
    assert profile.share("never", "idle") == 1.0
    assert profile.agreement("never") == pytest.approx(profile.share("every other", "idle"))
    assert 0.0 < profile.share("every other", "sketch") < 1.0
    assert profile.labels == ["idle", "sketch"]  # the env's action order, only those chosen
    assert not profile.shared_items  # discrete actions have no items to share


def test_every_env_names_its_actions():
    asynccl = make("mrcomm/AsyncCL-v0")
    assert [asynccl.action_label(a) for a in range(len(asynccl.mode_names))] == list(asynccl.mode_names)
    mapsync = make(MAPSYNC)
    assert [mapsync.action_label(a) for a in range(5)] == ["idle", "equality", "bisection", "full", "sketch"]
    assert [make("mrcomm/ChannelAssociation-v0").action_label(a) for a in (0, 1)] == ["silent", "emit"]
    rendezvous = make("mrcomm/RendezvousMapping-v0")
    k = rendezvous.K
    labels = [rendezvous.action_label(a) for a in range(k + 2)]
    assert labels[0] == "first candidate (recommended)" and set(labels[1:k]) == {"other candidate"}
    assert labels[k:] == ["rendezvous", "hold"]
    relative, absolute = make(MULTIHOP), make(MULTIHOP, layout="absolute")
    assert relative.action_label(np.array([1, 0, 1] + [0] * 32)) == "2 selected"
    # absolute layout: 0 withholds, any positive priority selects
    assert absolute.action_label(np.array([0.0, 0.2, 0.9] + [0.0] * 33)) == "2 selected"


def test_the_table_gives_each_action_share_and_the_agreement_row():
    profile = ActionProfile(
        policy="learned",
        rules=["rule"],
        seeds=[7],
        labels=["idle", "sketch"],
        decisions=4,
        counts={"learned": {"idle": 3, "sketch": 1}, "rule": {"sketch": 4}},
        same={"rule": 1},
    )
    table = profile_table(profile)
    assert table[2] == "| idle | 75.0 % | 0.0 % |"
    assert table[3] == "| sketch | 25.0 % | 100.0 % |"
    assert table[-1] == "| the same action as `learned` | — | 25.0 % |"  # discrete actions: no item rows
    assert ActionProfile.from_json(json.loads(json.dumps(profile.to_json()))) == profile


def test_the_learning_page_renders_the_recorded_profile_with_the_command_that_makes_it(tmp_path):
    env_id = MAPSYNC
    (tmp_path / "learning").mkdir()
    against = [["periodic_sketch", {"period": 1}]]
    assert actions_paragraph(env_id, tmp_path, against) == []  # nothing recorded: nothing said
    profile = profile_actions(
        env_id,
        {"max_cycles": 6},
        make_policy(env_id, "never"),
        {"periodic_sketch period=1": make_policy(env_id, "periodic_sketch", period=1)},
        [10000, 10001],
    )
    (tmp_path / "learning" / "MapSync-v0-actions.json").write_text(json.dumps(profile.to_json()))
    lines = actions_paragraph(env_id, tmp_path, against)
    text = "\n".join(lines)
    assert "--against periodic_sketch:period=1 --episodes 2 --seed 10000" in text
    assert f"({profile.decisions:,} decisions)" in text
    table, by_situation = profile_table(profile), context_table(profile)
    assert by_situation and lines[-len(by_situation) :] == by_situation  # MapSync names its robots' situations
    start = lines.index(table[0])
    assert lines[start : start + len(table)] == table


def test_a_recorded_profile_of_other_rules_than_the_config_names_is_refused(tmp_path):
    (tmp_path / "learning").mkdir()
    profile = ActionProfile(policy="learned", rules=["periodic_sketch period=2"], seeds=[0], decisions=0)
    (tmp_path / "learning" / "MapSync-v0-actions.json").write_text(json.dumps(profile.to_json()))
    with pytest.raises(ValueError, match="rerun `mrcomm reproduce-learning`"):
        actions_paragraph(MAPSYNC, tmp_path, [["periodic_sketch", {"period": 1}]])


@pytest.mark.parametrize(
    "params",
    [
        {},
        {"period": 1},
        {"period": 2, "mode": "sketch"},
        {"weights": [0.5, 0.25], "label": "a b, c"},
        {"label": 'say "hi", then \\ go', "on": True},
    ],
)
def test_a_rules_argument_reads_back_as_its_parameters(params):
    # what the learning page prints for a rule must be what `mrcomm actions --against` parses back: commas inside
    # a list value and spaces inside a text value included
    text = rule_argument("some_rule", params)
    (shell_word,) = shlex.split(shlex.quote(text))  # as the page quotes it for a shell
    name, _, rest = shell_word.partition(":")
    assert name == "some_rule"
    assert parse_params([pair for pair in split_values(rest) if pair], "--against") == params


def test_the_command_prints_the_table_and_writes_the_json(tmp_path, capsys):
    path = tmp_path / "actions.json"
    argv = ["actions", "MapSync-v0", "--policy", "periodic_sketch", "--against", "periodic_sketch:period=1"]
    argv += ["--against", "never", "--episodes", "2", "--param", "max_cycles=10", "--json", str(path)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "| action | `periodic_sketch` | `periodic_sketch period=1` | `never` |" in out
    record = json.loads(path.read_text())
    assert record["env"] == MAPSYNC and record["seeds"] == [0, 1] and record["params"] == {"max_cycles": 10}
    profile = ActionProfile.from_json(record)
    assert profile.rules == ["periodic_sketch period=1", "never"]
    # the paper's period (10) sketches once in 10 moves, at step 10 only: never within steps 0-9
    assert profile.share("periodic_sketch", "idle") == 1.0 and profile.agreement("never") == 1.0


@pytest.mark.parametrize(
    ("against", "message"),
    [
        ("no_such_rule", "valid policies are"),
        ("periodic_sketch:bogus=1", "bogus"),
        ("periodic_sketch:period", "key=value"),
    ],
)
def test_a_bad_rule_is_one_line_before_any_episode(against, message, capsys, monkeypatch):
    def forbidden(*args, **kwargs):
        raise AssertionError("the work started before the bad input was reported")

    monkeypatch.setattr(actions_module, "run_episode", forbidden)
    argv = ["actions", "MapSync-v0", "--policy", "never", "--against", against, "--episodes", "1"]
    assert main(argv) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and message in err[0]


def test_every_env_can_be_profiled_against_its_default_rule():
    for env_id in env_ids():
        rule = default_policy(env_id)
        profile = profile_actions(
            env_id, {"max_cycles": 3}, make_policy(env_id, rule), {rule: make_policy(env_id, rule)}, [0]
        )
        assert profile.decisions > 0 and profile.agreement(rule) == 1.0, env_id


def test_the_situations_split_every_decision_and_every_agreement():
    rules = {"never": make_policy(MAPSYNC, "never"), "sketch": make_policy(MAPSYNC, "periodic_sketch", period=1)}
    policy = make_policy(MAPSYNC, "periodic_sketch", period=3)
    profile = profile_actions(MAPSYNC, {"max_cycles": 40}, policy, rules, [0, 1, 2], policy_name="every third")
    assert sum(profile.context_decisions(c) for c in profile.by_context) == profile.decisions
    for who in ("every third", "never", "sketch"):
        for label in profile.labels:
            assert sum(profile.by_context[c][who].get(label, 0) for c in profile.by_context) == profile.counts[who].get(
                label, 0
            )
    for rule in rules:
        assert sum(profile.same_by_context[c][rule] for c in profile.by_context) == profile.same[rule]
    assert "own sensing changed cells" in profile.by_context  # robots explore: their sensing changes cells


def test_mapsync_news_stays_news_until_a_sync():
    # without a sync a robot's own changed cells are never reconciled: once it has news for its peer, it keeps it
    env = make(MAPSYNC, max_cycles=40)
    env.reset(seed=4)
    had_news = np.zeros(env.n_agents, dtype=bool)
    while env.agents:
        context = np.array(env.decision_context())
        assert not (had_news & (context == "no news")).any()
        had_news |= context == "own sensing changed cells"
        env.step(dict.fromkeys(env.agents, 0))  # idle
    assert had_news.any()


def test_asynccl_situation_is_whether_the_coming_exchange_has_a_link():
    # the infos' `neighbours` after a step count the links of the exchange the next actions choose a mode for
    env = make("mrcomm/AsyncCL-v0", max_cycles=30, link_model="bernoulli", link_probability=0.1)
    _, infos = env.reset(seed=2)
    seen = set()
    while env.agents:
        context = env.decision_context()
        for i, agent in enumerate(env.agents):
            assert context[i] == ("no robot in reach" if infos[agent]["neighbours"] == 0 else "robots in reach")
            seen.add(context[i])
        _, _, _, _, infos = env.step(dict.fromkeys(env.agents, 0))
    assert seen == {"no robot in reach", "robots in reach"}


def test_rendezvous_situation_is_the_share_of_the_team_in_the_vehicles_group():
    env = make("mrcomm/RendezvousMapping-v0", max_cycles=20, d_comms=10.0)
    env.reset(seed=1)
    views = env.local_views()
    seen = set()
    while env.agents:
        sizes = views.team("group").sum(axis=1)
        expected = [
            "alone" if k == 1 else "with the whole team" if k == env.n_agents else "with part of the team"
            for k in sizes
        ]
        assert env.decision_context() == expected
        seen.update(expected)
        env.step(dict.fromkeys(env.agents, env.K))  # everyone calls a rendezvous
    assert seen


def test_a_learned_policy_can_be_the_rule_it_is_compared_with(tmp_path, capsys):
    # ALGO:RUN and pretrained name learned policies, whose names hold no rule parameters after a colon
    path = tmp_path / "actions.json"
    argv = ["actions", "MapSync-v0", "--policy", "pretrained", "--against", "pretrained", "--episodes", "1"]
    assert main([*argv, "--param", "max_cycles=20", "--json", str(path)]) == 0
    profile = ActionProfile.from_json(json.loads(path.read_text()))
    assert profile.rules == ["pretrained"] and profile.agreement("pretrained") == 1.0
    assert profile.policy == "pretrained (acting)"  # a name of its own: the two are counted apart
    assert sum(profile.counts["pretrained (acting)"].values()) == sum(profile.counts["pretrained"].values())
    assert sum(profile.counts["pretrained"].values()) == profile.decisions
    with pytest.raises(ValueError, match="also a rule's"):
        profile_actions(
            MAPSYNC, {}, make_policy(MAPSYNC, "never"), {"never": make_policy(MAPSYNC, "never")}, [0], "never"
        )


class Dark:
    """Never emits: a ChannelAssociation field is then never done, and every episode runs to its horizon."""

    def reset(self, views, seed):
        pass

    def act(self, observations, views):
        return dict.fromkeys(observations, 0)


def test_channel_association_situation_is_the_phase_the_id_bits_code_follows():
    # 9 robots: ⌈log2 9⌉ = 4 address bits and a beacon, a clock of 5 phases; 12 steps hold phases 0-4, 0-4, 0-1.
    # `id_bits` sends bit p of its address at phase p and blinks at every beacon
    env_id = "mrcomm/ChannelAssociation-v0"
    rules = {"id_bits": make_policy(env_id, "id_bits")}
    profile = profile_actions(env_id, {"n_robots": 9, "max_cycles": 12}, Dark(), rules, [0, 1])
    decisions = {c: profile.context_decisions(c) for c in profile.by_context}
    per_step = 9 * 2  # robots × episodes
    assert decisions == {
        "bit phase 0": 3 * per_step,
        "bit phase 1": 3 * per_step,
        "bit phase 2": 2 * per_step,
        "bit phase 3": 2 * per_step,
        "beacon phase": 2 * per_step,
    }
    assert profile.context_share("beacon phase", "id_bits", "emit") == 1.0
    assert profile.context_share("bit phase 0", "id_bits", "emit") < 1.0  # some addresses have a 0 there


def test_multihop_measures_the_age_and_the_need_of_every_held_estimate_a_slot_would_relay():
    env = make(MULTIHOP, grid_side=3, max_cycles=8, layout="absolute")
    env.reset(seed=0)
    assert list(np.flatnonzero(env.adj[0])) == [1, 3]  # robot 0 in the corner of the 3 × 3 grid
    # a hand-made state at t = 10 s: robot 0 holds 5 (stamp 2) as fresh as both its neighbours do, holds 7
    # (stamp 3) fresher than neighbour 3 (stamp 1), holds 1 (stamp 4), which neighbour 1 keeps current itself
    # but neighbour 3 lacks, and does not hold 8
    env.t = 10.0
    env.stamps[0, [5, 7, 1, 8]] = [2.0, 3.0, 4.0, -np.inf]
    env.stamps[1, [5, 7]] = [2.0, 3.0]
    env.stamps[3, [5, 7, 1]] = [6.0, 1.0, -np.inf]
    priorities = np.zeros(9)
    priorities[[0, 5, 7, 1, 8]] = [0.9, 0.5, 0.4, 0.3, 0.2]  # its own estimate is always sent: not an item
    measures = env.action_measures("robot_0", priorities)
    ages, needless = measures["age of a selected estimate (s)"], measures["selected estimates no neighbour lacks"]
    # items in robot order (1, 5, 7); 8 is not held, so no slot can relay it
    assert ages.tolist() == [6.0, 8.0, 7.0]
    assert needless.tolist() == [False, True, False]
    assert all(len(v) == 0 for v in env.action_measures("robot_0", np.zeros(9)).values())  # withholds all


def test_multihop_relative_bits_measure_the_candidates_the_views_rank():
    env = make(MULTIHOP, **SMALL_MULTIHOP)
    observations, _ = env.reset(seed=4)
    policy = make_policy(MULTIHOP, "flooding")
    views = env.local_views()
    policy.reset(views, 4)
    for _ in range(3):  # let estimates spread, so that robots hold some and lack others
        observations, *_ = env.step(policy.act(observations, views))
    candidates, stamps = views.team("candidates"), views.team("stamps")
    bits = np.zeros(env.n_agents - 1)
    bits[::2] = 1  # every other candidate, nearest first
    chosen = candidates[2][::2]
    held = chosen[stamps[2, chosen] > -np.inf]
    ages = env.action_measures("robot_2", bits)["age of a selected estimate (s)"]
    assert len(held) > 0 and np.allclose(ages, env.ages()[2, held])


def test_the_profile_averages_the_measures_over_the_items_each_chose():
    rules = {"age_aware": make_policy(MULTIHOP, "age_aware"), "no_hop": make_policy(MULTIHOP, "no_hop")}
    profile = profile_actions(MULTIHOP, SMALL_MULTIHOP, make_policy(MULTIHOP, "age_aware"), rules, [0])
    age, need = "age of a selected estimate (s)", "selected estimates no neighbour lacks"
    assert profile.share_measures == [need]
    # the policy and its own rule choose the same items at the same states; no_hop chooses none
    assert profile.measures[age]["learned"] == profile.measures[age]["age_aware"]
    assert profile.measures[age]["no_hop"] == [0.0, 0] and profile.mean_measure(age, "no_hop") is None
    # the items measured are the selected ones the robot holds
    assert 0 < profile.measures[age]["learned"][1] <= profile.selected_places["learned"][1]
    assert 0.0 <= profile.mean_measure(need, "learned") <= 1.0
    table = profile_table(profile)
    assert table[-2].startswith(f"| {age}, mean | ") and table[-2].endswith(" | — |")
    assert table[-1].startswith(f"| {need}, share | ") and table[-1].count("%") == 2
    assert ActionProfile.from_json(json.loads(json.dumps(profile.to_json()))) == profile
