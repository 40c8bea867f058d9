"""The sweep runner on a real Ray cluster (``make test-ray``, in ``.venv-ray``): two nodes of one CPU each, started
on this machine by ``ray.cluster_utils.Cluster`` as separate raylets, and the runner joins it by address as it
joins a multi-node cluster (docs/scaling.md).

The nodes listen on the machine's own address, not 127.0.0.1: ``ray.init(address=...)`` rewrites a loopback
address to that address before connecting (``services.resolve_ip_for_localhost``), so a cluster bound to
loopback only could not be joined by address at all.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest
import ray
from ray.cluster_utils import Cluster

from mrcomm_env.experiments.bench import episode_tasks
from mrcomm_env.experiments.reproductions import run_reproduction
from mrcomm_env.experiments.sweep import Runner, SweepError, Task, using

TESTS = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(TESTS))  # helpers.sweep_tasks, the test helpers, in this process
HELPERS = "helpers.sweep_tasks:"
#: its reproduction writes no timings into its CSV/JSON files, so two runs can be compared byte for byte
REPRODUCED = "mrcomm/AsyncCL-v0"


@pytest.fixture(scope="module")
def cluster_address():
    # Ray's worker processes inherit the raylets' environment: helpers.sweep_tasks must import there too
    saved = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(TESTS), saved]))
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        yield cluster.address
    finally:
        ray.shutdown()  # the runner's connection, opened by its first map
        cluster.shutdown()
        if saved is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = saved


def test_a_sweep_uses_both_nodes(cluster_address):
    runner = Runner(ray=cluster_address, progress=False)
    nodes = runner.map([Task(HELPERS + "node_of", {"index": i, "seconds": 1.0}) for i in range(4)])
    alive = {node["NodeID"] for node in ray.nodes() if node["Alive"]}
    assert len(alive) == 2 and set(nodes) == alive


def test_episodes_on_the_cluster_equal_the_serial_run_exactly(cluster_address):
    # seeded episodes of scripted baselines, as a reproduction's Monte-Carlo loop runs them
    tasks = episode_tasks("mrcomm/MapSync-v0", 4) + episode_tasks("mrcomm/AsyncCL-v0", 3, {"max_cycles": 60})
    on_ray = Runner(ray=cluster_address, progress=False)
    results = on_ray.map(tasks)
    assert on_ray.stats == {"run": len(tasks), "cached": 0, "retried": 0}
    assert results == Runner(workers=1, progress=False).map(tasks)
    assert len({r["rms_position"] for r in results[4:]}) == 3  # the seeds made different episodes


class RecordingRunner(Runner):
    """A runner that remembers the stats of every sweep a reproduction ran through it."""

    def map(self, tasks, cache=None, desc="tasks"):
        try:
            return super().map(tasks, cache=cache, desc=desc)
        finally:
            self.sweeps = [*getattr(self, "sweeps", []), dict(self.stats)]


def _results(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.suffix in (".csv", ".json")}


def test_a_reproduction_on_the_cluster_writes_the_serial_files_byte_for_byte(cluster_address, tmp_path):
    with using(Runner(workers=1, progress=False)):
        run_reproduction(REPRODUCED, tmp_path / "serial", quick=True, tiny=True)
    with using(RecordingRunner(ray=cluster_address, progress=False)) as runner:
        run_reproduction(REPRODUCED, tmp_path / "ray", quick=True, tiny=True)
    # the reproduction's Monte-Carlo runs went through the runner, onto the cluster
    assert sum(sweep["run"] for sweep in getattr(runner, "sweeps", [])) > 0
    serial = _results(tmp_path / "serial")
    assert serial and _results(tmp_path / "ray") == serial


def test_a_task_that_fails_once_succeeds_on_its_retry(cluster_address, tmp_path):
    runner = Runner(ray=cluster_address, progress=False)
    tasks = [Task(HELPERS + "fail_first_time", {"marker": str(tmp_path / "marker"), "value": 7}), *_draws(2)]
    results = runner.map(tasks)
    assert results[0] == 7 and results[1:] == Runner(workers=1, progress=False).map(_draws(2))
    assert runner.stats["retried"] == 1
    assert (tmp_path / "marker").exists()  # the first attempt did run, and failed


def test_a_task_that_fails_twice_is_reported_with_its_arguments(cluster_address, tmp_path):
    runner = Runner(ray=cluster_address, progress=False)
    with pytest.raises(
        SweepError, match=r"1 of 3 tasks failed twice; doomed \{\"value\": 41\}.*cannot succeed"
    ) as info:
        runner.map([*_draws(2), Task(HELPERS + "always_fail", {"value": 41}, "doomed")], cache=tmp_path)
    assert runner.stats["retried"] == 1
    # the error as the task raised it, chained to Ray's copy that holds the remote traceback
    cause = info.value.__cause__
    assert isinstance(cause, RuntimeError) and isinstance(cause.__cause__, ray.exceptions.RayTaskError)
    assert len(list(tmp_path.glob("*.json"))) == 2  # the others' results were kept for a rerun


def _draws(n: int) -> list[Task]:
    return [Task(HELPERS + "draw", {"seed": s}, f"draw s={s}") for s in range(n)]


def test_a_driver_that_stops_cancels_the_tasks_it_sent(cluster_address, tmp_path):
    # the first result cannot be stored (the cache "folder" is a file), so the driver stops while one task of two
    # minutes runs and another waits; both must leave the cluster, not hold its CPUs for those minutes. Ray frees a
    # killed worker's CPU within seconds once warm, but a fresh install's first cluster took over 20 s once (CI):
    # one minute still tells a cancelled task from one that runs its two to the end
    blocked = tmp_path / "a_file"
    blocked.write_text("not a folder")
    slow = [Task(HELPERS + "node_of", {"index": i, "seconds": 120.0}) for i in range(2)]
    runner = Runner(ray=cluster_address, progress=False)
    with pytest.raises(OSError):
        runner.map([*_draws(1), *slow], cache=blocked)
    total = ray.cluster_resources()["CPU"]
    deadline = time.monotonic() + 60
    while ray.available_resources().get("CPU", 0) < total and time.monotonic() < deadline:
        time.sleep(0.2)
    assert ray.available_resources().get("CPU", 0) == total
