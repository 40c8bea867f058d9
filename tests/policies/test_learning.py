"""The learned-vs-scripted comparison (``mrcomm reproduce-learning``) and the shipped pretrained models."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from mrcomm_agents.learned import PRETRAINED_DIR, load_policy
from mrcomm_agents.training import CONFIG_DIR
from mrcomm_env.experiments import comparison
from mrcomm_env.experiments.cli import main
from mrcomm_env.registry import env_ids, env_revision, short_name

torch.set_num_threads(1)


def point(metric, bits, metric_ci=0.0, bits_ci=0.0, cost=None):
    return {"metric": metric, "metric_ci95": metric_ci, "bits": bits, "bits_ci95": bits_ci, "cost": cost}


@pytest.mark.parametrize(
    "learned,baseline,lower,expected",
    [
        (point(5.0, 10.0), point(6.0, 10.0), True, True),  # better at equal bits
        (point(5.0, 12.0), point(6.0, 10.0), True, False),  # better, but 20 % more bits
        (point(5.0, 10.4), point(6.0, 10.0), True, True),  # within the 5 % bit slack
        (point(7.0, 8.0, 0.5), point(6.0, 10.0, 0.4), True, False),  # worse beyond both intervals
        (point(6.5, 8.0, 0.5), point(6.0, 10.0, 0.4), True, True),  # worse, but within the intervals
        (point(0.9, 1.0), point(0.8, 1.0), False, True),  # higher is better
    ],
)
def test_dominates_means_no_more_bits_and_no_worse_metric(learned, baseline, lower, expected):
    assert comparison.dominates(learned, baseline, lower) is expected


@pytest.mark.parametrize(
    "learned,baseline,expected",
    [
        (point(5.0, 10.0, 0.3), point(6.0, 10.0, 0.3), True),  # better beyond both intervals
        (point(5.8, 10.0, 0.3), point(6.0, 10.0, 0.3), False),  # better, but within the intervals
        (point(6.0, 5.0, 0.3, 0.5), point(6.0, 10.0, 0.3, 0.5), True),  # same metric, clearly fewer bits
        (point(6.0, 9.5, 0.3, 0.5), point(6.0, 10.0, 0.3, 0.5), False),  # fewer bits, within the intervals
        (point(7.0, 5.0, 0.3), point(6.0, 10.0, 0.3), False),  # fewer bits but a worse metric
        # 2 % fewer bits, beyond tiny bit intervals, and a worse mean within wide metric intervals: a match only
        (point(15.3, 60142, 5.9, 171), point(12.4, 61466, 1.1, 537), False),
    ],
)
def test_beats_needs_a_margin_beyond_the_intervals(learned, baseline, expected):
    assert comparison.beats(learned, baseline, lower_is_better=True) is expected


@pytest.mark.parametrize(
    "learned,baseline,lower,expected",
    [
        # 40 ± 1 against 50 ± 2: at the worse ends 41 against 48, 1 − 41/48 ahead on the metric; bits equal at the
        # worse ends (100 against 100) count only with the metric not worse, which it is not (it is better)
        (point(40.0, 100.0, 1.0), point(50.0, 100.0, 2.0), True, (1 - 41 / 48, 0.0)),
        # 6 % more bits than the baseline: no metric margin, whatever the metric
        (point(40.0, 106.0, 1.0), point(50.0, 100.0, 2.0), True, (None, -0.06)),
        # a metric worse beyond the intervals earns no bits margin, however few the bits
        (point(60.0, 10.0, 1.0), point(50.0, 100.0, 2.0), True, (1 - 61 / 48, None)),
        # the same metric with 40 ± 5 bits against 100 ± 10: (40 + 5) against (100 − 10) at the worse ends
        (point(50.0, 40.0, 0.0, 5.0), point(50.0, 100.0, 0.0, 10.0), True, (0.0, 1 - 45 / 90)),
        # intervals that overlap (25 ≤ 28) but a learned figure of 30, beyond the baseline's worse end of 24 + 4:
        # worse, so no bits margin however few its bits; the metric margin 1 − 35/20 is negative
        (point(30.0, 30.0, 5.0), point(24.0, 60.0, 4.0), True, (1 - 35 / 20, None)),
        # the same figure just inside the baseline's interval (27.9 ≤ 28): not worse, 30 bits against 60
        (point(27.9, 30.0, 3.1), point(24.0, 60.0, 4.0), True, (1 - 31 / 20, 1 - 30 / 60)),
        # over training seeds the figure is the IQM, as its interval is: a mean of 26 inside the baseline's interval,
        # but an IQM of 29 beyond its worse end, is worse
        (
            {**point(26.0, 30.0, 6.0), "n": 5, "metric_iqm": 29.0, "metric_iqm_low": 25.0, "metric_iqm_high": 33.0},
            point(24.0, 60.0, 4.0),
            True,
            (1 - 33 / 20, None),
        ),
        # higher is better: 0.9 ± 0.05 against 0.8 ± 0.0, 0.85 / 0.8 − 1 ahead
        (point(0.9, 10.0, 0.05), point(0.8, 10.0), False, (0.85 / 0.8 - 1, 0.0)),
    ],
)
def test_margins_are_taken_at_the_worse_ends_of_both_intervals(learned, baseline, lower, expected):
    metric, bits = comparison.margins(learned, baseline, lower)
    for got, want in zip((metric, bits), expected, strict=True):
        assert (got is None) == (want is None) and (want is None or got == pytest.approx(want, abs=1e-12))


def test_a_margin_clears_goal_2_at_ten_percent_on_the_metric_or_twenty_on_bits():
    assert comparison.clears_margin(0.10, None) and comparison.clears_margin(None, 0.20)
    assert comparison.clears_margin(-0.5, 0.25) and comparison.clears_margin(0.11, -1.0)
    assert not comparison.clears_margin(0.099, 0.199) and not comparison.clears_margin(None, None)
    # the page names the criterion a margin clears: the metric's first where both do
    assert comparison.clearing_criterion(0.12, 0.30) == "metric" and comparison.clearing_criterion(0.05, 0.30) == "bits"
    assert comparison.clearing_criterion(0.099, 0.199) is None


def test_a_rule_of_ours_never_passes_for_the_papers_algorithm():
    """Against the paper's own algorithms, the page's reference is the best rule that says where the paper describes
    it, however much better a rule of ours scores; and every comparison table names a paper algorithm."""
    from mrcomm_baselines import from_paper
    from mrcomm_env.experiments.learning_report import widest_margin

    rows = [
        {**point(45.0, 758.0), "policy": "age_aware", "setting": None},
        {**point(43.0, 758.0), "policy": "heard_aware", "setting": None},
        {**point(60.0, 759.0), "policy": "location_based", "setting": None},
        {**point(100.0, 759.0), "policy": "random", "setting": None},
        {**point(41.0, 757.0, 0.1, 1.0, cost=0.0), "setting": 0.0, "policy": "learned", "n": 5},
    ]
    spec = {"lower_is_better": True}
    paper = widest_margin("MultiHop-v0", rows, spec, "paper")
    ours = widest_margin("MultiHop-v0", rows, spec, "any")
    assert paper.rule["policy"] == "location_based" and paper.clears
    assert ours.rule["policy"] == "heard_aware" and not ours.clears
    assert not from_paper("MultiHop-v0", "heard_aware") and not from_paper("ChannelAssociation-v0", "id_bits")
    for env_id in env_ids():
        names = [name for name, _ in comparison.comparison_spec(env_id)["baselines"]]
        assert any(from_paper(env_id, name) for name in names), env_id


def test_one_collapsed_seed_does_not_buy_a_match_through_a_wide_t_interval():
    """Five seeds, one collapsed (AsyncCL at a high bit price): the t-interval of the mean is wide enough to call a
    delay 12 times the baseline's "not worse"; the bootstrap interval of the IQM is not."""
    from mrcomm_env.experiments.comparison import iqm_ci95

    seeds = [1.9, 2.0, 2.1, 2.2, 70.0]
    learned = comparison.comparison_row("learned (ppo)", 0.5, seeds, [1474.0] * 5, 5)
    learned["metric_iqm"], learned["metric_iqm_low"], learned["metric_iqm_high"] = iqm_ci95(seeds)
    baseline = point(1.286, 2219.0, 0.027, 17.0)
    assert learned["metric"] - learned["metric_ci95"] < baseline["metric"]  # the t-interval alone would match
    assert not comparison.dominates(learned, baseline, lower_is_better=True)
    steady = comparison.comparison_row("learned (ppo)", 0.02, [1.28, 1.29, 1.30, 1.29, 1.30], [2200.0] * 5, 5)
    steady["metric_iqm"], steady["metric_iqm_low"], steady["metric_iqm_high"] = iqm_ci95([1.28, 1.29, 1.30, 1.29, 1.30])
    assert comparison.dominates(steady, baseline, lower_is_better=True)
    assert not comparison.beats(steady, baseline, lower_is_better=True)


