"""The ``mrcomm`` command as users and other tools call it."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from mrcomm_baselines import default_policy, policy_names
from mrcomm_env.core.stats import mean_ci95
from mrcomm_env.experiments import bench
from mrcomm_env.experiments.arguments import parse_params
from mrcomm_env.experiments.cli import main
from mrcomm_env.experiments.commands import evaluate, reproduce
from mrcomm_env.registry import env_class, env_ids


def test_parse_params_reads_json_where_possible():
    got = parse_params(["a=3", "b=0.5", "c=true", "d=inf", 'e="inf"', "f=[1, 2]", "g=grid", "h=null"])
    assert got == {"a": 3, "b": 0.5, "c": True, "d": "inf", "e": "inf", "f": [1, 2], "g": "grid", "h": None}
    with pytest.raises(ValueError, match="key=value"):
        parse_params(["novalue"])


def test_list_names_every_env_policy_and_reproduction(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for env_id in env_ids():
        assert env_id in out and env_class(env_id).DESCRIPTION in out
        for name in policy_names(env_id):
            assert name in out


@pytest.mark.parametrize("env_id", env_ids())
def test_evaluate_writes_json_of_stable_shape(env_id, tmp_path, capsys):
    path = tmp_path / "eval.json"
    short = env_id.split("/", 1)[1]  # ids work without the namespace
    code = main(
        [
            "evaluate",
            short,
            "--policy",
            default_policy(env_id),
            "--episodes",
            "3",
            "--seed",
            "5",
            "--param",
            "max_cycles=15",
            "--json",
            str(path),
            "--quiet",
        ]
    )
    assert code == 0
    record = json.loads(path.read_text())
    assert set(record) == {"env", "policy", "episodes", "seed", "params", "policy_params", "metrics"}
    assert record["env"] == env_id and record["episodes"] == 3 and record["seed"] == 5
    assert record["params"] == {"max_cycles": 15}
    assert set(env_class(env_id).METRICS) <= set(record["metrics"])
    for m in record["metrics"].values():
        assert set(m) == {"mean", "ci95", "values"} and len(m["values"]) == 3
        finite = [v for v in m["values"] if v is not None and np.isfinite(v)]
        if finite:
            mean, half = mean_ci95(finite)
            assert m["mean"] == pytest.approx(mean) and m["ci95"] == pytest.approx(half)
    table = capsys.readouterr().out
    assert "±" in table and "bits_sent" in table


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["evaluate", "Nope-v0", "--policy", "x"], "valid ids are"),
        (["evaluate", env_ids()[0], "--policy", "no_such_policy"], "valid policies are"),
        (
            ["evaluate", env_ids()[0], "--policy", default_policy(env_ids()[0]), "--param", "bogus=1"],
            "valid arguments are",
        ),
        (["reproduce"], "--all"),
    ],
)
def test_bad_input_exits_nonzero_listing_valid_choices(argv, message, capsys):
    assert main(argv) != 0
    assert message in capsys.readouterr().err


def test_console_script_exit_code_on_unknown_id():
    proc = subprocess.run(
        [sys.executable, "-m", "mrcomm_env.experiments.cli", "evaluate", "Nope-v0", "--policy", "x"],
        capture_output=True,
        text=True,
    )
    assert proc.returncode != 0 and "valid ids are" in proc.stderr


def test_a_reader_that_stops_early_gets_silence_and_the_shells_sigpipe_status():
    # `mrcomm list | head -1`: the reader closes the pipe before the command writes
    proc = subprocess.Popen(
        [sys.executable, "-m", "mrcomm_env.experiments.cli", "list"], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    proc.stdout.close()
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 141
    assert err == b""


def test_bench_writes_json_with_ratio(tmp_path):
    pytest.importorskip("mpe2")
    out = tmp_path / "bench.json"
    env_id = env_ids()[0]
    assert main(["bench", env_id, "--runs", "1", "--seconds", "0.2", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    entry = data["envs"][env_id]
    assert data["reference"]["env_steps_per_s"] > 0 and entry["env_steps_per_s"] > 0
    assert entry["ratio_to_reference"] == pytest.approx(entry["env_steps_per_s"] / data["reference"]["env_steps_per_s"])


def test_bench_train_slots_sets_the_copies_of_the_reference_and_of_each_env(tmp_path):
    pytest.importorskip("mpe2")
    out = tmp_path / "bench.json"
    argv = ["bench", "ChannelAssociation-v0", "--param", "max_cycles=8", "--train", "--train-slots", "24"]
    assert main([*argv, "--train-timesteps", "64", "--runs", "1", "--seconds", "0.1", "--out", str(out)]) == 0
    train = json.loads(out.read_text())["train"]
    # 8 copies of the 3-agent reference, 2 copies of the 12-robot field (one batch: its copy-axis world)
    assert train["reference"]["slots"] == 24
    assert train["envs"]["mrcomm/ChannelAssociation-v0"]["slots"] == 24
    assert main([*argv[:-1], "0", "--out", str(out)]) != 0  # a slot count must be positive


def test_bench_train_compares_each_env_with_the_reference_at_its_own_slot_count(tmp_path):
    """AsyncCL's 5 robots fill 10 slots of the 12 asked for: its ratio is to 3 copies of the reference (9 slots),
    measured beside the 4 copies (12 slots) the other envs meet."""
    pytest.importorskip("mpe2")
    out = tmp_path / "bench.json"
    argv = ["bench", "AsyncCL-v0", "MapSync-v0", "--param", "max_cycles=8", "--train", "--train-slots", "12"]
    assert main([*argv, "--train-timesteps", "64", "--runs", "1", "--seconds", "0.1", "--out", str(out)]) == 0
    train = json.loads(out.read_text())["train"]
    assert set(train["references"]) == {"9", "12"} and train["reference"] == train["references"]["12"]
    for env_id, slots, reference_slots in (("AsyncCL-v0", 10, 9), ("MapSync-v0", 12, 12)):
        entry = train["envs"][f"mrcomm/{env_id}"]
        reference = train["references"][str(reference_slots)]
        assert entry["slots"] == slots and entry["reference_slots"] == reference_slots
        assert entry["reference_agent_steps_per_s"] == reference["agent_steps_per_s"]
        assert entry["ratio_to_reference"] == pytest.approx(entry["agent_steps_per_s"] / reference["agent_steps_per_s"])
        # the ceiling: the same agent-steps over PPO's own time only (the wall time outside the env's stepping)
        ppo_seconds = entry["seconds"] * (1 - entry["env_step_share"])
        ceiling = entry["agent_steps"] / ppo_seconds / reference["agent_steps_per_s"]
        assert entry["ratio_ceiling"] == pytest.approx(ceiling) and entry["ratio_ceiling"] > entry["ratio_to_reference"]


def test_bench_train_shipped_runs_each_env_as_its_training_configuration_does(tmp_path):
    """``--train-shipped``: the env arguments and copies of agents/configs (``--param`` on top), against the
    reference at about the same slot count; MaskablePPO's configuration too (RendezvousMapping)."""
    pytest.importorskip("mpe2")
    from mrcomm_agents.training import CONFIG_DIR

    out = tmp_path / "bench.json"
    argv = ["bench", "MapSync-v0", "RendezvousMapping-v0", "--param", "max_cycles=8", "--train-shipped"]
    assert main([*argv, "--train-timesteps", "64", "--runs", "1", "--seconds", "0.1", "--out", str(out)]) == 0
    train = json.loads(out.read_text())["train"]
    # SB3's side of each: both comparisons train IPPO, so the SB3 path is the config's SB3 section ("ppo", or
    # RendezvousMapping's "maskable_ppo")
    for name, n_agents, algo in (("MapSync-v0", 2, "ppo"), ("RendezvousMapping-v0", 10, "maskable_ppo")):
        config = json.loads((CONFIG_DIR / f"{name}.json").read_text())
        entry = train["shipped"][f"mrcomm/{name}"]
        assert entry["shipped_algo"] == algo and entry["n_envs"] == config[algo]["n_envs"]
        assert entry["env_kwargs"] == {**config[algo].get("env_kwargs", {}), "max_cycles": 8}
        assert entry["slots"] == config[algo]["n_envs"] * n_agents
        reference = train["references"][str(entry["reference_slots"])]
        assert abs(entry["reference_slots"] - entry["slots"]) <= 1  # copies of the 3-agent reference
        assert entry["ratio_to_reference"] == pytest.approx(entry["agent_steps_per_s"] / reference["agent_steps_per_s"])
    assert "mrcomm/MapSync-v0" in train["envs"]  # --train's own figures as well


