"""Task functions for tests/experiments/test_sweep.py and tests/integrations/test_ray.py: importable by name
(``helpers.sweep_tasks:NAME``) from a worker process, whose ``PYTHONPATH`` those tests set to ``tests/``."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np


def draw(seed: int, n: int = 3) -> dict:
    """A result that depends only on the arguments (numpy values: the runner converts them)."""
    rng = np.random.default_rng(seed)
    return {"seed": seed, "values": rng.random(n), "mean": np.float64(rng.random(n).mean())}


def fail_first_time(marker: str, value: int) -> int:
    """Fails on its first call and succeeds on the next: the marker file remembers across processes."""
    path = Path(marker)
    if not path.exists():
        path.write_text(str(os.getpid()))
        raise RuntimeError("first attempt fails")
    return value


def always_fail(value: int) -> int:
    raise RuntimeError(f"task {value} cannot succeed")


def count_calls(log: str, value: int) -> int:
    """Appends one line per call to ``log``: how many times the task really ran."""
    with open(log, "a") as fh:
        fh.write(f"{value}\n")
    return value * value


def node_of(index: int, seconds: float) -> str:
    """The id of the Ray node that ran this task, after holding its CPU for ``seconds`` (so that the tasks of a
    sweep overlap and the scheduler must use every node)."""
    import time

    import ray

    time.sleep(seconds)
    return ray.get_runtime_context().get_node_id()


def record_pid(log: str, value: int) -> int:
    """Appends the worker's process id to ``log``: which processes ran the tasks."""
    with open(log, "a") as fh:
        fh.write(f"{os.getpid()}\n")
    return value


def record_pid_and_wait(log: str, seconds: float) -> int:
    """Appends the worker's process id to ``log``, then works for ``seconds``: a task still running when its
    driver is killed."""
    record_pid(log, 0)
    time.sleep(seconds)
    return 0
