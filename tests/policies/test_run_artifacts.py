"""Run folders and pretrained models load without running code from them (``agents/artifacts.py``).

A pickle planted in any file a loader reads — each JSON file, the statistics, each entry of ``model.zip`` and
each pickled entry of its ``data`` — must run nothing (a marker file its payload would create stays absent) and
end every command with a one-line error: ``evaluate --policy ppo:RUN`` and ``--policy pretrained``,
``train --resume``, a sweep rerun, and the Python API. Old folders (pickles) are refused unless the user opts in,
and ``convert-run`` rewrites them; the rebuilt models and statistics are exactly the ones SB3's pickles held."""

from __future__ import annotations

import base64
import io
import json
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from mrcomm_agents import learned
from mrcomm_agents.artifacts import (
    PICKLED_STATISTICS_FILE,
    REBUILT,
    SERIALIZED,
    STATISTICS_FILE,
    PickleRefused,
    RunError,
    load_model,
    load_statistics,
    pickled_entries,
    save_statistics,
)
from mrcomm_agents.learned import LearnedPolicy, load_policy, model_card
from mrcomm_agents.training import TrainConfig, algorithm_class, config_from_record, model_spec, train
from mrcomm_env.experiments.cli import main
from mrcomm_env.registry import env_ids

torch.set_num_threads(1)

ENV = "ChannelAssociation-v0"
ENV_KWARGS = {"n_robots": 3, "max_cycles": 10}
HYPER = {"n_steps": 16, "batch_size": 24, "n_epochs": 1}
ROLLOUT = HYPER["n_steps"] * ENV_KWARGS["n_robots"]