@pytest.mark.xdist_group("processes")
def test_bench_batched_steps_each_batch_size_in_its_own_process(tmp_path, capsys):
    pytest.importorskip("mpe2")
    out = tmp_path / "bench.json"
    argv = ["bench", "MapSync-v0", "--param", "max_cycles=3", "--batched", "--copies", "1", "3"]
    assert main([*argv, "--runs", "1", "--seconds", "0.1", "--warmup", "0", "--out", str(out)]) == 0
    batched = json.loads(out.read_text())["batched"]["mrcomm/MapSync-v0"]
    assert set(batched) == {"1", "3"}
    for copies, result in batched.items():
        assert result["n_copies"] == int(copies) and result["n_agents"] == 2 and result["finite"]
        # max_cycles=3: the copies reset on their own within the timed steps
        assert result["steps"] >= 2 and result["agent_steps_per_s"] > 0 and result["peak_rss_mb"] > 0
        assert result["agent_steps_per_s"] == pytest.approx(result["env_steps_per_s"] * 2)
        assert result["copy_axis_world"] is (copies != "1")  # a batch of one steps its env object
    assert batched["3"]["speedup_over_smallest"] == pytest.approx(
        batched["3"]["agent_steps_per_s"] / batched["1"]["agent_steps_per_s"]
    )
    assert "batch  mrcomm/MapSync-v0 M=3 (one copy-axis world, " in capsys.readouterr().out


