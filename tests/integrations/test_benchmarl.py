"""Every registered env as a BenchMARL task (``make test-benchmarl``): the task family covers the registry, its
yaml configs are valid env arguments, and ``Experiment`` trains MAPPO and IPPO on every task for a few hundred
frames, updating the policy."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import pytest
import torch
import yaml
from benchmarl.algorithms import IppoConfig, MappoConfig
from benchmarl.experiment import Experiment, ExperimentConfig
from benchmarl.models import MlpConfig
from torchrl.envs.utils import check_env_specs

import mrcomm_env
from mrcomm_env.experiments import benchmarl_bench, benchmarl_reference
from mrcomm_env.integrations.benchmarl import CONF_DIR, ENV_ID_OF_TASK, MrcommSerialClass, MrcommTask
from mrcomm_env.integrations.torchrl_batched import BatchedTorchRLEnv
from mrcomm_env.registry import env_class, env_revision

FRAMES_PER_BATCH = 100
N_BATCHES = 2
SHORT = {"max_cycles": 10}  # 100-frame batches hold whole episodes, so every batch has finished ones
# MultiHop-v0's default team is 100 robots (a 10×10 grid); its documented small grid keeps the run to seconds
SMALL = {"MULTIHOP": {"grid_side": 4}}


def test_the_task_family_has_one_task_per_registered_env():
    assert {task.name for task in MrcommTask} == set(ENV_ID_OF_TASK)
    assert set(ENV_ID_OF_TASK.values()) == set(mrcomm_env.env_ids())
    assert MrcommTask.from_env_id("MapSync-v0") is MrcommTask.MAPSYNC
    with pytest.raises(ValueError, match="unknown environment id"):
        MrcommTask.from_env_id("NoSuchEnv-v0")


@pytest.mark.parametrize("task", list(MrcommTask), ids=lambda t: t.name)
def test_yaml_config_holds_env_arguments_only(task):
    path = CONF_DIR / f"{task.name.lower()}.yaml"
    config = yaml.safe_load(path.read_text())
    assert set(config) <= set(env_class(ENV_ID_OF_TASK[task.name]).PARAMS)
    loaded = task.get_from_yaml()
    assert loaded.config == config
    env = loaded.get_env_fun(num_envs=1, continuous_actions=False, seed=0, device="cpu")()
    assert loaded.max_steps(env) == config["max_cycles"]
    assert loaded.group_map(env) == {
        "robot": list(mrcomm_env.make(ENV_ID_OF_TASK[task.name], **config).possible_agents)
    }
    assert loaded.supports_discrete_actions() != loaded.supports_continuous_actions()
    assert list(loaded.state_spec(env).keys()) == ["state"]
    assert set(loaded.observation_spec(env)["robot"].keys()) == {"observation"}
    mask = loaded.action_mask_spec(env)
    assert (mask is not None) == callable(getattr(mrcomm_env.make(ENV_ID_OF_TASK[task.name]), "action_masks", None))


def test_multibinary_layout_is_refused_with_the_fix():
    with pytest.raises(ValueError, match="config.*MultiBinary.*layout: absolute"):
        MrcommTask.MULTIHOP.get_task({"layout": "relative"})


def test_bad_env_argument_fails_when_the_task_is_made():
    with pytest.raises(ValueError, match="n_robots"):
        MrcommTask.MAPSYNC.get_task({"n_robots": -1})


def small_experiment(task, algorithm_config, tmp_path, **settings) -> Experiment:
    config = ExperimentConfig.get_from_yaml()
    config.max_n_frames = N_BATCHES * FRAMES_PER_BATCH
    config.on_policy_collected_frames_per_batch = FRAMES_PER_BATCH
    config.on_policy_n_envs_per_worker = 2
    config.on_policy_minibatch_size = FRAMES_PER_BATCH // 2
    config.on_policy_n_minibatch_iters = 1
    config.evaluation = False
    config.render = False
    config.loggers = []
    config.create_json = False
    config.save_folder = str(tmp_path)
    for name, value in settings.items():
        setattr(config, name, value)
    return Experiment(
        task=task,
        algorithm_config=algorithm_config,
        model_config=MlpConfig.get_from_yaml(),
        critic_model_config=MlpConfig.get_from_yaml(),
        seed=0,
        config=config,
    )


@pytest.mark.parametrize("algorithm", [MappoConfig, IppoConfig], ids=["mappo", "ippo"])
@pytest.mark.parametrize("task", list(MrcommTask), ids=lambda t: t.name)
def test_experiment_trains_on_every_task(task, algorithm, tmp_path):
    yaml_config = task.get_from_yaml().config
    experiment = small_experiment(
        task.get_task({**yaml_config, **SHORT, **SMALL.get(task.name, {})}), algorithm.get_from_yaml(), tmp_path
    )
    before = [p.detach().clone() for p in experiment.policy.parameters()]
    experiment.run()
    after = list(experiment.policy.parameters())
    assert experiment.total_frames == N_BATCHES * FRAMES_PER_BATCH
    assert experiment.n_iters_performed == N_BATCHES
    assert any(not torch.equal(b, a) for b, a in zip(before, after)), "training did not change the policy"
    assert all(torch.isfinite(p).all() for p in after)
    # MAPPO's centralised critic reads the env's global state(); IPPO's critics read each robot's own observation
    critic_reads_state = "state" in experiment.losses["robot"].critic_network.in_keys
    assert critic_reads_state == (algorithm is MappoConfig)
    assert math.isfinite(float(experiment.mean_return))


@pytest.mark.parametrize("task", [MrcommTask.MAPSYNC, MrcommTask.RENDEZVOUS_MAPPING], ids=lambda t: t.name)
def test_copies_run_as_one_batched_env_with_vectorised_evaluation(task, tmp_path):
    # BenchMARL's n_envs_per_worker copies arrive as one env with that batch size (not a SerialEnv of wrappers), and
    # its evaluation steps evaluation_episodes copies at once, rendering copy 0
    experiment = small_experiment(
        task.get_task({**task.get_from_yaml().config, **SHORT}),
        IppoConfig.get_from_yaml(),
        tmp_path,
        evaluation=True,
        evaluation_episodes=3,
        evaluation_interval=FRAMES_PER_BATCH,
        render=True,
        create_json=True,  # BenchMARL evaluates only when something records it: here its marl-eval JSON
    )
    frames = []
    experiment._on_evaluation_end = lambda rollouts: frames.append(len(rollouts))
    assert experiment.test_env.batch_size == (3,)
    env = experiment.env_func()
    assert env.batch_size == (experiment.config.on_policy_n_envs_per_worker,)
    assert isinstance(env.base_env, BatchedTorchRLEnv)
    experiment.run()
    assert frames == [3] * N_BATCHES, "one rollout per evaluation copy, after each batch"
    assert math.isfinite(float(experiment.mean_return))
    (report,) = tmp_path.rglob("*.json")
    runs = json.loads(report.read_text())
    (seed_run,) = [
        seed
        for tasks in runs.values()
        for algos in tasks.values()
        for seeds in algos.values()
        for seed in seeds.values()
    ]
    evaluations = [seed_run[f"step_{i + 1}"]["return"] for i in range(N_BATCHES)]
    assert all(len(returns) == 3 and all(math.isfinite(r) for r in returns) for returns in evaluations)
    assert len(set(evaluations[0])) > 1, "the evaluation copies are seeded s + i: their episodes differ"


def test_serial_path_is_one_wrapper_per_copy():
    task = MrcommTask.MAPSYNC.get_task(SHORT)
    serial = MrcommSerialClass(task.name, dict(task.config))
    env = serial.get_env_fun(num_envs=2, continuous_actions=False, seed=0, device="cpu")()
    assert env.batch_size == ()
    assert serial.max_steps(env) == SHORT["max_cycles"]


def test_collection_bench_times_both_paths_and_the_ceiling(tmp_path):
    out = tmp_path / "bench.json"
    assert (
        benchmarl_bench.main(
            ["--tasks", "MAPSYNC", "--num-envs", "2", "--frames-per-batch", "20", "--batches", "1", "--out", str(out)]
        )
        == 0
    )
    result = json.loads(out.read_text())["tasks"]["mrcomm/MapSync-v0"]
    for path in ("serial", "batched", "ceiling"):
        assert result[path]["frames"] == 20 and result[path]["frames_per_s"] > 0
    assert result["ratio"] == pytest.approx(result["batched"]["frames_per_s"] / result["serial"]["frames_per_s"])
    assert benchmarl_bench.main(["--num-envs", "0", "--out", str(out)]) == 2


@pytest.mark.parametrize("task", list(MrcommTask), ids=lambda t: t.name)
def test_every_task_env_passes_check_env_specs_under_benchmarl_torchrl(task):
    # BenchMARL pins an older torchrl (0.11) than the torchrl extra (0.14): the batched env's specs hold under both
    config = {**task.get_from_yaml().config, **SHORT, **SMALL.get(task.name, {})}
    env = task.get_task(config).get_env_fun(num_envs=3, continuous_actions=False, seed=0, device="cpu")()
    assert env.batch_size == (3,)
    check_env_specs(env, seed=0)
    data = env.rollout(2 * SHORT["max_cycles"] + 1, break_when_any_done=False)
    assert data["next", "done"].sum() >= 3 * 2  # every copy ended at least twice and went on


# ------------------------------------------------------------------------------ the reference benchmark
TINY_RUN = {"frames": 200, "frames_per_batch": 100, "num_envs": 4, "episodes": 2}


def test_reference_benchmark_runs_resumes_and_writes_its_page(tmp_path, capsys):
    out, page = tmp_path / "benchmark", tmp_path / "benchmark.md"
    args = (["MAPSYNC"], ["ippo"], [0], *TINY_RUN.values())
    assert benchmarl_reference.run_plan(out, *args) == [("MAPSYNC", "ippo", 0)]
    record_path, json_path = benchmarl_reference.run_paths(out, "MAPSYNC", "ippo", 0)
    record = json.loads(record_path.read_text())
    assert record["frames"] == TINY_RUN["frames"] and record["iterations"] == 2
    assert record["wall_seconds"] >= record["training_seconds"] > 0
    assert {len(values) for values in record["heldout"].values()} == {TINY_RUN["episodes"]}
    run = json.loads(json_path.read_text())["mrcomm"]["mapsync"]["ippo"]["seed_0"]
    assert [run[k]["step_count"] for k in sorted(k for k in run if k.startswith("step_"))] == [100, 200]
    assert not record_path.with_suffix(".scratch").exists()
    references = json.loads((out / benchmarl_reference.REFERENCES).read_text())["MAPSYNC"]
    assert record["env_revision"] == references["env_revision"] == env_revision("mrcomm/MapSync-v0")
    assert references["metric"] == "disagreement" and set(references["policies"]) == {
        "random",
        "periodic_equality_then_bisection",
    }

    # a finished run is not run again; a run another process holds is left to it, and a killed one's scratch goes
    assert benchmarl_reference.run_plan(out, *args) == []
    held = benchmarl_reference.RunLock(benchmarl_reference.run_paths(out, "MAPSYNC", "ippo", 1)[0].with_suffix(".lock"))
    assert held.acquire()
    try:
        assert benchmarl_reference.run_plan(out, ["MAPSYNC"], ["ippo"], [1], *TINY_RUN.values()) == []
        assert "MAPSYNC ippo seed 1 is being run by pid" in capsys.readouterr().out
    finally:
        held.release()

    tiny = ["--frames-per-batch", "100", "--num-envs", "4", "--episodes", "2", "--out", str(out)]
    assert benchmarl_reference.main(["cost", "--tasks", "MAPSYNC", "--algorithms", "ippo", *tiny]) == 0
    cost = json.loads((out / benchmarl_reference.COST).read_text())["MAPSYNC"]["ippo"]
    assert cost["iteration_seconds"] == pytest.approx(cost["collection_seconds"] + cost["training_seconds"])
    iterations = math.ceil(benchmarl_reference.FRAMES / 100)
    projected = iterations * cost["iteration_seconds"] + benchmarl_reference.EVALUATIONS * cost["evaluation_seconds"]
    assert cost["projected_run_hours"] == pytest.approx(projected / 3600)
    assert not list(out.glob("*.scratch"))

    assert benchmarl_reference.main(["page", "--out", str(out), "--page", str(page)]) == 0
    text = page.read_text()
    assert f"| mapsync | ippo | {cost['collection_seconds']:.1f} |" in text
    assert f"| 2 | {2 * cost['projected_run_hours']:.1f} |" in text  # seeds 1 and 2 are left
    assert "**Runs:** 1 of the plan's 42 have finished." in text
    assert "| IPPO (BenchMARL) | 1 |" in text and "| IPPO | mapsync | 1 |" in text
    wall_row = next(line for line in text.splitlines() if line.startswith("| mapsync | ippo | 0 | 200 |"))
    assert wall_row.endswith("| — |")  # a run that went through in one attempt resumed nowhere
    assert (out / "profile.png").stat().st_size > 0 and (out / "curves.png").stat().st_size > 0
    merged = json.loads((out / benchmarl_reference.MERGED).read_text())
    assert merged["mrcomm"]["mapsync"]["ippo"]["seed_0"] == run


def test_the_page_names_runs_recorded_at_an_earlier_revision_of_their_env():
    """Runs and scripted rows whose ``env_revision`` is not the env's current one are named with it under their
    task's table; current ones are not."""
    current = env_revision("mrcomm/MapSync-v0")
    runs = [
        {"algorithm": "ippo", "seed": 0, "env_revision": current},
        {"algorithm": "mappo", "seed": 1, "env_revision": "v0 rev 0"},
        {"algorithm": "iql", "seed": 2, "env_revision": current},
    ]
    assert benchmarl_reference._revision_note("MAPSYNC", [runs[0], runs[2]], {"env_revision": current}) == []
    note = " ".join(benchmarl_reference._revision_note("MAPSYNC", runs, {"env_revision": "v0 rev 0"}))
    assert f"Recorded before mrcomm/MapSync-v0's {current}" in note
    assert "MAPPO seed 1, the `random` and paper rows at v0 rev 0." in note
    assert "IPPO" not in note and "IQL" not in note


