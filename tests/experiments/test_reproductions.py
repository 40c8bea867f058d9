"""Every reproduction in the registry runs at smoke-test sizes and writes every file it promises, and results
are never half-written: not by a failing write, not by an interrupted ``mrcomm reproduce``."""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from mrcomm_env.experiments import io, reproductions
from mrcomm_env.experiments.cli import main
from mrcomm_env.experiments.reproductions import module, run_reproduction
from mrcomm_env.experiments.reproductions.common import TASKS_DIR
from mrcomm_env.registry import ENTRIES, short_name

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_END = b"IEND\xaeB`\x82"  # the IEND chunk and its CRC: the last 8 bytes of every complete PNG


def paper_numbers(env_id: str) -> list[str]:
    """Text of the paper's own numbers that the section must quote beside ours (at every run size)."""
    if env_id == "mrcomm/AsyncCL-v0":
        from mrcomm_env.asynccl import theory

        # Table I (theory, simulation and q = 1 columns) and Table II for N = 3, the smallest team
        return [
            f"{theory.PAPER_TABLE1[3][0]:.4f}/{theory.PAPER_TABLE1[3][1]:.4f}",
            f"{theory.PAPER_TABLE1[3][3]:.4f}",
            f"{theory.PAPER_TABLE2[3]:.4f}",
        ]
    if env_id == "mrcomm/MultiHop-v0":
        from mrcomm_env.multihop import theory

        # §4's claim of a > 47 % drop at m = 7, and its frame rates of Fig. 3
        return ["> 47 %", *(f" / {rate} |" for rate in theory.paper_frame_rates().values())]
    if env_id == "mrcomm/ChannelAssociation-v0":
        # Fig. 5's 780 (w, v) cells, and every claim the section checks, by the paper's section number
        return ["780 cells", "§4.3.2", "§4.3.3", "§4.4.2", "§5.4", "§5.5", "§5.7", "§5.8", "§6.5"]
    return ["paper"]  # a reproduction this test does not know yet: at least it names the paper's numbers


def assert_well_formed(path: Path) -> None:
    data = path.read_bytes()
    assert data, f"{path.name} is empty"
    if path.suffix == ".png":
        assert data.startswith(PNG_SIGNATURE) and data.endswith(PNG_END), f"{path.name} is not a complete PNG"
    elif path.suffix == ".json":
        assert json.loads(data), f"{path.name} holds no results"
    elif path.suffix == ".csv":
        rows = list(csv.reader(data.decode().splitlines()))
        assert len(rows) >= 2 and all(rows[0]), f"{path.name}: no header or no data row"
        assert {len(row) for row in rows} == {len(rows[0])}, f"{path.name}: rows of different lengths"


def leftover_temporaries(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.endswith(io.TEMP_SUFFIX)]


@pytest.mark.parametrize("env_id", list(ENTRIES))
def test_reproduction_writes_every_promised_file(env_id, tmp_path, capsys):
    out = tmp_path / "results"
    # serially: tests/experiments/test_reproduction_sweeps.py checks that worker processes write the same files
    assert main(["reproduce", env_id, "--tiny", "--workers", "1", "--out", str(out)]) == 0
    report_path = out / "REPORT.md"
    report = report_path.read_text()
    name = short_name(env_id)
    written = {p.name: p for p in (out / name).iterdir() if p.name != TASKS_DIR}
    # its Monte-Carlo runs went through the sweep runner, which cached each task's result as it finished
    cached = list((out / name / TASKS_DIR).glob("*.json"))
    assert cached, "no sweep task ran: the reproduction does its Monte-Carlo work outside the sweep runner"
    for path in cached:
        assert set(json.loads(path.read_text())) == {"task", "result"}

    declared = set(getattr(module(env_id), "ARTIFACTS", ()))
    linked = set(re.findall(rf"\]\({re.escape(name)}/([^)\s]+)\)", report))  # figures the report shows
    assert linked, "the report links no figure"
    assert declared | linked <= set(written), f"promised but missing: {sorted((declared | linked) - set(written))}"
    if declared:
        assert set(written) == declared, f"written but not declared in ARTIFACTS: {sorted(set(written) - declared)}"
    suffixes = {p.suffix for p in written.values()}
    assert ".png" in suffixes and suffixes & {".csv", ".json"}
    for path in written.values():
        assert_well_formed(path)
    assert not leftover_temporaries(tmp_path)
    # REPORT.md comes last: it describes only files that already exist
    assert report_path.stat().st_mtime_ns >= max(p.stat().st_mtime_ns for p in written.values())

    section = report.split(f"## {env_id}", 1)[1]
    for number in paper_numbers(env_id):
        assert number in section, f"the section does not quote the paper's {number!r}"