#: the parts of RendezvousMapping's comparison spec the page reads: a time metric that an unfinished episode counts
#: at 60 phases, swept over the communication range, with the baselines scored per range
RANGE_SPEC = {
    "metric": "iterations_to_half_info",
    "lower_is_better": True,
    "unfinished": 60,
    "cost_param": "d_comms",
    "baselines_per_cost": True,
    "algo": "ippo",
    "settings": {"ippo": {}},
}


def test_a_learned_point_that_finishes_no_episode_gets_no_verdict_on_bits():
    """RendezvousMapping's comparison at d_comms = 0: a policy that keeps the team apart never reaches half the
    information (each episode counts as the 60 phases) and sends far fewer bits than the protocol, which finishes one
    episode in five. Without the task done, fewer bits is no win; at a range where it finishes, it still is."""
    from mrcomm_env.experiments.learning_report import learning_section

    spec = dict(RANGE_SPEC)

    def learned(cost, per_seed, bits):
        row = comparison.comparison_row("learned (ippo)", cost, per_seed, bits, 5)
        row["metric_iqm"], row["metric_iqm_low"], row["metric_iqm_high"] = comparison.iqm_ci95(per_seed)
        row["setting"] = cost
        return row

    def protocol(cost, episodes, bits):
        row = comparison.comparison_row("paper_protocol", None, episodes, bits, 5)
        row["setting"] = cost
        return row

    never = learned(0.0, [60.0] * 5, [17000.0, 18000.0, 16000.0, 19000.0, 17500.0])
    sometimes = learned(10.0, [26.0, 33.0, 22.0, 20.0, 28.0], [37000.0, 45000.0, 33000.0, 36000.0, 38000.0])
    rows = [
        never,
        sometimes,
        protocol(0.0, [60, 60, 58, 60, 60], [60300.0] * 5),
        protocol(10.0, [24.0] * 5, [58400.0] * 5),
    ]
    assert not comparison.finishes_some(never, spec) and comparison.finishes_some(sometimes, spec)
    assert comparison.beats(never, rows[2], lower_is_better=True)  # on the numbers alone it would be a win
    page = learning_section("RendezvousMapping-v0", rows, spec, "figure.png")
    assert "- `paper_protocol`: **beaten** at equal or fewer bits (d_comms = 10)" in page
    assert "No verdict at d_comms = 0" in page
    finished = dict(spec, unfinished=None)
    assert "(d_comms = 0, 10)" in learning_section("RendezvousMapping-v0", rows, finished, "figure.png")


