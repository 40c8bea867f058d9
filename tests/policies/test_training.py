"""``mrcomm train`` / ``mrcomm_agents.training``: run folders, checkpoints, resuming without loss, learned policies
in ``mrcomm evaluate``, and one-line errors for bad runs."""

from __future__ import annotations

import csv
import json
import math
import os
import shutil

import numpy as np
import pytest
import torch

from mrcomm_agents import training
from mrcomm_agents.artifacts import STATISTICS_FILE, load_statistics
from mrcomm_agents.learned import LearnedPolicy, load_policy
from mrcomm_agents.training import RunError, TrainConfig, train
from mrcomm_env.experiments.cli import main
from mrcomm_env.experiments.learning_report import sweep_section

torch.set_num_threads(1)

ENV = "ChannelAssociation-v0"
ENV_KWARGS = {"n_robots": 3, "max_cycles": 10}
N_AGENTS = 3
#: one rollout = n_steps × (n_envs × N agent slots) agent-steps; PPO then takes n_epochs × rollout/batch steps
HYPER = {"n_steps": 16, "batch_size": 24, "n_epochs": 2}
ROLLOUT = HYPER["n_steps"] * N_AGENTS


def config(timesteps: int, **kw) -> TrainConfig:
    settings = dict(
        env_id=ENV,
        timesteps=timesteps,
        seed=3,
        env_kwargs=dict(ENV_KWARGS),
        hyperparams=dict(HYPER),
        n_envs=1,
        net_arch=[16],
        checkpoint_every=ROLLOUT,
    )
    settings.update(kw)
    return TrainConfig(**settings)


def interrupt_after_checkpoints(monkeypatch, count: int) -> None:
    """Make training raise KeyboardInterrupt (as Ctrl-C) right after its ``count``-th checkpoint."""
    saves = []
    original = training._Progress.__init__

    def interrupting(self, total, start, every, save, enabled):
        def save_then_stop(model):
            save(model)
            saves.append(model.num_timesteps)
            if len(saves) == count:
                raise KeyboardInterrupt

        original(self, total, start, every, save_then_stop, enabled)

    monkeypatch.setattr(training._Progress, "__init__", interrupting)


def adam_steps(model) -> int:
    """Optimizer steps taken so far, from Adam's own state (lost if the optimizer state were not restored)."""
    state = model.policy.optimizer.state_dict()["state"]
    return int(max(float(s["step"]) for s in state.values()))


def test_a_run_folder_holds_model_statistics_config_and_logs(tmp_path):
    out = train(config(2 * ROLLOUT), tmp_path / "run", progress=False)
    for name in ("model.zip", "vecnormalize.json", "config.json", "progress.csv", "done.json"):
        assert (out / name).stat().st_size > 0, name
    assert list(out.glob("events.out.tfevents.*")), "no TensorBoard event file"
    record = json.loads((out / "config.json").read_text())
    assert record["env_id"] == "mrcomm/ChannelAssociation-v0" and record["env_kwargs"] == ENV_KWARGS
    assert record["algo"] == "ppo" and record["seed"] == 3 and record["hyperparams"] == HYPER
    assert {"stable-baselines3", "torch", "numpy"} <= set(record["versions"])
    assert "git_commit" in record
    rows = (out / "progress.csv").read_text().splitlines()
    assert len(rows) == 1 + 1 + 2 + 1  # header, the held-out evaluations at the start, per rollout and at the end


