"""The papers' experiments, one module per environment (named by the registry's ``EnvEntry.reproduction``).

Each module defines ``EXPERIMENTS`` (name → one-line description) and ``run(out_dir, quick) -> str``, which
writes CSV/JSON and PNG files into ``out_dir`` and returns a markdown section with the paper's numbers
beside ours.
"""

from __future__ import annotations

import importlib

from mrcomm_env.registry import entry


def module(env_id: str):
    """The reproduction module of ``env_id``."""
    return importlib.import_module(entry(env_id).reproduction)
