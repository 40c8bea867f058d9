"""Reproductions run their Monte-Carlo work as sweep tasks: the files do not depend on the backend that ran them,
a rerun into the same folder runs nothing again, and a task that fails twice ends ``mrcomm reproduce`` with one
line naming it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mrcomm_env.experiments.cli import main
from mrcomm_env.experiments.reproductions import run_reproduction
from mrcomm_env.experiments.sweep import Runner, using

#: a cheap reproduction at smoke-test sizes, with many small tasks (its time goes into its figures)
ENV = "ChannelAssociation-v0"
#: what a reproduction's JSON records about wall time: the one part of its output that may differ between runs
TIMING_KEYS = {"seconds", "timing", "timing_s"}


def _without_timing(data):
    if isinstance(data, dict):
        return {k: _without_timing(v) for k, v in data.items() if k not in TIMING_KEYS}
    if isinstance(data, list):
        return [_without_timing(v) for v in data]
    return data


def written_files(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (the task cache included) by relative path; JSON without its timing fields."""
    files = {}
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        data = path.read_bytes()
        if path.suffix == ".json":
            data = json.dumps(_without_timing(json.loads(data)), sort_keys=True).encode()
        files[str(path.relative_to(root))] = data
    return files


def reproduce(out: Path, runner: Runner) -> dict[str, bytes]:
    with using(runner):
        run_reproduction(ENV, out, quick=True, tiny=True)
    return written_files(out)


@pytest.fixture(scope="module")
def serial_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("serial") / ENV
    runner = Runner(workers=1, progress=False)
    return out, reproduce(out, runner), runner.stats


@pytest.mark.xdist_group("processes")
def test_worker_processes_write_the_serial_files_byte_for_byte(serial_run, tmp_path):
    _, serial_files, serial_stats = serial_run
    runner = Runner(workers=2, progress=False)
    files = reproduce(tmp_path / ENV, runner)
    assert runner.stats["run"] > 1 and runner.stats["run"] == serial_stats["run"]
    assert sorted(files) == sorted(serial_files)
    assert any(name.endswith(".png") for name in files) and any(name.startswith("tasks/") for name in files)
    differ = [name for name in files if files[name] != serial_files[name]]
    assert not differ, f"files that depend on the backend: {differ}"


def test_a_rerun_into_the_same_folder_runs_no_task_and_writes_the_same_files(serial_run):
    out, serial_files, serial_stats = serial_run
    runner = Runner(workers=1, progress=False)
    assert reproduce(out, runner) == serial_files
    assert runner.stats == {"run": 0, "cached": serial_stats["run"], "retried": 0}


def test_a_task_that_fails_twice_ends_reproduce_with_one_line_naming_it(tmp_path, monkeypatch, capsys):
    from mrcomm_env.experiments.reproductions import rendezvous_mapping

    real = rendezvous_mapping.episode_to_cap

    def fail_for_greedy(env_kwargs, planner, seed, cap, *args):
        if planner == "greedy":
            raise RuntimeError("the planner crashed")
        return real(env_kwargs, planner, seed, cap, *args)

    monkeypatch.setattr(rendezvous_mapping, "episode_to_cap", fail_for_greedy)
    out = tmp_path / "results"
    assert main(["reproduce", "RendezvousMapping-v0", "--tiny", "--workers", "1", "--out", str(out)]) == 1
    err = capsys.readouterr().err.replace("\r", "\n").strip().splitlines()[-1]
    assert err.startswith("mrcomm: error: ") and "failed twice" in err
    assert "fig8_infinite_comms [main] sigma=0 clumping=0 draw=0 greedy" in err and '"planner": "greedy"' in err
    assert "RuntimeError: the planner crashed" in err
    assert not (out / "REPORT.md").exists()
    # the tasks that succeeded are kept for the rerun
    assert any((out / "RendezvousMapping-v0" / "tasks").glob("*.json"))


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--workers", "0"], "argument --workers: must be an integer ≥ 1, got '0'"),
        (["--workers", "2", "--ray", "auto"], "argument --ray: not allowed with argument --workers"),
    ],
)
def test_bad_runner_flags_are_refused_before_any_work(flags, message, tmp_path, capsys):
    out = tmp_path / "results"
    assert main(["reproduce", ENV, "--tiny", *flags, "--out", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()