class Payload:
    """Unpickled, it opens (and so creates) the marker file: code from the run folder ran."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return open, (self.marker, "w")


def tiny_config(**kw) -> TrainConfig:
    settings = dict(
        env_id=ENV,
        timesteps=2 * ROLLOUT,
        seed=1,
        env_kwargs=dict(ENV_KWARGS),
        hyperparams=dict(HYPER),
        n_envs=1,
        net_arch=[8],
        checkpoint_every=ROLLOUT,
        eval_episodes=0,
    )
    settings.update(kw)
    return TrainConfig(**settings)


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    """A finished PPO run with two checkpoints, written by the code under test."""
    return train(tiny_config(), tmp_path_factory.mktemp("run") / "run", progress=False)


# ------------------------------------------------------------------------------------------------ planting
def data_entries(model: Path) -> list[str]:
    """The entries of ``data`` that SB3 would unpickle if they were still pickles (written as rebuilt markers)."""
    with zipfile.ZipFile(model) as archive:
        data = json.loads(archive.read("data"))
    return [k for k, v in data.items() if isinstance(v, dict) and (REBUILT in v or SERIALIZED in v)]


def rewrite_member(model: Path, member: str, payload: bytes) -> None:
    with zipfile.ZipFile(model) as archive:
        members = [(info, archive.read(info)) for info in archive.infolist()]
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for info, content in members:
            archive.writestr(info, payload if info.filename == member else content)
    model.write_bytes(buffer.getvalue())


def plant(folder: Path, target: str, marker: Path) -> None:
    """Put the payload in ``target`` of ``folder``: a file name, ``model.zip:MEMBER`` or ``model.zip:data:KEY``."""
    raw = pickle.dumps(Payload(marker))
    if target == PICKLED_STATISTICS_FILE:  # an old folder: the pickle VecNormalize.save writes, and no JSON
        (folder / STATISTICS_FILE).unlink(missing_ok=True)
        (folder / target).write_bytes(raw)
    elif target.startswith("model.zip:data:"):
        key = target.split(":", 2)[2]
        model = folder / "model.zip"
        with zipfile.ZipFile(model) as archive:
            data = json.loads(archive.read("data"))
        data[key] = {":type:": "<class 'object'>", SERIALIZED: base64.b64encode(raw).decode()}
        rewrite_member(model, "data", json.dumps(data).encode())
    elif target.startswith("model.zip:"):
        member = target.split(":", 1)[1]
        if member.endswith(".pth"):
            buffer = io.BytesIO()
            torch.save(Payload(marker), buffer)  # torch's own format, the payload in its data.pkl
            raw = buffer.getvalue()
        rewrite_member(folder / "model.zip", member, raw)
    else:
        (folder / target).write_bytes(raw)


MODEL_MEMBERS = ["data", "policy.pth", "policy.optimizer.pth", "pytorch_variables.pth", "_stable_baselines3_version"]
MODEL_MEMBERS += ["system_info.txt"]


def targets(model: Path, files: list[str]) -> list[str]:
    entries = [f"model.zip:data:{key}" for key in [*data_entries(model), "an_entry_of_its_own"]]
    return files + [f"model.zip:{m}" for m in MODEL_MEMBERS] + entries


def assert_refused_in_one_line(code: int, capsys, marker: Path, target: str) -> None:
    err = capsys.readouterr().err.strip()
    assert not marker.exists(), f"code ran from {target}"
    assert code != 0, target
    assert err.startswith("mrcomm: error:") and "\n" not in err, (target, err)


def test_the_planted_target_lists_cover_every_entry_sb3_would_unpickle(finished_run):
    # the lists below are derived from the run: a new pickled entry of SB3's shows up here
    entries = data_entries(finished_run / "model.zip")
    assert {"policy_class", "observation_space", "action_space", "lr_schedule", "clip_range"} <= set(entries)
    assert pickled_entries(finished_run / "model.zip") == []  # markers only: nothing pickled is written
    assert not list(finished_run.rglob("*.pkl"))


@pytest.mark.parametrize("api", ["cli", "python"])
def test_evaluate_a_run_with_a_planted_pickle_runs_no_code(finished_run, tmp_path, capsys, api):
    files = ["config.json", STATISTICS_FILE, PICKLED_STATISTICS_FILE]
    for i, target in enumerate(targets(finished_run / "model.zip", files)):
        run = tmp_path / f"run{i}"
        shutil.copytree(finished_run, run)
        marker = tmp_path / f"marker{i}"
        plant(run, target, marker)
        if api == "cli":
            code = main(["evaluate", ENV, "--policy", f"ppo:{run}", "--episodes", "1", "--quiet"])
            assert_refused_in_one_line(code, capsys, marker, target)
        else:
            with pytest.raises(RunError) as caught:
                LearnedPolicy(run, ENV)
            assert not marker.exists(), f"code ran from {target}"
            assert "\n" not in str(caught.value), target


def test_resume_with_a_planted_pickle_in_the_newest_checkpoint_runs_no_code(finished_run, tmp_path, capsys):
    newest = sorted((finished_run / "checkpoints").glob("step-*"))[-1]
    files = ["state.json", STATISTICS_FILE, PICKLED_STATISTICS_FILE]
    cases = [(f"checkpoint {t}", t) for t in targets(newest / "model.zip", files)]
    cases += [("run config.json", "config.json"), ("run done.json", "done.json")]
    for i, (label, target) in enumerate(cases):
        run = tmp_path / f"run{i}"
        shutil.copytree(finished_run, run)
        marker = tmp_path / f"marker{i}"
        folder = run if label.startswith("run ") else run / "checkpoints" / newest.name
        plant(folder, target, marker)
        argv = ["train", ENV, "--resume", "--out", str(run), "--timesteps", str(3 * ROLLOUT), "--quiet"]
        assert_refused_in_one_line(main(argv), capsys, marker, label)


def test_a_pickle_planted_in_the_newest_checkpoint_is_refused_not_skipped_for_the_older_one(finished_run, tmp_path):
    # an older checkpoint serves when the newest was damaged by a crash, but a pickle is no crash: it is refused
    newest = sorted((finished_run / "checkpoints").glob("step-*"))[-1]
    run = tmp_path / "run"
    shutil.copytree(finished_run, run)
    plant(run / "checkpoints" / newest.name, "model.zip:policy.pth", tmp_path / "marker")
    with pytest.raises(PickleRefused):
        train(None, run, resume=True, progress=False, requested={"timesteps": 3 * ROLLOUT})
    assert not (tmp_path / "marker").exists()


def test_a_sweep_rerun_with_a_planted_pickle_runs_no_code(tmp_path, capsys):
    out = tmp_path / "sweep"
    config = tmp_path / "config.json"
    config.write_text(json.dumps({"ppo": {**HYPER, "n_envs": 1, "net_arch": [8], "eval_episodes": 0}}))
    argv = ["train", ENV, "--seeds", "0", "--timesteps", str(ROLLOUT), "--out", str(out), "--config", str(config)]
    argv += ["--param", "n_robots=3", "--param", "max_cycles=10", "--eval-episodes", "1", "--workers", "1", "--quiet"]
    assert main(argv) == 0
    capsys.readouterr()
    (run,) = [p.parent for p in out.rglob("done.json")]
    pristine = tmp_path / "pristine"
    shutil.copytree(run, pristine)
    for i, target in enumerate(["config.json", STATISTICS_FILE, "model.zip:policy.pth", "model.zip:data:action_space"]):
        shutil.rmtree(run)
        shutil.copytree(pristine, run)
        marker = tmp_path / f"marker{i}"
        plant(run, target, marker)
        assert_refused_in_one_line(main(argv), capsys, marker, target)


def test_the_pretrained_model_with_a_planted_pickle_runs_no_code(tmp_path, capsys, monkeypatch):
    shipped = learned.pretrained_dir(ENV)
    files = ["card.json", "config.json", STATISTICS_FILE, PICKLED_STATISTICS_FILE]
    for i, target in enumerate(targets(shipped / "model.zip", files)):
        root = tmp_path / f"pretrained{i}"
        shutil.copytree(shipped, root / shipped.name)
        monkeypatch.setattr(learned, "PRETRAINED_DIR", root)
        marker = tmp_path / f"marker{i}"
        plant(root / shipped.name, target, marker)
        code = main(["evaluate", ENV, "--policy", "pretrained", "--episodes", "1", "--quiet"])
        assert_refused_in_one_line(code, capsys, marker, target)
        with pytest.raises(RunError):
            load_policy("pretrained", ENV)
        assert not marker.exists()


# ------------------------------------------------------------------------------------------------ formats
def sb3_native_folder(run: Path, out: Path) -> Path:
    """``run`` as the library wrote runs before ``agents/artifacts.py``: SB3's own model.zip (pickled entries)
    and VecNormalize's pickle, in the run folder and in every checkpoint."""
    shutil.copytree(run, out)
    spec = model_spec(config_from_record(json.loads((run / "config.json").read_text())))
    for folder in [out, *sorted((out / "checkpoints").glob("step-*"))]:
        load_model(folder / "model.zip", spec).save(str(folder / "model.zip"))
        with open(folder / PICKLED_STATISTICS_FILE, "wb") as handle:
            pickle.dump(load_statistics(folder / STATISTICS_FILE), handle)
        (folder / STATISTICS_FILE).unlink()
    return out