@pytest.mark.xdist_group("processes")
def test_bench_sweep_times_each_backend_on_identical_results(tmp_path, monkeypatch, capsys):
    from mrcomm_env.experiments import bench

    monkeypatch.setattr(bench, "SWEEP_TASKS", 3)  # the timing is not what this test checks: keep it short
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray → ImportError, wherever this test runs
    out = tmp_path / "bench.json"
    argv = ["bench", "--sweep", "MapSync-v0", "--param", "max_cycles=20", "--runs", "1", "--out", str(out)]
    assert main(argv) == 0
    sweep = json.loads(out.read_text())["sweep"]
    assert sweep["env_id"] == "mrcomm/MapSync-v0" and sweep["tasks"] == 3 and sweep["params"] == {"max_cycles": 20}
    local = [sweep["backends"]["workers 1"], sweep["backends"]["workers 2"]]
    assert all(b["identical_to_serial"] and b["sweep_s"] > 0 and b["overhead_s"] >= 0 and b["cores"] > 0 for b in local)
    assert local[0]["speedup"] == 1 and local[1]["speedup"] == pytest.approx(local[0]["sweep_s"] / local[1]["sweep_s"])
    assert "mrcomm-env[ray]" in sweep["backends"]["ray 2 CPUs"]["skipped"]
    assert "sweep  ray 2 CPUs: skipped" in capsys.readouterr().out


def test_bench_sweep_times_one_env(tmp_path, capsys, no_episode):
    argv = ["bench", "--sweep", *env_ids()[:2], "--out", str(tmp_path / "bench.json")]
    assert main(argv) == 2
    assert "--sweep times one env" in _one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "bench.json").exists()