def test_references_of_an_earlier_revision_are_kept_and_score_the_runs_recorded_there(tmp_path, monkeypatch):
    """A task whose env changed revision gets its references computed again; the old ones stay under ``earlier``,
    and a run is normalised against the references of the revision it ran at (the current ones when that revision
    has no record). A record that names no revision is computed again, and a run record without one is refused. Its
    task table shows the kept revision's scripted rows, labelled with it."""
    paper = benchmarl_reference.default_policy("mrcomm/MapSync-v0")
    computed: list[str] = []

    def results(task, episodes):  # each computation gives other returns: 1 and 3, then 2 and 4, ...
        computed.append(task)
        offset = float(len(computed))
        return {
            name: {"return": [base + offset], "metric": [0.0], "bits": [0.0]}
            for name, base in (("random", 0.0), (paper, 2.0))
        }

    monkeypatch.setattr(benchmarl_reference, "reference_results", results)
    monkeypatch.setattr(benchmarl_reference, "env_revision", lambda env_id: "v0 rev 0")
    out = tmp_path / "benchmark"
    benchmarl_reference.ensure_references(out, ["MAPSYNC"], 2)
    benchmarl_reference.ensure_references(out, ["MAPSYNC"], 2)
    assert computed == ["MAPSYNC"]  # same revision, same episodes: kept
    monkeypatch.setattr(benchmarl_reference, "env_revision", lambda env_id: "v0 rev 1")
    references = benchmarl_reference.ensure_references(out, ["MAPSYNC"], 2)
    assert computed == ["MAPSYNC"] * 2
    assert references == json.loads((out / benchmarl_reference.REFERENCES).read_text())
    assert references["MAPSYNC"]["env_revision"] == "v0 rev 1"
    assert references["MAPSYNC"]["earlier"]["v0 rev 0"]["policies"]["random"]["return"] == [1.0]

    def run(revision):
        return {
            "task": "MAPSYNC",
            "algorithm": "ippo",
            "seed": 0,
            "heldout": {"return": [3.0]},
            "env_revision": revision,
        }

    assert float(benchmarl_reference.run_score(run("v0 rev 0"), references)) == 1.0  # (3 - 1) / (3 - 1)
    assert float(benchmarl_reference.run_score(run("v0 rev 1"), references)) == 0.5  # (3 - 2) / (4 - 2)
    assert float(benchmarl_reference.run_score(run("v0 rev 9"), references)) == 0.5

    records = [
        {**run(revision), "seed": seed, "env_config": {}, "frames": 10, "wall_seconds": 60.0}
        for seed, revision in enumerate(("v0 rev 0", "v0 rev 1"))
    ]
    for record in records:
        record["heldout"].update(metric=[0.0], bits=[0.0])
    text = "\n".join(benchmarl_reference._task_tables(records, references))
    assert "| `random` (v0 rev 0) | – | 1 |" in text and f"| `{paper}` (paper, v0 rev 0) | – | 3 |" in text
    assert "| `random` | – | 2 |" in text and f"| `{paper}` (paper) | – | 4 |" in text
    assert "| IPPO (BenchMARL) | 2 |" in text and "| 0.75" in text  # seeds 1.0 and 0.5
    assert "Their scripted rows at v0 rev 0 are kept" in text

    monkeypatch.setattr(benchmarl_reference, "env_revision", lambda env_id: "v0 rev 2")
    references = benchmarl_reference.ensure_references(out, ["MAPSYNC"], 2)
    assert set(references["MAPSYNC"]["earlier"]) == {"v0 rev 0", "v0 rev 1"}
    assert "earlier" not in references["MAPSYNC"]["earlier"]["v0 rev 1"]

    # a record that names no revision played unknown episodes: it is computed again, not kept as current
    unnamed = {key: value for key, value in references["MAPSYNC"].items() if key not in ("env_revision", "earlier")}
    (out / benchmarl_reference.REFERENCES).write_text(json.dumps({"MAPSYNC": unnamed}))
    references = benchmarl_reference.ensure_references(out, ["MAPSYNC"], 2)
    assert computed == ["MAPSYNC"] * 4 and references["MAPSYNC"]["env_revision"] == "v0 rev 2"

    # a run record without its revision is refused when the page loads it, naming the file
    record_path, json_path = benchmarl_reference.run_paths(out, "MAPSYNC", "ippo", 0)
    record_path.parent.mkdir(parents=True)
    record_path.write_text(json.dumps({key: value for key, value in records[0].items() if key != "env_revision"}))
    json_path.write_text("{}")
    with pytest.raises(ValueError, match=r"seed_0\.json: the run record names no 'env_revision'"):
        benchmarl_reference.load_runs(out)