def test_an_old_folder_is_refused_then_loads_with_the_opt_in_and_converts(finished_run, tmp_path, capsys):
    old = sb3_native_folder(finished_run, tmp_path / "old")
    assert pickled_entries(old / "model.zip")  # SB3's own archive pickles its policy class, spaces, schedules
    evaluate = ["evaluate", ENV, "--policy", f"ppo:{old}", "--episodes", "2", "--quiet", "--json"]
    assert main([*evaluate, str(tmp_path / "refused.json")]) != 0
    err = capsys.readouterr().err.strip()
    assert "vecnormalize.pkl" in err and "--trust-pickle" in err and "convert-run" in err and "\n" not in err
    assert main(["train", ENV, "--resume", "--out", str(old), "--timesteps", str(3 * ROLLOUT), "--quiet"]) != 0
    assert "--trust-pickle" in capsys.readouterr().err
    assert main([*evaluate, str(tmp_path / "trusted.json"), "--trust-pickle"]) == 0
    # convert-run needs the same opt-in: it has to unpickle the statistics to convert them
    assert main(["convert-run", str(old)]) != 0
    assert "--trust-pickle" in capsys.readouterr().err
    assert main(["convert-run", str(old), "--trust-pickle"]) == 0
    assert not list(old.rglob("*.pkl")) and pickled_entries(old / "model.zip") == []
    for checkpoint in (old / "checkpoints").glob("step-*"):
        assert pickled_entries(checkpoint / "model.zip") == [] and (checkpoint / STATISTICS_FILE).exists()
    assert main([*evaluate, str(tmp_path / "converted.json")]) == 0
    trusted = json.loads((tmp_path / "trusted.json").read_text())["metrics"]
    converted = json.loads((tmp_path / "converted.json").read_text())["metrics"]
    assert converted == trusted
    # and the converted run resumes
    assert main(["train", ENV, "--resume", "--out", str(old), "--timesteps", str(3 * ROLLOUT), "--quiet"]) == 0