def test_run_without_tiny_is_called_at_quick_size(monkeypatch, tmp_path):
    """A reproduction whose ``run`` predates ``tiny`` still runs under ``--tiny``, at its quick size."""
    calls = []

    def run(out_dir: Path, quick: bool) -> str:
        calls.append((out_dir, quick))
        return "section"

    monkeypatch.setattr(reproductions, "module", lambda env_id: SimpleNamespace(run=run))
    assert run_reproduction("any", tmp_path, quick=True, tiny=True) == "section"
    assert calls == [(tmp_path, True)]


# ---------------------------------------------------------------------------------------------- atomic files
def test_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "table.csv"
    path.write_text("old,complete\n1,2\n")
    with pytest.raises(KeyboardInterrupt), io.atomic_open(path, "w") as handle:
        handle.write("new,half")
        raise KeyboardInterrupt
    assert path.read_text() == "old,complete\n1,2\n"
    assert sorted(tmp_path.iterdir()) == [path]


def test_atomic_file_gets_the_permissions_of_a_plain_open(tmp_path):
    (tmp_path / "plain").write_text("x")
    io.atomic_write_text(tmp_path / "atomic", "x")
    assert (tmp_path / "atomic").stat().st_mode == (tmp_path / "plain").stat().st_mode


def test_atomic_csv_reads_back_as_the_rows_it_was_given(tmp_path):
    import csv

    rows = [{"policy": "age_aware", "bits": 758.8, "note": "a, quoted"}, {"policy": "flooding", "bits": 1, "note": ""}]
    io.atomic_write_csv(tmp_path / "table.csv", rows)
    with open(tmp_path / "table.csv", newline="") as handle:
        back = list(csv.DictReader(handle))
    assert back == [{key: str(value) for key, value in row.items()} for row in rows]
    assert sorted(tmp_path.iterdir()) == [tmp_path / "table.csv"]


def test_atomic_json_is_strict_json_with_non_finite_numbers_as_null(tmp_path):
    """NaN and ±inf, Python's floats and numpy's, alone or in an array, are written as null: a strict parser (one
    that refuses Python's NaN extension, as JavaScript's and jq's do) reads the file."""
    import numpy as np

    record = {
        "propagation_time_8x8": float("nan"),
        "ceiling": [float("inf"), -float("inf"), 1.5],
        "float32": np.float32("nan"),
        "array": np.array([np.nan, 2.0]),
        "kept": {"bits": 758.8, "episodes": 5, "name": "age_aware", "none": None},
    }
    io.atomic_write_json(tmp_path / "result.json", record, indent=1)

    def refuse(constant):
        raise ValueError(f"not strict JSON: {constant}")

    back = json.loads((tmp_path / "result.json").read_text(), parse_constant=refuse)
    assert back == {
        "propagation_time_8x8": None,
        "ceiling": [None, None, 1.5],
        "float32": None,
        "array": [None, 2.0],
        "kept": {"bits": 758.8, "episodes": 5, "name": "age_aware", "none": None},
    }


def test_atomic_savefig_writes_a_complete_png(tmp_path):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2, 2))
    FigureCanvasAgg(fig)
    fig.add_subplot(1, 1, 1).plot([0, 1], [1, 0])
    io.atomic_savefig(fig, tmp_path / "fig.png", dpi=50)
    assert_well_formed(tmp_path / "fig.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig.png"]


