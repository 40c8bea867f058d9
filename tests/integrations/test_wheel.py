"""The built wheel installs and runs like any package, beside PyPI's `agents` and a local `agents/` folder.

Run by `make test-wheel` inside `.venv-wheel`, a clean venv into which the Makefile installed the wheel that
`python -m build` made (checked by `twine check`), with the `train` extra, and PyPI's unrelated `agents` package
(without its TensorFlow dependencies, which nothing here imports). The tests run from a temporary folder that
holds an `agents/` and a `baselines/` package of its own whose import fails loudly: our code must use neither.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest


@pytest.fixture
def foreign_folder(tmp_path: Path) -> Path:
    """A working folder with its own `agents/` and `baselines/` packages, as a user's project might have."""
    for name in ("agents", "baselines"):
        package = tmp_path / name
        package.mkdir()
        (package / "__init__.py").write_text(f"raise ImportError('the user\\'s own {name} package was imported')\n")
    return tmp_path


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """``python -m`` puts the working folder first on ``sys.path``: the user's own packages there win every clash."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    command = [sys.executable, "-m", "mrcomm_env.experiments.cli", *args]
    return subprocess.run(command, cwd=cwd, capture_output=True, text=True, env=env, timeout=600)


def test_console_script_runs(foreign_folder):
    mrcomm = Path(sys.executable).with_name("mrcomm")
    result = subprocess.run([str(mrcomm), "list"], cwd=foreign_folder, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr


def test_installed_from_the_wheel_not_the_source_tree():
    import mrcomm_agents
    import mrcomm_baselines
    import mrcomm_env

    installed = Path(sysconfig.get_paths()["purelib"]).resolve()
    for module in (mrcomm_env, mrcomm_agents, mrcomm_baselines):
        assert Path(module.__file__).resolve().is_relative_to(installed), module.__file__


def test_pypi_agents_is_installed_beside_us():
    """The name `agents` belongs to another project on PyPI; installing it must not touch ours."""
    from importlib.metadata import distribution

    assert distribution("agents").version
    assert (Path(distribution("agents").locate_file("agents")) / "__init__.py").exists()


def test_list_runs_from_a_folder_with_its_own_agents(foreign_folder):
    result = _run(["list"], foreign_folder)
    assert result.returncode == 0, result.stderr
    assert "mrcomm/MultiHop-v0" in result.stdout


def test_pretrained_policy_evaluates_from_the_wheel(foreign_folder):
    out = foreign_folder / "eval.json"
    result = _run(
        ["evaluate", "MultiHop-v0", "--policy", "pretrained", "--episodes", "1", "--seed", "0", "--json", str(out)],
        foreign_folder,
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(out.read_text())
    assert report, "the evaluation wrote an empty report"


def test_a_scripted_baseline_evaluates_from_the_wheel(foreign_folder):
    args = ["evaluate", "AsyncCL-v0", "--policy", "scheme2_qinf", "--episodes", "1", "--param", "max_cycles=20"]
    result = _run(args, foreign_folder)
    assert result.returncode == 0, result.stderr
