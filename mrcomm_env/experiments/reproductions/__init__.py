"""The papers' experiments, one module per environment (named by the registry's ``EnvEntry.reproduction``).

Each module defines ``EXPERIMENTS`` (name → one-line description) and ``run(out_dir, quick) -> str``, which
writes CSV/JSON and PNG files into ``out_dir`` and returns a markdown section with the paper's numbers
beside ours. Optionally ``run`` also takes ``tiny: bool`` (smoke-test sizes) and the module declares
``ARTIFACTS`` (the file names ``run`` promises). docs/architecture.md, "Contract of a reproduction".
"""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path

from mrcomm_env.registry import entry


def module(env_id: str):
    """The reproduction module of ``env_id``."""
    return importlib.import_module(entry(env_id).reproduction)


def supports_tiny(env_id: str) -> bool:
    """Whether ``env_id``'s ``run`` takes ``tiny`` (smoke-test sizes); others run their quick sizes instead."""
    return "tiny" in inspect.signature(module(env_id).run).parameters


def run_reproduction(env_id: str, out_dir: Path, quick: bool, tiny: bool = False) -> str:
    """Run ``env_id``'s reproduction into ``out_dir``; ``tiny`` is passed on only to a ``run`` that takes it."""
    run = module(env_id).run
    if tiny and supports_tiny(env_id):
        return run(Path(out_dir), quick, tiny=True)
    return run(Path(out_dir), quick)