STALE_REPORT = "# report of an earlier run\n\n![old](AsyncCL-v0/fig_that_no_longer_exists.png)\n"


def test_reproduce_interrupted_mid_write_leaves_no_report_and_no_temporary(tmp_path, monkeypatch, capsys):
    """Ctrl-C while the second result file is being put in place: the first file is whole, the second was
    never half-written, and no REPORT.md (neither the new one nor the stale one) describes the folder."""
    out = tmp_path / "results"
    out.mkdir()
    (out / "REPORT.md").write_text(STALE_REPORT)
    real_replace = os.replace
    replaced = []

    def replace_then_interrupt(src, dst):
        if out not in Path(dst).parents:  # another library's own rename (a compiled-kernel cache, say)
            return real_replace(src, dst)
        if replaced:
            raise KeyboardInterrupt
        real_replace(src, dst)
        replaced.append(Path(dst))

    monkeypatch.setattr(io.os, "replace", replace_then_interrupt)
    env_id = next(iter(ENTRIES))
    assert main(["reproduce", env_id, "--tiny", "--workers", "1", "--out", str(out)]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert not (out / "REPORT.md").exists()
    assert not leftover_temporaries(tmp_path)
    files = [p for p in out.rglob("*") if p.is_file()]
    assert files == replaced  # exactly the one file that was completed
    assert_well_formed(files[0])


def test_reproduce_killed_by_sigint_leaves_no_report(tmp_path):
    """A real Ctrl-C (SIGINT) once the first result file exists: exit 130, one line, no REPORT.md."""
    out = tmp_path / "results"
    out.mkdir()
    (out / "REPORT.md").write_text(STALE_REPORT)
    proc = subprocess.Popen(
        [sys.executable, "-m", "mrcomm_env.experiments.cli", "reproduce", "--all", "--tiny", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # a shell without job control starts background jobs with SIGINT ignored, and Python keeps an ignored
        # SIGINT ignored: give the child the default disposition, so Ctrl-C means KeyboardInterrupt there
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        deadline = time.monotonic() + 300
        while not any(p.is_file() and p.parent != out and not p.name.endswith(io.TEMP_SUFFIX) for p in out.rglob("*")):
            assert proc.poll() is None, "the run ended before writing a file"
            assert time.monotonic() < deadline, "no result file within 300 s"
            time.sleep(0.05)
        assert not (out / "REPORT.md").exists(), "the stale report outlived the first new file"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    if proc.returncode == 0:
        pytest.fail("the run finished before the interrupt arrived; it cannot have been interrupted")
    assert proc.returncode == 130
    assert "Traceback" not in err
    assert err.replace("\r", "\n").strip().splitlines()[-1] == "mrcomm: interrupted"
    assert not (out / "REPORT.md").exists()
    assert not leftover_temporaries(tmp_path)
    for path in out.rglob("*"):
        if path.is_file():
            assert_well_formed(path)


def test_multihop_fig5_rows_are_nearest_first_with_ties_by_robot_id():
    """A grid has many robots at one distance: their rows must not come in an order the CPU's sort picks."""
    import matplotlib.pyplot as plt
    import numpy as np

    from mrcomm_env.experiments.reproductions import multihop

    rng = np.random.default_rng(0)
    dist = np.r_[0.0, rng.choice([1.0, 2.0, 3.0, 5.0, 8.0], size=63)]  # robot 0 is the corner robot itself
    result = {"distance": dist, "mean_age": rng.random(64), "max_age": rng.random(64), "unknown": 0}
    fig, ax = plt.subplots()
    try:
        rows, _ = multihop._fig5_table(ax, [result] * len(multihop.FIG5_CONFIGS))
    finally:
        plt.close(fig)
    for config in multihop.FIG5_CONFIGS:
        ordered = [(row["distance"], row["robot"]) for row in rows if row["scheme"] == config[2]]
        assert len(ordered) == 63 and ordered == sorted(ordered)