def test_training_logs_a_held_out_evaluation_of_the_paper_metric_and_bits(tmp_path):
    """progress.csv (and TensorBoard) carry the env's metric and bits per robot on held-out episodes, at the
    requested period and at the end; the evaluation draws nothing from the training's random streams."""
    from mrcomm_agents.heldout import HELDOUT_SEEDS, evaluate_episodes

    evaluated = train(config(4 * ROLLOUT, eval_every=2 * ROLLOUT, eval_episodes=2), tmp_path / "a", progress=False)
    with open(evaluated / "progress.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    logged = [r for r in rows if r.get("heldout/completion_time")]
    steps = [int(float(r["time/total_timesteps"])) for r in logged]
    assert steps == [0, 2 * ROLLOUT, 4 * ROLLOUT, 4 * ROLLOUT]  # the start, every 2 rollouts, the final policy
    for row in logged:
        bits_step = float(row["heldout/bits_per_agent_step"])
        bits_episode = float(row["heldout/bits_per_agent_episode"])
        assert math.isfinite(bits_step) and bits_episode >= bits_step >= 0
        assert 0 <= float(row["heldout/completion_time"]) <= ENV_KWARGS["max_cycles"]  # unfinished: its length
    # the logged final figures are the trained model's on the held-out seeds
    policy = LearnedPolicy(evaluated, ENV)
    again = evaluate_episodes(
        policy.model, policy.normalizer, ENV, ENV_KWARGS, [HELDOUT_SEEDS, HELDOUT_SEEDS + 1], True
    )
    for key in ("completion_time", "bits_per_agent_episode"):
        assert float(logged[-1][f"heldout/{key}"]) == pytest.approx(again[key], rel=1e-12), key
    # training with the evaluation gives the same weights as without it
    plain = train(config(4 * ROLLOUT, eval_episodes=0), tmp_path / "b", progress=False)
    a, b = LearnedPolicy(evaluated, ENV).model.policy, LearnedPolicy(plain, ENV).model.policy
    for (name, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items()):
        assert torch.equal(x, y), name


def test_resume_loses_neither_steps_nor_optimizer_nor_statistics(tmp_path, monkeypatch):
    rollouts = 4
    target = rollouts * ROLLOUT
    interrupt_after_checkpoints(monkeypatch, 2)  # right after the second checkpoint, as Ctrl-C would
    with pytest.raises(KeyboardInterrupt):
        train(config(target), tmp_path / "run", progress=False)
    monkeypatch.undo()
    assert not (tmp_path / "run" / "done.json").exists()
    newest = training.checkpoints(tmp_path / "run")[0]
    state = json.loads((newest / "state.json").read_text())
    assert 0 < state["num_timesteps"] < target
    # training's own time goes on from what the checkpoint kept (set far beyond this test's seconds to tell)
    (newest / "state.json").write_text(json.dumps({**state, "training_seconds": 1_000.0}))

    train(None, tmp_path / "run", resume=True, progress=False)
    assert 1_000.0 < json.loads((tmp_path / "run" / "state.json").read_text())["training_seconds"] < 1_060.0
    policy = LearnedPolicy(tmp_path / "run", ENV)
    model = policy.model
    assert model.num_timesteps == target
    # every rollout took n_epochs × (rollout / batch) optimizer steps; a fresh optimizer would count fewer
    per_rollout = HYPER["n_epochs"] * (ROLLOUT // HYPER["batch_size"])
    assert adam_steps(model) == rollouts * per_rollout
    # VecNormalize saw one observation per agent-step of the whole run, plus the N reset observations of the
    # start and of the resumption (its count starts at 1e-4); statistics lost on resume would count half
    stats = load_statistics(tmp_path / "run" / STATISTICS_FILE)
    assert stats.obs_rms.count == pytest.approx(target + 2 * N_AGENTS, abs=1e-3)
    # the resumed run appended to the log: one row per rollout of the whole run, steps increasing, one header,
    # and the held-out evaluations of the new run's start and of the end (the interrupted process, stopped by
    # Ctrl-C, wrote no final one; the resumed one no start)
    with open(tmp_path / "run" / "progress.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    steps = [int(float(r["time/total_timesteps"])) for r in rows]
    assert steps == [0] + [ROLLOUT * (k + 1) for k in range(rollouts)] + [target]


def test_resume_of_a_finished_run_is_refused(tmp_path, capsys):
    train(config(ROLLOUT), tmp_path / "run", progress=False)
    with pytest.raises(RunError, match="finished"):
        train(None, tmp_path / "run", resume=True)
    assert main(["train", ENV, "--resume", "--out", str(tmp_path / "run"), "--quiet"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "finished" in err[0]


def test_a_new_run_never_overwrites_an_old_one(tmp_path):
    train(config(ROLLOUT), tmp_path / "run", progress=False)
    with pytest.raises(RunError, match="--resume"):
        train(config(ROLLOUT), tmp_path / "run", progress=False)


def test_evaluate_accepts_a_trained_model_with_the_same_json(tmp_path):
    run = train(config(ROLLOUT), tmp_path / "run", progress=False)
    out = tmp_path / "eval.json"
    params = [arg for k, v in ENV_KWARGS.items() for arg in ("--param", f"{k}={v}")]
    assert (
        main(["evaluate", ENV, "--policy", f"ppo:{run}", "--episodes", "2", "--quiet", *params, "--json", str(out)])
        == 0
    )
    record = json.loads(out.read_text())
    assert record["policy"] == f"ppo:{run}" and record["episodes"] == 2
    assert set(record["metrics"]) >= {"fraction_matched", "bits_sent", "episode_return"}
    # the policy is deterministic: the same seeds give the same metrics
    again = tmp_path / "again.json"
    main(["evaluate", ENV, "--policy", f"ppo:{run}", "--episodes", "2", "--quiet", *params, "--json", str(again)])
    assert json.loads(again.read_text())["metrics"] == record["metrics"]


@pytest.mark.parametrize(
    "spec,damage,message",
    [
        ("ppo:{run}", lambda run: (run / "model.zip").write_bytes(b"not a zip"), "cannot load"),
        ("ppo:{run}", lambda run: [(run / "model.zip").unlink(), shutil.rmtree(run / "checkpoints")], "no checkpoint"),
        ("ppo:{run}", lambda run: (run / "config.json").write_text("{"), "corrupt"),
        ("ppo:{run}/missing", lambda run: None, "not a training run"),
        ("dqn:{run}", lambda run: None, "trained with ppo"),
        ("a2c:{run}", lambda run: None, "unknown policy"),
    ],
)
def test_bad_models_give_one_line_errors(tmp_path, capsys, spec, damage, message):
    run = train(config(ROLLOUT), tmp_path / "run", progress=False)
    damage(run)
    code = main(["evaluate", ENV, "--policy", spec.format(run=run), "--episodes", "1", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and message in err[0], err


def test_a_model_of_another_env_or_other_spaces_is_refused(tmp_path):
    run = train(config(ROLLOUT), tmp_path / "run", progress=False)
    with pytest.raises(RunError, match="trained on mrcomm/ChannelAssociation-v0"):
        load_policy(f"ppo:{run}", "MultiHop-v0")
    policy = load_policy(f"ppo:{run}", ENV)
    import mrcomm_env

    other = mrcomm_env.make(ENV, n_robots=40)  # more robots: a longer ID in the observation
    with pytest.raises(RunError, match="expects observations"):
        policy.reset(other.local_views(), 0)


def test_unknown_algorithm_is_rejected_before_any_work(tmp_path, capsys):
    assert main(["train", ENV, "--algo", "a3c", "--out", str(tmp_path / "x"), "--quiet"]) != 0
    assert "algo" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_learned_actions_come_from_the_network(tmp_path):
    run = train(config(ROLLOUT), tmp_path / "run", progress=False)
    policy = load_policy(f"ppo:{run}", ENV)
    import mrcomm_env

    env = mrcomm_env.make(ENV, **ENV_KWARGS)
    obs, _ = env.reset(seed=0)
    views = env.local_views()
    policy.reset(views, 0)
    actions = policy.act(obs, views)
    stacked = policy.normalizer.normalize_obs(np.stack([obs[a] for a in env.agents]))
    with torch.no_grad():
        dist = policy.model.policy.get_distribution(policy.model.policy.obs_to_tensor(stacked)[0])
        expected = dist.mode().numpy()
    assert [actions[a] for a in env.agents] == expected.tolist()


def _tiny_config_file(tmp_path) -> str:
    path = tmp_path / "tiny.json"
    settings = {"env_kwargs": dict(ENV_KWARGS), "n_envs": 1, "net_arch": [16], **HYPER}
    path.write_text(json.dumps({"ppo": settings}))
    return str(path)


def test_train_seeds_and_grid_run_every_combination_through_the_runner(tmp_path, capsys):
    out = tmp_path / "sweep"
    args = ["train", ENV, "--timesteps", str(ROLLOUT), "--config", _tiny_config_file(tmp_path), "--out", str(out)]
    # a hyperparameter of PPO, a run setting and an environment argument, each routed to its own place
    grid = ["--grid", "learning_rate=0.001,0.0003", "--grid", "net_arch=[8],[16,16]", "--grid", "emission_cost=0.5"]
    code = main([*args, *grid, "--seeds", "0,1", "--eval-episodes", "2", "--workers", "1", "--quiet"])
    assert code == 0
    rows = list(csv.DictReader(open(out / "summary.csv")))
    assert len(rows) == 2 * 2 * 1 * 2  # grid points × seeds
    assert [r["seed"] for r in rows[:2]] == ["0", "1"]  # fixed order: grid values as given, then the seeds
    for row in rows:
        record = json.loads((out / row["run"] / "config.json").read_text())
        assert record["hyperparams"]["learning_rate"] == float(row["learning_rate"])
        assert record["net_arch"] == json.loads(row["net_arch"])
        assert record["env_kwargs"]["emission_cost"] == 0.5 and record["seed"] == int(row["seed"])
        assert int(row["timesteps"]) >= ROLLOUT and np.isfinite(float(row["eval_completion_time"]))
    assert "grid points by held-out completion_time" in capsys.readouterr().out
    record = json.loads((out / "sweep.json").read_text())
    assert record["command"].startswith("mrcomm train ChannelAssociation-v0") and record["seeds"] == [0, 1]
    # the recorded sweep renders as a ranked table of its grid points in docs/learning.md
    docs = tmp_path / "docs"
    (docs / "learning").mkdir(parents=True)
    (docs / "learning" / f"sweep-{ENV}.csv").write_text((out / "summary.csv").read_text())
    (docs / "learning" / f"sweep-{ENV}.json").write_text((out / "sweep.json").read_text())
    table = [line for line in sweep_section(ENV, docs).splitlines() if line.startswith("| 0.")]
    assert len(table) == 4  # one row per grid point (learning_rate × net_arch), seeds pooled
    # a page whose comparison trains another section than the sweep tuned says so; one that trains it does not
    assert "the comparison above trains the `ippo` section" in sweep_section(ENV, docs, "ippo")
    assert "the comparison above trains" not in sweep_section(ENV, docs, "ppo")
    # a rerun trains nothing again
    before = sorted(p.stat().st_mtime_ns for p in out.rglob("model.zip"))
    assert main([*args, *grid, "--seeds", "0,1", "--eval-episodes", "2", "--workers", "1", "--quiet"]) == 0
    assert sorted(p.stat().st_mtime_ns for p in out.rglob("model.zip")) == before


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--grid", "emission_cost=-1"], "emission_cost"),  # the env's own check, before any training
        (["--grid", "learning_rate"], "--grid takes KEY=V1,V2"),
        (["--seeds", "1,1"], "--seeds takes distinct integers"),
        (["--grid", "gamma=0.9,2.5"], "'gamma'"),  # SB3 accepted it
        (["--grid", "clip_range=-1"], "'clip_range'"),
    ],
)
def test_bad_sweeps_are_refused_in_one_line_before_any_training(tmp_path, capsys, extra, message):
    out = tmp_path / "sweep"
    code = main(["train", ENV, "--out", str(out), "--quiet", "--workers", "1", *extra])
    assert code != 0
    err = capsys.readouterr().err.strip()
    assert message in err and "Traceback" not in err and len(err.splitlines()) <= 2
    assert not out.exists()


# ------------------------------------------------------------------------------ interruptions and mistakes
def _cli_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


def _train_cli(run, *extra) -> list[str]:
    params = [x for k, v in ENV_KWARGS.items() for x in ("--param", f"{k}={v}")]
    return ["train", ENV, "--out", str(run), "--quiet", *params, *extra]


def test_a_run_killed_before_its_first_checkpoint_starts_over(tmp_path, capsys):
    """``kill -9`` before the first checkpoint leaves config.json and logs but nothing to resume."""
    import signal
    import subprocess
    import sys
    import time

    run = tmp_path / "run"
    cfg = tmp_path / "settings.json"
    cfg.write_text(json.dumps({"ppo": {**HYPER, "n_envs": 1, "net_arch": [16], "checkpoint_every": 10**9}}))
    command = [sys.executable, "-m", "mrcomm_env.experiments.cli", *_train_cli(run, "--config", str(cfg))]
    proc = subprocess.Popen([*command, "--timesteps", str(10**8)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (run / "progress.csv").exists():
        time.sleep(0.1)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert (run / "config.json").exists() and not training.has_checkpoint(run)
    assert main(["train", ENV, "--resume", "--out", str(run), "--quiet"]) != 0
    assert "nothing to resume" in _cli_error(capsys)
    assert main(_train_cli(run, "--config", str(cfg), "--timesteps", str(ROLLOUT))) == 0
    assert json.loads((run / "done.json").read_text())["num_timesteps"] == ROLLOUT


def test_a_second_process_on_the_same_run_is_refused_naming_the_holder(tmp_path, capsys):
    run = tmp_path / "run"
    with training.run_lock(run):
        assert main(_train_cli(run, "--timesteps", str(ROLLOUT))) != 0
        err = _cli_error(capsys)
        assert f"pid {os.getpid()}" in err
    train(config(ROLLOUT), run, progress=False)  # the lock went with its holder


def test_resume_refuses_settings_that_disagree_with_the_run(tmp_path, capsys):
    run = tmp_path / "run"
    train(config(ROLLOUT, checkpoint_every=10**6), run, progress=False)
    (run / "done.json").unlink()  # as if interrupted after its last checkpoint
    for other, named in (
        (["train", "MapSync-v0", "--resume", "--out", str(run)], "'env_id'"),
        (["train", ENV, "--resume", "--out", str(run), "--param", "n_robots=4"], "'n_robots'"),
        (["train", ENV, "--resume", "--out", str(run), "--seed", "9"], "'seed'"),
        (["train", ENV, "--resume", "--out", str(run), "--algo", "dqn"], "'algo'"),
    ):
        assert main([*other, "--quiet"]) != 0
        assert named in _cli_error(capsys)


def test_resume_with_more_timesteps_extends_a_finished_run(tmp_path, capsys):
    run = tmp_path / "run"
    train(config(ROLLOUT), run, progress=False)
    assert main(["train", ENV, "--resume", "--out", str(run), "--quiet"]) != 0
    assert "--timesteps" in _cli_error(capsys)
    assert main(["train", ENV, "--resume", "--out", str(run), "--timesteps", str(3 * ROLLOUT), "--quiet"]) == 0
    assert LearnedPolicy(run, ENV).model.num_timesteps == 3 * ROLLOUT
    assert json.loads((run / "done.json").read_text())["num_timesteps"] == 3 * ROLLOUT
    assert json.loads((run / "config.json").read_text())["timesteps"] == 3 * ROLLOUT


def test_two_checkpoints_are_kept_and_a_damaged_newest_one_is_skipped(tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    interrupt_after_checkpoints(monkeypatch, 3)
    with pytest.raises(KeyboardInterrupt):
        train(config(6 * ROLLOUT), run, progress=False)
    monkeypatch.undo()
    kept = training.checkpoints(run)
    assert len(kept) == training.KEEP_CHECKPOINTS
    (kept[0] / "model.zip").write_bytes(b"PK\x03\x04 cut short by a crash")
    train(None, run, resume=True, progress=False)
    assert "damaged" in capsys.readouterr().err
    assert LearnedPolicy(run, ENV).model.num_timesteps == 6 * ROLLOUT


def test_a_corrupt_config_json_is_named_in_one_line(tmp_path, capsys):
    run = tmp_path / "run"
    train(config(ROLLOUT, checkpoint_every=10**6), run, progress=False)
    (run / "done.json").unlink()
    (run / "config.json").write_text('{"env_id": "mrcomm/Chann')
    assert main(["train", ENV, "--resume", "--out", str(run), "--quiet"]) != 0
    assert "config.json" in _cli_error(capsys)
    assert main(["evaluate", ENV, "--policy", f"ppo:{run}", "--episodes", "1", "--quiet"]) != 0
    assert "config.json" in _cli_error(capsys)


def test_a_config_file_without_the_algorithm_section_is_refused(tmp_path, capsys):
    cfg = tmp_path / "settings.json"
    cfg.write_text(json.dumps({"learning_rate": 0.001}))  # settings, but not under "ppo"
    assert main(_train_cli(tmp_path / "run", "--config", str(cfg))) != 0
    assert "no section for algorithm 'ppo'" in _cli_error(capsys)
    assert not (tmp_path / "run").exists()


def test_an_output_folder_that_cannot_be_written_is_refused_before_training(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(_train_cli(blocker / "run", "--timesteps", str(ROLLOUT))) != 0
    assert "cannot write the run folder" in _cli_error(capsys)


def test_a_run_evaluates_in_its_own_env_arguments(tmp_path, capsys):
    """A run trained on 3 robots has 3-robot observations: ``evaluate ppo:RUN`` uses them, --param overrides."""
    run = tmp_path / "run"
    train(config(ROLLOUT), run, progress=False)
    assert main(["evaluate", ENV, "--policy", f"ppo:{run}", "--episodes", "1", "--quiet"]) == 0
    assert "'n_robots': 3" in capsys.readouterr().out
    assert (
        main(["evaluate", ENV, "--policy", f"ppo:{run}", "--episodes", "1", "--param", "max_cycles=4", "--quiet"]) == 0
    )
    out = capsys.readouterr().out
    assert "'n_robots': 3" in out and "'max_cycles': 4" in out


def test_times_never_reached_are_documented_metrics_and_count_as_the_episode_length():
    from mrcomm_agents.heldout import evaluate_episodes
    from mrcomm_env.registry import env_ids, make

    for env_id in env_ids():
        env = make(env_id)
        assert set(env.UNREACHED_TIMES) <= set(env.METRICS), env_id
        env.close()

    class AllAlike:
        """A policy under which every robot does the same every step, so no robot is ever told apart."""

        def predict(self, observations, deterministic=True):
            return np.zeros(len(observations), dtype=np.int64), None

    kwargs = {"n_robots": 4, "mobile_fraction": 0.0, "max_cycles": 6}
    env = make(ENV, **kwargs)
    env.reset(seed=5)
    while env.agents:
        env.step({a: 0 for a in env.agents})
    assert env.metrics()["completion_time"] == -1  # the env's own report: not reached
    held_out = evaluate_episodes(AllAlike(), None, ENV, kwargs, [5, 6], deterministic=True)
    assert held_out["completion_time"] == 6.0


def test_a_silent_asynccl_team_counts_at_the_episode_length_in_both_evaluations():
    """A team that completes no step has a nan ``mean_delay``: an average that skipped it would score a silent
    policy as well as its other episodes (or as nan), so both evaluations count it at the episode's length."""
    from mrcomm_agents.heldout import evaluate_episodes
    from mrcomm_baselines import make_policy
    from mrcomm_env.experiments.evaluation import evaluate_policy
    from mrcomm_env.registry import make

    env_id, kwargs = "mrcomm/AsyncCL-v0", {"n_robots": 3, "max_cycles": 8}
    env = make(env_id, **kwargs)
    env.reset(seed=3)
    while env.agents:
        env.step(dict.fromkeys(env.agents, 0))  # action 0: silent
    assert math.isnan(env.metrics()["mean_delay"])  # the env's own report: no step complete

    class Silent:
        def predict(self, observations, deterministic=True):
            return np.zeros(len(observations), dtype=np.int64), None

    assert evaluate_episodes(Silent(), None, env_id, kwargs, [3, 4], deterministic=True)["mean_delay"] == 8.0
    spec = {"metric": "mean_delay"}
    silent = evaluate_policy(env_id, kwargs, make_policy(env_id, "silent"), [3, 4], spec)
    assert silent["metric"] == [8.0, 8.0] and silent["bits"] == [0.0, 0.0]
    talking = evaluate_policy(env_id, kwargs, make_policy(env_id, "scheme1"), [3, 4], spec)
    assert all(0 < m < 8 for m in talking["metric"])  # a real delay is kept as it is
