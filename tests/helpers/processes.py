"""Whether a process is still running: what the tests of worker processes (sweeps, sharded batches) wait on."""

from __future__ import annotations

import os
import time


def process_alive(pid: int) -> bool:
    """True while ``pid`` runs; a zombie (ended, not yet reaped by its parent) is gone for every purpose."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as stat:
        return stat.read().split(")")[-1].split()[0] != "Z"


def wait_until_gone(pids: list[int], seconds: float) -> bool:
    """Wait up to ``seconds`` for every process of ``pids`` to end; whether they all did."""
    deadline = time.monotonic() + seconds
    while any(process_alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    return not any(process_alive(pid) for pid in pids)