@pytest.mark.parametrize(
    "env_id, settings",
    [
        (ENV, {}),
        (ENV, {"algo": "dqn", "hyperparams": {"learning_starts": 0, "buffer_size": 64, "train_freq": 2}}),
        ("RendezvousMapping-v0", {"algo": "maskable_ppo", "env_kwargs": {"max_cycles": 6}}),
        ("MultiHop-v0", {"policy": "candidate_subset", "env_kwargs": {"grid_side": 3, "max_cycles": 6}}),
    ],
    ids=["ppo", "dqn", "maskable_ppo", "candidate_subset"],
)
def test_a_rebuilt_model_equals_the_one_sb3_unpickles(tmp_path, env_id, settings):
    """What load_model rebuilds instead of unpickling (policy class, spaces, schedules, buffers) is what SB3's
    pickles held: the same weights, optimizer state, schedules and predictions."""
    settings = {"env_kwargs": dict(ENV_KWARGS), "hyperparams": dict(HYPER), **settings}
    config = tiny_config(env_id=env_id, timesteps=ROLLOUT, **settings)
    run = train(config, tmp_path / "run", progress=False)
    rebuilt = LearnedPolicy(run, env_id)
    native = tmp_path / "native.zip"
    rebuilt.model.save(str(native))  # SB3's own format, its entries pickled
    custom = {"policy_class": type(rebuilt.model.policy)}  # the classes' module paths are ours to name
    unpickled = algorithm_class(config.algo).load(str(native), device="cpu", custom_objects=custom)
    a, b = rebuilt.model, unpickled
    assert a.observation_space == b.observation_space and a.action_space == b.action_space
    assert type(a.policy) is type(b.policy)
    for (name, x), (_, y) in zip(a.policy.state_dict().items(), b.policy.state_dict().items(), strict=True):
        assert torch.equal(x, y), name
    assert str(a.policy.optimizer.state_dict()) == str(b.policy.optimizer.state_dict())
    for progress in (1.0, 0.5, 0.0):
        assert a.lr_schedule(progress) == b.lr_schedule(progress)
        for name in ("clip_range", "exploration_schedule"):
            if hasattr(b, name):
                assert getattr(a, name)(progress) == getattr(b, name)(progress), name
    for name in ("rollout_buffer_class", "replay_buffer_class", "train_freq", "policy_kwargs", "n_steps", "gamma"):
        if hasattr(b, name):
            assert getattr(a, name) == getattr(b, name), name
    obs = np.random.default_rng(0).random((6, *a.observation_space.shape)).astype(np.float32)
    extra = {"action_masks": np.ones((6, a.action_space.n), dtype=bool)} if config.algo == "maskable_ppo" else {}
    assert np.array_equal(
        a.predict(obs, deterministic=True, **extra)[0], b.predict(obs, deterministic=True, **extra)[0]
    )


def test_statistics_come_back_exactly(finished_run, tmp_path):
    from stable_baselines3.common.vec_env import VecNormalize

    stats = load_statistics(finished_run / STATISTICS_FILE)
    pickled = pickle.loads(pickle.dumps(stats))  # what VecNormalize.save would have held
    assert isinstance(stats, VecNormalize)
    obs = np.random.default_rng(1).normal(size=(7, *stats.obs_rms.mean.shape)).astype(np.float32) * 3
    assert np.array_equal(stats.normalize_obs(obs), pickled.normalize_obs(obs))
    # a float whose shortest text is long comes back to the same bits
    stats.obs_rms.mean[0] = 0.1 + 0.2
    save_statistics(stats, tmp_path / STATISTICS_FILE)
    again = load_statistics(tmp_path / STATISTICS_FILE)
    assert np.array_equal(again.obs_rms.mean, stats.obs_rms.mean) and again.obs_rms.count == stats.obs_rms.count
    assert np.array_equal(again.obs_rms.var, stats.obs_rms.var) and again.ret_rms.var == stats.ret_rms.var


def test_run_files_are_standard_json_with_an_undefined_metric_as_null(tmp_path):
    """A run's JSON files (``best.json``'s held-out metrics, ``warm_start.json``, ``state.json``) must read in any
    JSON reader: a metric the episode left undefined (nan) is ``null``, not Python's ``NaN``."""
    from mrcomm_agents.artifacts import write_json

    record = {
        "heldout": {"propagation_time_8x8": float("nan"), "coverage_cost": np.float64("nan"), "mean_age": 56.5},
        "agreement": [1.0, np.float32(0.5), float("inf")],
        "steps": np.int64(3),
    }
    write_json(tmp_path / "best.json", record)

    def refuse(constant):
        raise ValueError(f"non-standard JSON constant {constant}")

    back = json.loads((tmp_path / "best.json").read_text(), parse_constant=refuse)
    assert back == {
        "heldout": {"propagation_time_8x8": None, "coverage_cost": None, "mean_age": 56.5},
        "agreement": [1.0, 0.5, None],
        "steps": 3,
    }


@pytest.mark.parametrize("env_id", [e for e in env_ids() if learned.has_pretrained(e)])
def test_the_shipped_models_keep_the_held_out_metric_on_their_cards(env_id):
    """Re-exported in the safe formats, every shipped model plays the card's held-out episodes to the card's
    metric exactly (the same policy, the same statistics, the same episodes)."""
    from mrcomm_env.experiments.evaluation import evaluate_policy
    from mrcomm_env.experiments.runs import comparison_spec

    card = model_card(env_id)
    heldout = card["heldout"]
    seeds = list(range(heldout["first_seed"], heldout["first_seed"] + heldout["episodes"]))
    result = evaluate_policy(
        env_id, card["env_kwargs"], load_policy("pretrained", env_id), seeds, comparison_spec(env_id)
    )
    assert float(np.mean(result["metric"])) == heldout["metric"]
    folder = learned.pretrained_dir(env_id)
    assert not list(folder.glob("*.pkl")) and pickled_entries(folder / "model.zip") == []