def test_the_from_scratch_table_sets_no_target_where_the_paper_algorithm_finishes_no_episode(monkeypatch):
    """Reaching the time of an algorithm that never finished is no milestone: at d_comms = 0 the untrained policy
    "reached" `paper_protocol`'s 60 phases (it never finished either) at agent-step 0."""
    from mrcomm_env.experiments import learning_report

    spec = dict(RANGE_SPEC)
    on_curves = {
        0.0: {"policy": "paper_protocol", "metric": 60.0, "bits": 60000.0},
        10.0: {"policy": "paper_protocol", "metric": 25.0, "bits": 58000.0},
    }
    monkeypatch.setattr(learning_report, "baseline_on_training_heldout", lambda e, s, p, setting: on_curves[setting])
    baselines = [{"policy": "paper_protocol", "setting": c, "metric": 59.0, "bits": 60000.0} for c in on_curves]
    curves = [
        {"cost": cost, "seed": 0, "agent_steps": steps, "seconds": steps / 1e4, "metric": metric, "bits": bits}
        for cost, steps, metric, bits in [
            (0.0, 0, 60.0, 15000.0),
            (0.0, 10**6, 60.0, 15000.0),
            (10.0, 0, 60.0, 20000.0),
            (10.0, 10**6, 24.0, 40000.0),
        ]
    ]
    rows = [
        line
        for line in learning_report.scratch_table("RendezvousMapping-v0", curves, baselines, spec, "")
        if line.startswith("| 0 |") or line.startswith("| 10 |")
    ]
    assert rows[0].startswith("| 0 | no target: `paper_protocol` finishes none of the")
    assert rows[1].startswith("| 10 | 1 of 1 | 1,000,000 |")


def test_a_comparison_from_a_clone_reads_its_from_scratch_table_from_the_kept_curves(monkeypatch, tmp_path):
    """A comparison whose runs start from a clone has no curve from random weights of its own: its goal-3 table reads
    ``<Name>-scratch-curves.csv`` where one is kept, and says where the runs start either way."""
    from mrcomm_env.experiments import learning_report

    spec = {**RANGE_SPEC, "baselines_per_cost": False, "settings": {"ippo": {"init_from": "baseline:greedy"}}}
    target = {"policy": "paper_protocol", "metric": 25.0, "bits": 58000.0}
    monkeypatch.setattr(learning_report, "baseline_on_training_heldout", lambda e, s, p, setting: target)
    baselines = [{"policy": "paper_protocol", "setting": None, "metric": 24.0, "bits": 58000.0}]
    (tmp_path / "learning").mkdir()
    without = learning_report.from_random_weights("RendezvousMapping-v0", baselines, spec, tmp_path)
    assert len(without) == 1 and "a clone of `greedy`" in without[0] and "notes below" in without[0]
    # seed 0 reaches 25 phases at 58,000 bits after 500,000 agent-steps; seed 1 never does (26 at the end)
    curves = tmp_path / "learning" / "RendezvousMapping-v0-scratch-curves.csv"
    curves.write_text(
        "cost,seed,agent_steps,metric,bits,seconds\n"
        "10.0,0,0,60.0,20000.0,0.0\n10.0,0,500000,25.0,58000.0,50.0\n10.0,0,1000000,24.0,57000.0,100.0\n"
        "10.0,1,0,60.0,20000.0,0.0\n10.0,1,1000000,26.0,50000.0,90.0\n"
    )
    table = learning_report.from_random_weights("RendezvousMapping-v0", baselines, spec, tmp_path)
    assert "a clone of `greedy`" in table[0] and "RendezvousMapping-v0-scratch-curves.csv" in table[0]
    assert table[-1].startswith("| 10 | 1 of 2 | 500,000 | 50.0 | 25, 5.35e+04 (after 1,000,000 agent-steps")