def test_an_on_policy_run_killed_midway_goes_on_from_its_newest_checkpoint(tmp_path):
    """``kill -9`` once the third of eight batches is checkpointed: the next attempt goes on from a checkpoint, and
    the run's record and marl-eval JSON hold all eight iterations and evaluations, each once. The kill waits for the
    fourth checkpoint's file to appear: only then is the third whole (a file appears when BenchMARL starts writing it,
    and a kill while it writes leaves it cut short, which the attempt after it skips), and BenchMARL keeps it, deleting
    only the oldest of its two before it writes the next."""
    out, run_args = tmp_path / "benchmark", ("MAPSYNC", "ippo", 0, 800, 100, 4, 2)
    record_path, json_path = benchmarl_reference.run_paths(out, *run_args[:3])
    scratch = record_path.with_suffix(".scratch")
    code = (
        "import sys; from pathlib import Path; from mrcomm_env.experiments import benchmarl_reference as b; "
        f"b.run_one(Path(sys.argv[1]), *{run_args!r})"
    )
    child = subprocess.Popen(
        [sys.executable, "-c", code, str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    try:
        deadline = time.monotonic() + 600
        while not list(scratch.glob("*/checkpoints/checkpoint_400.pt")):
            assert child.poll() is None, "the run ended before it was killed"
            assert time.monotonic() < deadline, "no fourth checkpoint in 10 minutes"
            time.sleep(0.05)
    finally:
        child.kill()
        child.wait()
    assert not record_path.exists()

    record = benchmarl_reference.run_one(out, *run_args)
    assert record["frames"] == 800 and record["iterations"] == 8
    [resumed] = record["resumed_at_frames"]
    assert 300 <= resumed < 800 and resumed % 100 == 0  # the third checkpoint, or a later one that is whole
    run = json.loads(json_path.read_text())["mrcomm"]["mapsync"]["ippo"]["seed_0"]
    steps = [run[k] for k in run if k.startswith("step_")]
    assert sorted(step["step_count"] for step in steps) == list(range(100, 900, 100))
    assert run["absolute_metrics"]["return"] == [max(max(step["return"]) for step in steps)]
    assert 0 < record["benchmarl_seconds"] <= record["wall_seconds"]
    assert not scratch.exists()


class _RunsCodeWhenUnpickled:
    """Unpickling this makes a folder: a checkpoint holding it must be refused, never loaded."""

    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return (os.mkdir, (self.path,))


def test_only_a_checkpoint_of_tensors_and_numbers_is_gone_on_from(tmp_path):
    """The newest checkpoint is cut short (a kill while BenchMARL wrote it), the one before holds an object whose
    unpickling runs code: both are refused (``weights_only``) and deleted, and the oldest is chosen."""
    checkpoints = tmp_path / "experiment" / "checkpoints"
    checkpoints.mkdir(parents=True)
    torch.save({"state": {"total_frames": 100}, "weights": torch.zeros(3)}, checkpoints / "checkpoint_100.pt")
    torch.save({"state": _RunsCodeWhenUnpickled(tmp_path / "ran")}, checkpoints / "checkpoint_200.pt")
    whole = (checkpoints / "checkpoint_100.pt").read_bytes()
    (checkpoints / "checkpoint_300.pt").write_bytes(whole[: len(whole) // 2])
    assert benchmarl_reference.loadable_checkpoint(tmp_path) == checkpoints / "checkpoint_100.pt"
    assert not (tmp_path / "ran").exists()
    assert sorted(p.name for p in checkpoints.iterdir()) == ["checkpoint_100.pt"]


@pytest.mark.parametrize(
    "algorithm, note_plan",
    [("iql", {"frames": 800}), ("ippo", {"frames": 400})],  # off-policy: never; on-policy: other arguments
)
def test_a_scratch_folder_is_resumed_only_by_an_on_policy_run_with_its_own_arguments(tmp_path, algorithm, note_plan):
    plan_args = {"frames": 800}
    scratch = tmp_path / "seed_0.scratch"
    checkpoints = scratch / "experiment" / "checkpoints"
    checkpoints.mkdir(parents=True)
    torch.save({"state": {}}, checkpoints / "checkpoint_100.pt")
    (scratch / "experiment" / "experiment.json").write_text("{}")
    (scratch / benchmarl_reference.SCRATCH_PLAN).write_text(json.dumps({"plan": note_plan, "resumed_at_frames": []}))
    resumable = benchmarl_reference.algorithm_config(algorithm).on_policy()
    assert benchmarl_reference.scratch_for(scratch, plan_args, resumable) == (None, {}, [])
    assert sorted(p.name for p in scratch.iterdir()) == [benchmarl_reference.SCRATCH_PLAN]  # a fresh start
    (scratch / benchmarl_reference.SCRATCH_PLAN).write_text(json.dumps({"plan": plan_args, "resumed_at_frames": [300]}))
    checkpoints.mkdir(parents=True)
    torch.save({"state": {}}, checkpoints / "checkpoint_100.pt")
    (scratch / "experiment" / "experiment.json").write_text('{"earlier": 1}')
    expected = (checkpoints / "checkpoint_100.pt", {"earlier": 1}, [300]) if resumable else (None, {}, [])
    assert benchmarl_reference.scratch_for(scratch, plan_args, resumable) == expected


def test_each_iteration_counts_once_in_the_timers_of_a_resumed_run(tmp_path):
    """A resumed run logs again the iterations its killed attempt made after the checkpoint: the last row counts."""
    scalars = tmp_path / "experiment" / "scalars"
    scalars.mkdir(parents=True)
    (scalars / "timers_training_time.csv").write_text("0,1.0\n1,2.0\n2,3.0\n1,20.0\n2,30.0\n3,4.0\n")
    assert benchmarl_reference.timer_rows(tmp_path, "training") == [1.0, 20.0, 30.0, 4.0]


@pytest.mark.parametrize("task", ["MAPSYNC", "CHANNEL_ASSOCIATION"])
def test_heldout_evaluation_plays_the_episodes_the_single_env_plays(task):
    # action 0 for every robot (MapSync: never sync; ChannelAssociation: never emit, so association never completes
    # and the completion time counts as the episode's max_cycles), once as BenchMARL's policy module acts and once as
    # a scripted policy in the single env, on the same seeds: the same metric, bits and return (rewards pass through
    # float32 on the TorchRL side: 2^-24 relative per reward, summed over at most 200 rewards of one sign, so 1e-6
    # relative is ample)
    from mrcomm_env.core.policy import Policy
    from mrcomm_env.experiments.evaluation import evaluate_policy

    class FirstAction:
        def policy(self, td):
            td.set(("robot", "action"), torch.zeros(td["robot", "observation"].shape[:2], dtype=torch.int64))
            return td

    class FirstActionScripted(Policy):
        name = "first_action"

        def act(self, observations, views):
            return dict.fromkeys(observations, 0)

    env_id, episodes = ENV_ID_OF_TASK[task], 3
    ours = benchmarl_reference.evaluate_benchmarl_policy(FirstAction(), task, episodes)
    seeds = list(range(benchmarl_reference.HELDOUT_SEED, benchmarl_reference.HELDOUT_SEED + episodes))
    spec = benchmarl_reference.paper_spec(env_id)
    config = dict(MrcommTask[task].get_from_yaml().config)
    theirs = evaluate_policy(env_id, config, FirstActionScripted(), seeds, spec)
    assert ours["metric"] == theirs["metric"] and ours["bits"] == theirs["bits"]
    assert ours["return"] == pytest.approx(theirs["return"], rel=1e-6)
    if task == "CHANNEL_ASSOCIATION":
        assert ours["metric"] == [float(config["max_cycles"])] * episodes  # never completed: the episode's length


def test_normalised_scores_put_random_at_zero_and_the_paper_at_one():
    references = {
        task: {
            "env_revision": "v0",
            "paper_policy": "paper",
            "policies": {"random": {"return": [-4.0, -2.0]}, "paper": {"return": [1.0]}},
        }
        for task in ("A", "B")
    }
    records = [
        {"task": task, "algorithm": "ippo", "seed": seed, "heldout": {"return": [value]}, "env_revision": "v0"}
        for task, seed, value in (("A", 0, -3.0), ("A", 1, 1.0), ("B", 0, 2.5), ("B", 1, -3.0))
    ]
    matrices, tasks = benchmarl_reference.score_matrices(records, references)
    assert tasks == {"ippo": ["A", "B"]}
    assert matrices["ippo"].tolist() == [[0.0, 1.375], [1.0, 0.0]]  # (seeds × tasks); random's mean is -3


def test_score_matrices_leave_out_a_task_with_fewer_seeds_instead_of_cutting_every_task_to_it():
    """IQL had 3 seeds on two tasks and 1 on a third: cutting every task to one seed left one run a task, and the
    stratified bootstrap of one run a task is a zero-width interval."""
    references = {
        task: {
            "env_revision": "v0",
            "paper_policy": "paper",
            "policies": {"random": {"return": [0.0]}, "paper": {"return": [1.0]}},
        }
        for task in ("A", "B", "C")
    }
    runs = [("A", 0, 0.5), ("A", 1, 0.7), ("A", 2, 0.9), ("B", 0, 1.0), ("B", 1, 1.2), ("B", 2, 1.1), ("C", 1, 0.2)]
    records = [
        {"task": task, "algorithm": "iql", "seed": seed, "heldout": {"return": [value]}, "env_revision": "v0"}
        for task, seed, value in runs
    ]
    matrices, tasks = benchmarl_reference.score_matrices(records, references)
    assert tasks == {"iql": ["A", "B"]}
    assert matrices["iql"].tolist() == [[0.5, 1.0], [0.7, 1.2], [0.9, 1.1]]
    assert benchmarl_reference.left_out(records, tasks) == {"iql": ["C"]}
    # one seed on every task still counts every task
    single = [r for r in records if r["seed"] == 1]
    matrices, tasks = benchmarl_reference.score_matrices(single, references)
    assert tasks == {"iql": ["A", "B", "C"]} and matrices["iql"].tolist() == [[0.7, 1.2, 0.2]]


def test_reference_benchmark_refuses_bad_arguments_in_one_line(tmp_path, capsys):
    assert (
        benchmarl_reference.main(["run", "--frames", "100", "--frames-per-batch", "200", "--out", str(tmp_path)]) == 2
    )
    assert capsys.readouterr().err.strip() == "benchmark: argument '--frames' must be at least '--frames-per-batch'"
    with pytest.raises(SystemExit) as exit_info:
        benchmarl_reference.main(["run", "--jobs", "0"])
    assert exit_info.value.code == 2
    assert "argument '--jobs' must be an integer ≥ 1, got '0'" in capsys.readouterr().err
