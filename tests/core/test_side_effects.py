"""Running the envs writes nothing into the installed package (numba's kernel cache goes to a user folder)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import mrcomm_env

PACKAGE = Path(mrcomm_env.__file__).resolve().parent


def package_files() -> set[Path]:
    return {p for p in PACKAGE.rglob("*") if p.is_file() and p.suffix not in (".pyc",)}


def test_compiled_kernels_are_cached_outside_the_package(tmp_path):
    before = package_files()
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(XDG_CACHE_HOME=str(tmp_path))
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


def test_every_kernel_module_caches_outside_the_package_even_when_imported_first(tmp_path):
    """numba fixes a kernel's cache folder when its ``@njit(cache=True)`` runs, at import: a kernel module imported
    before anything has called ``configure_numba_cache`` (a test, a script, a user's import) must still cache in
    the user folder. Every module of the package with cached kernels, each in a fresh process."""
    modules = sorted(
        ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        for path in PACKAGE.rglob("*.py")
        if "njit(cache=True" in path.read_text(encoding="utf-8")
    )
    assert len(modules) >= 6  # AsyncCL's EKF and table, MapSync's, MultiHop's, RendezvousMapping's plan and forest
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(XDG_CACHE_HOME=str(tmp_path))
    code = (
        "import importlib, sys\n"
        "from numba.core.dispatcher import Dispatcher\n"
        "module = importlib.import_module(sys.argv[1])\n"
        "kernels = [f for f in vars(module).values() if isinstance(f, Dispatcher) and f._cache is not None]\n"
        "assert kernels, 'no cached kernels found'\n"
        "for f in kernels:\n"
        "    print(f._cache._cache_path)\n"
    )
    for module in modules:
        run = subprocess.run(
            [sys.executable, "-c", code, module], env=env, capture_output=True, text=True, timeout=300, check=True
        )
        folders = run.stdout.split()
        assert folders and all(Path(f).is_relative_to(tmp_path) for f in folders), (module, folders)