@pytest.mark.parametrize("env_id", env_ids())
def test_every_env_has_a_learning_configuration_its_baselines_exist(env_id):
    from mrcomm_baselines import policy_names

    spec = comparison.comparison_spec(env_id)
    assert spec["baselines"] and spec["costs"] and spec["seeds"] >= 3
    assert {name for name, _ in spec["baselines"]} <= set(policy_names(env_id))
    assert "random" in {name for name, _ in spec["baselines"]}
    algo = spec.get("algo", "ppo")
    assert algo in spec["settings"], f"no {algo} settings"


def test_reproduce_learning_end_to_end_on_a_tiny_budget(tmp_path, monkeypatch):
    tiny = {
        "ppo": {
            "env_kwargs": {"n_robots": 4, "mobile_fraction": 0.0, "max_cycles": 12},
            "timesteps": 64,
            "n_envs": 1,
            "net_arch": [8],
            "n_steps": 16,
            "batch_size": 32,
            "n_epochs": 1,
        },
        "comparison": {
            "setting": "tiny",
            "cost_param": "emission_cost",
            "costs": [0.0, 0.5],
            "metric": "completion_time",
            "lower_is_better": True,
            "unfinished": 12,
            "bits_per": "episode",
            "seeds": 1,
            "eval_episodes": 2,
            "deterministic": False,
            "checkpoint": "best",
            "baselines": [["coin_flip", {}], ["random", {}]],
            "actions_against": [["coin_flip", {}]],
        },
    }
    config_dir = tmp_path / "configs"
    config_dir.mkdir()
    (config_dir / "ChannelAssociation-v0.json").write_text(json.dumps(tiny))
    monkeypatch.setattr("mrcomm_agents.training.CONFIG_DIR", config_dir)
    monkeypatch.setattr("mrcomm_env.experiments.runs.agent_config_dir", lambda: config_dir)
    monkeypatch.setattr("mrcomm_agents.learned.PRETRAINED_DIR", tmp_path / "pretrained")
    docs = tmp_path / "docs"
    code = main(
        [
            "reproduce-learning",
            "ChannelAssociation-v0",
            "--out",
            str(tmp_path / "runs"),
            "--docs",
            str(docs),
            "--quiet",
            "--export-pretrained",
            "--workers",
            "1",  # the monkeypatched configuration lives in this process only
        ]
    )
    assert code == 0
    page = (docs / "learning.md").read_text()
    assert "learning/ChannelAssociation-v0.png" in page and "- `random`: **" in page and "- `coin_flip`: **" in page
    rows = (docs / "learning" / "ChannelAssociation-v0.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 + 2  # header, one learned row per cost, two baselines
    assert (docs / "learning" / "ChannelAssociation-v0.png").stat().st_size > 0
    # learning curves from the runs' held-out evaluations: here the start and the final policy of each run, since
    # the 64-step budget ends before the default evaluation period
    with open(docs / "learning" / "ChannelAssociation-v0-curves.csv", newline="") as fh:
        curve = list(csv.DictReader(fh))
    assert sorted((float(r["cost"]), int(r["agent_steps"])) for r in curve) == [
        (0.0, 0),
        (0.0, 64),
        (0.5, 0),
        (0.5, 64),
    ]
    assert all(float(r["seconds"]) > 0 for r in curve if int(r["agent_steps"]) == 64)
    assert all(0 <= float(r["metric"]) <= 12 for r in curve)  # an unfinished episode counts as its 12 steps
    assert (docs / "learning" / "ChannelAssociation-v0-curves.png").stat().st_size > 0
    assert "learning/ChannelAssociation-v0-curves.png" in page and "64 agent-steps each" in page
    shipped = tmp_path / "pretrained" / "ChannelAssociation-v0"
    assert {p.name for p in shipped.iterdir()} == {"model.zip", "vecnormalize.json", "config.json", "card.json"}
    card = json.loads((shipped / "card.json").read_text())
    assert card["env_kwargs"] == json.loads((shipped / "config.json").read_text())["env_kwargs"]
    assert card["deterministic"] is False  # the mode of the (patched) comparison config above
    # each run is scored, and the chosen one shipped, as its best checkpoint by held-out return: with evaluations
    # only at agent-step 0 (never a candidate) and at the end, the final policy's
    assert card["checkpoint"] == "best" and card["agent_steps"] == 64
    best_runs = [json.loads(p.read_text())["checkpoint"] for p in (tmp_path / "runs").rglob("best.json")]
    assert sorted(best_runs) == ["step-000000000064"] * 2
    assert card["best_baseline"]["policy"] == "coin_flip"  # the one paper algorithm here (random is a reference)
    assert card["heldout"]["episodes"] == 2 and 0 <= card["heldout"]["metric"] <= 12  # 12: the tiny max_cycles
    # what the shipped run chooses beside the rule the config names, on the table's held-out episodes: 4 robots
    # decide at every step until the field is done or the 12 steps end
    actions = json.loads((docs / "learning" / "ChannelAssociation-v0-actions.json").read_text())
    assert actions["rules"] == ["coin_flip"] and actions["seeds"] == [10000, 10001]
    assert 2 * 4 <= actions["decisions"] <= 2 * 4 * 12
    assert sum(actions["counts"]["learned"].values()) == actions["decisions"]
    assert "| the same action as `learned` | — |" in page and "--against coin_flip --episodes 2 --seed 10000" in page
    # a rerun trains nothing again: every run folder is finished
    runs = sorted((tmp_path / "runs").rglob("done.json"))
    assert len(runs) == 2
    before = [p.stat().st_mtime_ns for p in runs]
    main(
        [
            "reproduce-learning",
            "ChannelAssociation-v0",
            "--out",
            str(tmp_path / "runs"),
            "--docs",
            str(docs),
            "--quiet",
            "--workers",
            "1",
        ]
    )
    assert [p.stat().st_mtime_ns for p in runs] == before


SHIPPED = [e for e in env_ids() if (PRETRAINED_DIR / short_name(e) / "model.zip").exists()]


@pytest.mark.parametrize("env_id", SHIPPED)
def test_pretrained_model_is_small_and_evaluates(env_id, tmp_path):
    folder = PRETRAINED_DIR / short_name(env_id)
    assert sum(p.stat().st_size for p in folder.iterdir()) < 1_000_000
    out = tmp_path / "eval.json"
    assert main(["evaluate", env_id, "--policy", "pretrained", "--episodes", "1", "--quiet", "--json", str(out)]) == 0
    metrics = json.loads(out.read_text())["metrics"]
    assert all(v["mean"] is None or math.isfinite(v["mean"]) for v in metrics.values())
    trained = json.loads((folder / "config.json").read_text())
    assert trained["env_id"] == env_id and load_policy("pretrained", env_id).env_kwargs == trained["env_kwargs"]


def test_every_env_with_a_learning_configuration_ships_a_pretrained_model():
    configured = [e for e in env_ids() if (CONFIG_DIR / f"{short_name(e)}.json").exists()]
    assert configured and set(configured) <= set(SHIPPED), f"missing: {sorted(set(configured) - set(SHIPPED))}"


def test_learning_page_is_current_with_its_recorded_tables_and_sweeps(tmp_path):
    # docs/learning.md is rendered from docs/learning/<Name>-v0.csv (the comparison) and sweep-<Name>-v0.* (the
    # hyperparameter sweeps) with the live configs: re-rendering them must give the committed page
    import shutil

    docs = Path(__file__).parents[2] / "docs"
    shutil.copytree(docs / "learning", tmp_path / "learning")
    for fragment in (tmp_path / "learning").glob("*.md"):
        fragment.unlink()  # every section is rebuilt, none is copied
    assert main(["reproduce-learning", "--docs-only", "--docs", str(tmp_path)]) == 0
    assert (tmp_path / "learning.md").read_text() == (docs / "learning.md").read_text()


@pytest.mark.parametrize("env_id", SHIPPED)
def test_every_shipped_model_has_a_card_that_agrees_with_it(env_id):
    """The card holds the model's training setting and the evaluation mode it was chosen with, which
    ``--policy pretrained`` uses."""
    from mrcomm_agents.learned import model_card
    from mrcomm_env.experiments.runs import comparison_spec

    card = model_card(env_id)
    record = json.loads((PRETRAINED_DIR / short_name(env_id) / "config.json").read_text())
    assert card["env_id"] == record["env_id"] and card["env_kwargs"] == record["env_kwargs"]
    assert card["algo"] == record["algo"]
    assert card["deterministic"] is comparison_spec(env_id).get("deterministic", True)
    policy = load_policy("pretrained", env_id)
    if card.get("checkpoint", "final") == "final":
        # the agent-steps the model was trained for: its budget, rounded up to whole rollouts
        assert card["agent_steps"] == policy.model.num_timesteps >= record["timesteps"]
    else:  # its run's best checkpoint by held-out return, after some update and at most at the end
        assert card["checkpoint"] == "best" and 0 < card["agent_steps"] == policy.model.num_timesteps
        assert card["agent_steps"] <= card["rl_phase"]["end"]["agent_steps"]
    assert policy.deterministic is card["deterministic"]
    assert (
        load_policy("pretrained", env_id, deterministic=not card["deterministic"]).deterministic
        is not card["deterministic"]
    )


@pytest.mark.parametrize("env_id", SHIPPED)
def test_every_card_gives_the_held_out_metric_at_the_start_and_the_end_of_its_rl_phase(env_id):
    """The card's ``rl_phase`` is its run's first and last held-out evaluation as the recorded learning curves hold
    them (``docs/learning/<Name>-curves.csv``): a card left over from another run, or one whose start is not
    agent-step 0 (random weights or the warm start's clone), fails."""
    from mrcomm_agents.heldout import HELDOUT_SEEDS
    from mrcomm_agents.learned import model_card
    from mrcomm_env.experiments.runs import comparison_spec

    card = model_card(env_id)
    spec = comparison_spec(env_id)
    cost = float(card["env_kwargs"][spec["cost_param"]])
    with open(Path(__file__).parents[2] / "docs" / "learning" / f"{short_name(env_id)}-curves.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if float(r["cost"]) == cost and int(r["seed"]) == card["seed"]]
    assert rows, f"no recorded curve for the shipped run ({spec['cost_param']}={cost}, seed {card['seed']})"
    phase = card["rl_phase"]
    assert phase["start"]["agent_steps"] == 0 and phase["first_seed"] == HELDOUT_SEEDS
    for end, row in (("start", rows[0]), ("end", rows[-1])):
        assert phase[end]["agent_steps"] == int(row["agent_steps"])
        assert math.isclose(phase[end]["metric"], float(row["metric"]), rel_tol=1e-12)
        assert math.isclose(phase[end]["bits"], float(row["bits"]), rel_tol=1e-12)
    assert phase["end"]["agent_steps"] >= card["agent_steps"]  # the last evaluation is the final policy's


def test_multihop_pretrained_fills_a_slot_as_one_choice_of_at_most_m_minus_1():
    """The shipped MultiHop model draws its select bits as one subset (``candidate_subset``): never more than the
    slot holds, which independent select bits could not promise."""
    from mrcomm_agents.policies import SubsetDistribution
    from mrcomm_env.registry import make

    policy = load_policy("pretrained", "MultiHop-v0")
    assert isinstance(policy.model.policy.action_dist, SubsetDistribution)
    env = make("MultiHop-v0", **policy.env_kwargs)
    observations, _ = env.reset(seed=10_000)
    policy.reset(env.local_views(), seed=10_000)
    room = policy.env_kwargs.get("slot_size", 4) - 1
    sent = []
    for _ in range(10):
        actions = policy.act(observations, env.local_views())
        sent += [int(np.sum(a)) for a in actions.values()]
        observations, *_ = env.step(actions)
    assert max(sent) <= room and np.mean(sent) > 0


def test_the_shipped_run_never_buys_its_metric_with_more_bits_than_the_best_paper_algorithm():
    """`--export-pretrained` ships the best metric among the runs within the best baseline's bits (5 % slack),
    and says so on the card; with no such run it falls back to the best metric."""
    spec = {"lower_is_better": True, "bits_per": "episode"}
    baselines = [
        {"policy": "id_bits", "setting": None, "metric": 5.0, "bits": 13.0},
        {"policy": "coin_flip", "setting": None, "metric": 10.0, "bits": 30.0},
        {"policy": "random", "setting": None, "metric": 4.0, "bits": 1.0},  # a reference, never "the best"
    ]
    runs = [
        {"out": "cheap0", "cost": 0.0, "seed": 0, "score": 5.0, "bits": 15.2},  # best metric, 17 % more bits
        {"out": "frugal", "cost": 0.1, "seed": 1, "score": 5.1, "bits": 13.5},  # within 5 % of id_bits' bits
        {"out": "stingy", "cost": 0.4, "seed": 0, "score": 6.0, "bits": 12.0},
    ]
    shipped = comparison.shipped_run(runs, baselines, spec, episodes=20)
    assert shipped["run"] == "frugal" and shipped["within_baseline_bits"]
    assert shipped["best_baseline"] == {"policy": "id_bits", "metric": 5.0, "bits": 13.0}
    assert shipped["heldout"]["metric"] == 5.1 and shipped["heldout"]["bits"] == 13.5
    assert shipped["heldout"]["episodes"] == 20
    too_dear = [dict(r, bits=r["bits"] + 10) for r in runs]
    fallback = comparison.shipped_run(too_dear, baselines, spec, episodes=20)
    assert fallback["run"] == "cheap0" and not fallback["within_baseline_bits"]
    # per-setting baselines (RendezvousMapping's communication range): each run is held to its own setting's
    per_setting = {**spec, "baselines_per_cost": True}
    ranged = [
        {"policy": "paper_protocol", "setting": 0.0, "metric": 5.0, "bits": 100.0},
        {"policy": "paper_protocol", "setting": 0.1, "metric": 5.0, "bits": 10.0},
    ]
    assert comparison.shipped_run(runs[:2], ranged, per_setting, episodes=5)["run"] == "cheap0"
    # and across settings a metric counts relative to its own setting's best paper algorithm: 22 phases where the
    # protocol needs 24 (8 % better) ships before 12 where it needs 12.4 (3 % better), whatever the raw numbers
    phases = [
        {"policy": "paper_protocol", "setting": 1000.0, "metric": 12.4, "bits": 61_000.0},
        {"policy": "paper_protocol", "setting": 10.0, "metric": 24.0, "bits": 58_000.0},
    ]
    ranges = [
        {"out": "far", "cost": 1000.0, "seed": 0, "score": 12.0, "bits": 61_000.0},
        {"out": "near", "cost": 10.0, "seed": 0, "score": 22.0, "bits": 40_000.0},
        {"out": "near_dear", "cost": 10.0, "seed": 1, "score": 21.0, "bits": 70_000.0},  # beyond the bits
    ]
    chosen = comparison.shipped_run(ranges, phases, per_setting, episodes=5)
    assert chosen["run"] == "near" and chosen["best_baseline"]["metric"] == 24.0


@pytest.mark.parametrize("env_id", SHIPPED)
def test_a_shipped_models_card_agrees_with_the_learning_page(env_id):
    """The card's best paper algorithm is the one docs/learning.md's table gives in the model's setting, and the
    shipped model sends no more bits than it (with the equal-bits rule's 5 % slack): a model is never shipped for
    a metric bought with bits."""
    from mrcomm_agents.learned import model_card
    from mrcomm_env.experiments.learning_report import read_rows
    from mrcomm_env.experiments.runs import comparison_spec

    card = model_card(env_id)
    if "best_baseline" not in card:
        pytest.fail(f"{env_id}'s card predates the comparison's account (rerun reproduce-learning --export-pretrained)")
    spec = comparison_spec(env_id)
    rows = read_rows(Path(__file__).parents[2] / "docs" / "learning" / f"{short_name(env_id)}.csv")
    setting = card["env_kwargs"][spec["cost_param"]] if spec.get("baselines_per_cost") else None
    best = comparison.best_baseline([r for r in rows if r["cost"] is None], setting, spec)
    assert best is not None and best["policy"] == card["best_baseline"]["policy"]
    if comparison.stale_revision(env_id, rows) is None:  # the table's revision is the env's: the same episodes
        assert card["best_baseline"]["metric"] == pytest.approx(best["metric"], rel=1e-9)
    else:  # the env changed since the table was recorded: the card's figures are the current revision's
        assert card["env_revision"] == env_revision(env_id)
    assert card["heldout"]["bits"] <= 1.05 * card["best_baseline"]["bits"] + 1e-9


def test_export_writes_a_card_with_the_agent_steps_the_model_was_trained_for(tmp_path, monkeypatch):
    """A budget that is not a whole number of rollouts is rounded up by training; the card says what the model had,
    as its ``state.json`` counts it, not the budget, and the model, statistics and config travel with it."""
    from mrcomm_agents import learned
    from mrcomm_agents.training import TrainConfig, train

    config = TrainConfig(
        env_id="MapSync-v0",
        algo="ippo",
        timesteps=1_000,  # rollouts of 8 steps × 4 copies × 2 robots: 1,024 agent-steps
        seed=0,
        env_kwargs={"lam": 0.01, "max_cycles": 20},
        hyperparams={"n_steps": 8, "batch_size": 32, "n_epochs": 1},
        n_envs=4,
        net_arch=[8],
        eval_episodes=1,
    )
    run = train(config, tmp_path / "run", progress=False)
    monkeypatch.setattr(learned, "PRETRAINED_DIR", tmp_path / "shipped")  # the root every reader of it joins
    target = comparison.export_pretrained(run, "MapSync-v0")
    card = json.loads((target / "card.json").read_text())
    trained = json.loads((run / "state.json").read_text())["num_timesteps"]
    assert card["agent_steps"] == trained == 1_024
    assert card["rl_phase"]["end"]["agent_steps"] == trained
    assert {p.name for p in target.iterdir()} >= {"model.zip", "vecnormalize.json", "config.json", "card.json"}


def test_a_curve_reaches_the_paper_at_its_metric_with_at_most_five_percent_more_bits():
    def at(steps, metric, bits):
        return {"agent_steps": steps, "metric": metric, "bits": bits, "seconds": steps / 100}

    target = {"metric": 5.0, "bits": 10.0}
    curve = [at(300, 5.0, 10.4), at(0, 9.0, 10.0), at(100, 5.0, 10.6), at(200, 4.0, 12.0)]
    assert comparison.first_reach(curve, target, lower_is_better=True)["agent_steps"] == 300  # the first, in steps
    assert comparison.first_reach(curve[1:], target, lower_is_better=True) is None  # too many bits, or too slow
    higher = [at(0, 0.5, 10.0), at(50, 0.9, 9.0)]
    assert comparison.first_reach(higher, {"metric": 0.8, "bits": 10.0}, lower_is_better=False)["agent_steps"] == 50


def test_a_resumed_runs_curve_counts_the_wall_time_of_every_session(tmp_path):
    # each session of a resumed run logs time/time_elapsed from 0 (SB3's and the batched trainer's clocks start at
    # their learn()); the curve's seconds must go on across sessions, or a from-scratch table would report the
    # last session's time alone
    header = "time/total_timesteps,time/time_elapsed,heldout/weighted_mean_age,heldout/bits_per_agent_step"
    log = [header, "0,0,150,700", "100,50,", "200,100,60,710", "300,20,", "400,40,45,720"]  # resumed after 200
    (tmp_path / "progress.csv").write_text("\n".join(log) + "\n")
    spec = {"metric": "weighted_mean_age", "bits_per": "step"}
    rows = comparison.curve_rows([{"out": str(tmp_path), "cost": 0.0, "seed": 0}], spec)
    assert [(r["agent_steps"], r["seconds"]) for r in rows] == [(0, 0.0), (200, 100.0), (400, 140.0)]


def test_a_table_recorded_at_an_earlier_env_revision_is_flagged_and_not_counted(tmp_path):
    """A comparison table whose rows were trained and evaluated at another revision of the env than the current one
    (its ``env_revision`` column) is shown with that revision and left out of the summary's counts; a table at the
    current revision, or one without the column, counts."""
    from mrcomm_env.experiments import learning_report
    from mrcomm_env.registry import env_class

    env_id = "mrcomm/RendezvousMapping-v0"
    current = env_class(env_id).VERSION_HISTORY[-1][0]
    earlier = env_class(env_id).VERSION_HISTORY[-2][0]
    assert env_revision(env_id) == current
    assert comparison.stale_revision(env_id, [{"env_revision": current}, {"env_revision": current}]) is None
    assert comparison.stale_revision(env_id, [{"env_revision": earlier}, {"env_revision": current}]) == earlier
    assert comparison.stale_revision(env_id, [{"policy": "random"}]) is None  # written before the column

    recorded = list(csv.DictReader(open(Path(__file__).parents[2] / "docs" / "learning" / "RendezvousMapping-v0.csv")))
    # a learned point at d_comms = 10 that clears the bits margin over paper_protocol whatever the recorded figures:
    # the protocol's time with a tenth of its bits (the recorded rows give its figures at that range)
    protocol = next(r for r in recorded if r["policy"] == "paper_protocol" and float(r["setting"]) == 10.0)
    for row in recorded:
        if row["policy"].startswith("learned") and float(row["setting"]) == 10.0:
            row.update(metric=protocol["metric"], metric_iqm=protocol["metric"], metric_iqm_low=protocol["metric"])
            row.update(metric_iqm_high=protocol["metric"], bits=float(protocol["bits"]) / 10, bits_ci95=0.0)
    (tmp_path / "learning").mkdir()

    def summary(revision: str | None) -> str:
        rows = [{k: v for k, v in row.items() if k != "env_revision"} for row in recorded]
        if revision is not None:
            rows = [{**row, "env_revision": revision} for row in rows]
        with open(tmp_path / "learning" / "RendezvousMapping-v0.csv", "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        return "\n".join(learning_report.margins_table(tmp_path))

    for revision in (current, None):  # that table clears the margin over paper_protocol (90 % fewer bits)
        text = summary(revision)
        assert "algorithms on 1 of 1 envs" in text and "leave out" not in text and "not counted" not in text
    text = summary(earlier)
    assert "algorithms on 0 of 1 envs" in text and "ours included, on 0 of 1" in text
    assert f"leave out RendezvousMapping-v0's (recorded at {earlier}) table" in text
    assert f"recorded at {earlier}, not counted" in text
