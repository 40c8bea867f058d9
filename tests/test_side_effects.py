"""Running the envs writes nothing into the installed package (numba's kernel cache goes to a user folder)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import mrcomm_env

PACKAGE = Path(mrcomm_env.__file__).resolve().parent


def package_files() -> set[Path]:
    return {p for p in PACKAGE.rglob("*") if p.is_file() and p.suffix not in (".pyc",)}


def test_compiled_kernels_are_cached_outside_the_package(tmp_path):
    pytest.importorskip("numba")
    before = package_files()
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(XDG_CACHE_HOME=str(tmp_path), MRCOMM_BACKEND="numba")
    code = (
        "import mrcomm_env\n"
        "e = mrcomm_env.make('AsyncCL-v0', n_robots=3, max_cycles=3)\n"
        "e.reset(seed=0)\n"
        "while e.agents: e.step({a: 6 for a in e.agents})\n"
    )
    subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=300)
    assert package_files() - before == set(), "files were written into the package"
    cached = list((tmp_path / "mrcomm-env" / "numba").rglob("*.nbi"))
    assert cached, "the compiled kernels were not cached in the user cache folder"