# ---------------------------------------------------------------------------------------------- errors
def _one_error_line(err: str) -> str:
    """The CLI's stderr on an error: exactly one line, no traceback."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def _evaluate_argv(*extra: str) -> list[str]:
    env_id = env_ids()[0]
    return ["evaluate", env_id, "--policy", default_policy(env_id), "--param", "max_cycles=3", "--quiet", *extra]


@pytest.fixture
def no_episode(monkeypatch):
    """Fails the test if any episode or timed run starts: input errors must be found before the work."""
    from mrcomm_env.experiments import evaluation

    def forbidden(*args, **kwargs):
        raise AssertionError("the work started before the bad input was reported")

    monkeypatch.setattr(evaluation, "run_episode", forbidden)
    monkeypatch.setattr(evaluation, "steps_per_second", forbidden)
    monkeypatch.setattr(bench, "steps_per_second", forbidden)  # the bench's own name for it


@pytest.mark.parametrize("seed", ["-1", "1.5", "abc", "1e3"])
def test_bad_seed_is_one_line(seed, capsys, no_episode):
    assert main(_evaluate_argv("--seed", seed)) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "--seed" in line and "integer ≥ 0" in line and repr(seed) in line


@pytest.mark.parametrize(
    ("flag", "value", "allowed"),
    [("--episodes", "0", "integer ≥ 1"), ("--episodes", "-3", "integer ≥ 1"), ("--episodes", "two", "integer ≥ 1")],
)
def test_bad_episode_count_is_one_line(flag, value, allowed, capsys, no_episode):
    assert main(_evaluate_argv(flag, value)) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert flag in line and allowed in line


@pytest.mark.parametrize(
    ("flag", "value", "allowed"),
    [
        ("--runs", "0", "integer ≥ 1"),
        ("--runs", "2.5", "integer ≥ 1"),
        ("--seconds", "-1", "> 0"),
        ("--seconds", "0", "> 0"),
        ("--seconds", "nan", "finite"),
        ("--seconds", "inf", "finite"),
        ("--warmup", "-1", "≥ 0"),
    ],
)
def test_bad_bench_numbers_are_rejected_in_one_line(flag, value, allowed, tmp_path, capsys, no_episode):
    argv = ["bench", env_ids()[0], flag, value, "--out", str(tmp_path / "bench.json")]
    assert main(argv) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert flag in line and allowed in line
    assert not (tmp_path / "bench.json").exists()


def test_bench_checks_every_param_before_timing(tmp_path, capsys, no_episode):
    argv = ["bench", *env_ids(), "--param", "bogus=1", "--runs", "1", "--out", str(tmp_path / "b.json")]
    assert main(argv) == 2
    assert "valid arguments are" in _one_error_line(capsys.readouterr().err)


def test_bench_train_shipped_needs_a_shipped_configuration_before_timing(tmp_path, capsys, monkeypatch, no_episode):
    monkeypatch.setattr("mrcomm_env.experiments.runs.agent_config_dir", lambda: tmp_path)  # no agents/configs here
    argv = ["bench", "MapSync-v0", "--train-shipped", "--runs", "1", "--out", str(tmp_path / "b.json")]
    assert main(argv) == 2
    assert "has no learning configuration" in _one_error_line(capsys.readouterr().err)


def test_the_comparison_reads_the_configs_the_trainer_reads():
    # found without importing the agents package (BenchMARL's venv has no SB3), yet the trainer's own folder
    from mrcomm_agents.training import CONFIG_DIR
    from mrcomm_env.experiments.runs import agent_config_dir

    assert agent_config_dir() == CONFIG_DIR and (CONFIG_DIR / "MapSync-v0.json").is_file()


@pytest.fixture
def blocked_dir(tmp_path):
    """A path nothing can be written under, whoever runs the test (root included): its parent is a file."""
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    return blocker / "sub"


def test_unwritable_json_is_reported_before_any_episode(blocked_dir, capsys, no_episode):
    assert main(_evaluate_argv("--json", str(blocked_dir / "eval.json"))) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "--json" in line and "not writable" in line


def test_json_path_that_is_a_directory_is_rejected(tmp_path, capsys, no_episode):
    assert main(_evaluate_argv("--json", str(tmp_path))) == 2
    assert "is a directory" in _one_error_line(capsys.readouterr().err)


def test_unwritable_bench_out_is_reported_before_timing(blocked_dir, capsys, no_episode):
    assert main(["bench", env_ids()[0], "--runs", "1", "--out", str(blocked_dir / "bench.json")]) == 2
    assert "--out" in _one_error_line(capsys.readouterr().err)


def test_unwritable_reproduce_out_is_reported_before_any_reproduction(blocked_dir, capsys, monkeypatch):
    monkeypatch.setattr(reproduce, "run_reproduction", lambda *a, **k: pytest.fail("reproduction started"))
    assert main(["reproduce", env_ids()[0], "--tiny", "--out", str(blocked_dir)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "--out" in line and "not writable" in line


def test_policy_that_does_not_fit_the_env_is_reported_before_any_episode(capsys, no_episode):
    # AsyncCL's scheme policies need their mode among the env's 'modes'; found by one reset before the episodes
    argv = ["evaluate", "AsyncCL-v0", "--policy", "scheme1", "--param", 'modes=["silent"]', "--quiet"]
    assert main(argv) == 2
    assert "scheme1" in _one_error_line(capsys.readouterr().err)


def test_huge_mode_number_is_one_line(capsys):
    # issue 11: "scheme2_q" followed by 25 nines overflowed an integer conversion deep inside the env
    argv = [
        "evaluate",
        "AsyncCL-v0",
        "--policy",
        "random",
        "--episodes",
        "1",
        "--quiet",
        "--param",
        "max_cycles=2",
        "--param",
        'modes=["scheme2_q' + "9" * 25 + '"]',
    ]
    assert main(argv) == 2
    assert _one_error_line(capsys.readouterr().err).startswith("mrcomm: error: ")


@pytest.mark.parametrize(
    ("raised", "code", "words"),
    [
        (MemoryError("Unable to allocate 7.63 GiB for an array with shape (2000, 2000, 256)"), 1, "out of memory"),
        (OverflowError("int too large to convert"), 2, "int too large"),
        (ValueError("first line\nsecond line"), 2, "first line second line"),
        (KeyboardInterrupt(), 130, "interrupted"),
        (RuntimeError("something broke"), 1, "--debug"),
    ],
)
def test_failures_during_the_work_are_one_line(raised, code, words, monkeypatch, capsys):
    def fail(*args, **kwargs):
        raise raised

    monkeypatch.setattr(evaluate, "evaluate", fail)
    assert main(_evaluate_argv()) == code
    assert words in _one_error_line(capsys.readouterr().err)


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_shows_the_traceback(where, monkeypatch):
    argv = ["evaluate", "Nope-v0", "--policy", "x"]
    argv = ["--debug", *argv] if where == "before" else [*argv, "--debug"]
    with pytest.raises(ValueError, match="valid ids are"):
        main(argv)


def test_console_script_bad_seed_has_no_traceback():
    proc = subprocess.run(
        [sys.executable, "-m", "mrcomm_env.experiments.cli", *_evaluate_argv("--seed", "-1")],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    assert "--seed" in _one_error_line(proc.stderr)


def test_json_is_written_atomically(tmp_path, monkeypatch, capsys):
    """An evaluate run that fails while writing leaves the previous --json file whole and no temporary file."""
    from mrcomm_env.experiments import io

    path = tmp_path / "eval.json"
    path.write_text('{"previous": true}')

    def interrupted_sync(fd):  # Ctrl-C after the new bytes are written, before they replace the old file
        raise KeyboardInterrupt

    monkeypatch.setattr(io.os, "fsync", interrupted_sync)
    assert main(_evaluate_argv("--json", str(path))) == 130
    assert json.loads(path.read_text()) == {"previous": True}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["eval.json"]


def test_bench_train_measures_ppo_without_leaving_sb3_folders_in_tmp(tmp_path, monkeypatch):
    import tempfile

    from mrcomm_env.experiments.bench_train import train_throughput
    from mrcomm_env.registry import make

    monkeypatch.delenv("SB3_LOGDIR", raising=False)  # as a user runs it (the suite points SB3 elsewhere)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    result = train_throughput([lambda: make("mrcomm/ChannelAssociation-v0", max_cycles=8)] * 2, 128)
    assert result["agent_steps"] >= 128 and result["agent_steps_per_s"] > 0
    assert 0 < result["env_step_share"] < 1
    wall_outside_the_env = result["seconds"] * (1 - result["env_step_share"])
    assert result["ppo_agent_steps_per_s"] == pytest.approx(result["agent_steps"] / wall_outside_the_env)
    assert not list(tmp_path.glob("SB3-*"))
