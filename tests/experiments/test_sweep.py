"""The sweep runner (mrcomm_env/experiments/sweep.py): order, backends, retry, resume and errors."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest
from helpers.processes import wait_until_gone

from mrcomm_env.experiments.sweep import Runner, SweepError, Task, cancel_until_gone, current, using

TESTS = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(TESTS))  # helpers.sweep_tasks must import in spawned workers too
FN = "helpers.sweep_tasks:"


def _tasks(n=5):
    return [Task(FN + "draw", {"seed": s}, f"draw s={s}") for s in range(n)]


def test_results_come_back_in_task_order_and_as_plain_data():
    results = Runner(workers=1, progress=False).map(_tasks())
    assert [r["seed"] for r in results] == list(range(5))
    assert isinstance(results[0]["values"], list) and isinstance(results[0]["mean"], float)


@pytest.mark.xdist_group("processes")
def test_processes_give_exactly_the_serial_numbers(monkeypatch):
    monkeypatch.setenv("PYTHONPATH", str(TESTS))  # the spawned workers import helpers.sweep_tasks
    tasks = _tasks(6)
    assert Runner(workers=2, progress=False).map(tasks) == Runner(workers=1, progress=False).map(tasks)


def test_a_failed_task_is_retried_once(tmp_path):
    runner = Runner(workers=1, progress=False)
    assert runner.map([Task(FN + "fail_first_time", {"marker": str(tmp_path / "m"), "value": 7})]) == [7]
    assert runner.stats["retried"] == 1


def test_a_task_that_fails_twice_is_reported_with_its_arguments_after_the_others(tmp_path):
    tasks = [*_tasks(2), Task(FN + "always_fail", {"value": 41}, "doomed")]
    runner = Runner(workers=1, progress=False)
    with pytest.raises(
        SweepError, match=r"1 of 3 tasks failed twice; doomed \{\"value\": 41\}.*cannot succeed"
    ) as info:
        runner.map(tasks, cache=tmp_path)
    assert runner.stats["retried"] == 1
    # the task's own exception is the cause: a traceback (mrcomm --debug) shows where the task failed
    assert isinstance(info.value.__cause__, RuntimeError) and info.value.__cause__.__traceback__ is not None
    assert len(list(tmp_path.glob("*.json"))) == 2  # the two good results were kept for the rerun


def test_a_rerun_skips_the_tasks_already_done(tmp_path):
    log = tmp_path / "calls.log"
    tasks = [Task(FN + "count_calls", {"log": str(log), "value": v}, f"v={v}") for v in range(4)]
    first = Runner(workers=1, progress=False).map(tasks[:2], cache=tmp_path / "cache")  # an interrupted sweep
    runner = Runner(workers=1, progress=False)
    assert runner.map(tasks, cache=tmp_path / "cache") == [0, 1, 4, 9]
    assert first == [0, 1]
    assert log.read_text().split() == ["0", "1", "2", "3"]  # each task ran exactly once over both runs
    assert runner.stats == {"run": 2, "cached": 2, "retried": 0}
    record = json.loads(next((tmp_path / "cache").glob("v=3-*.json")).read_text())
    assert record["task"]["kwargs"]["value"] == 3 and record["result"] == 9


def test_changed_arguments_make_a_new_task():
    a, b = Task(FN + "draw", {"seed": 1}), Task(FN + "draw", {"seed": 2})
    assert a.key() != b.key() and a.key() == Task(FN + "draw", {"seed": 1}).key()


def test_the_same_task_twice_is_refused():
    with pytest.raises(ValueError, match="same task twice"):
        Runner(progress=False).map([*_tasks(2), _tasks(1)[0]])


@pytest.mark.parametrize(
    "kwargs, match",
    [({"workers": 0}, "'workers' must be an integer ≥ 1"), ({"ray": " "}, "'ray' must be 'auto' or a cluster address")],
)
def test_bad_runner_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Runner(**kwargs)


def test_using_sets_the_runner_for_the_block():
    runner = Runner(workers=3, progress=False)
    assert current().workers == 1
    with using(runner):
        assert current() is runner
    assert current().workers == 1


def test_ray_without_ray_installed_says_how_to_get_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray → ImportError
    with pytest.raises(ValueError, match=r"mrcomm-env\[ray\]"):
        Runner(ray="auto", progress=False).map(_tasks(1))


def test_a_ray_task_refuses_to_run_on_a_node_with_other_code():
    # what each Ray task runs first (in-process here: the check needs no cluster); the cache key holds the
    # driver's code version, so a node with other code must not file its numbers under it
    from mrcomm_env.experiments.sweep import CodeMismatch, _ray_execute, code_version

    task = (FN + "count_calls", {"log": os.devnull, "value": 3})
    here = {"code": code_version()}
    assert _ray_execute(*task, here) == 9
    other_code = {"code": "0" * len(here["code"])}
    with pytest.raises(CodeMismatch, match=rf"runs mrcomm-env code {here['code']}, the driver code {'0' * 12}"):
        _ray_execute(*task, other_code)


@pytest.mark.xdist_group("processes")
def test_a_using_block_keeps_one_pool_of_workers_for_all_its_sweeps(monkeypatch, tmp_path):
    monkeypatch.setenv("PYTHONPATH", str(TESTS))
    log = tmp_path / "pids.log"
    runner = Runner(workers=2, progress=False)
    with using(runner):
        for value in range(3):  # three sweeps in one block
            runner.map([Task(FN + "record_pid", {"log": str(log), "value": v}) for v in (value, value + 10)])
        assert runner._pool is not None
    assert runner._pool is None  # stopped with the block
    assert len(set(log.read_text().split())) <= 2  # the same two workers ran all six tasks


@pytest.mark.xdist_group("processes")
def test_workers_die_with_a_driver_killed_by_sigkill(tmp_path):
    """``kill -9`` of a sweep's driver (``mrcomm reproduce --workers 2``) leaves no worker behind."""
    import signal
    import subprocess
    import time

    log = tmp_path / "pids.txt"
    driver = (
        f"import sys; sys.path.insert(0, {str(TESTS)!r})\n"
        "from mrcomm_env.experiments.sweep import Runner, Task\n"
        "Runner(workers=2, progress=False).map([Task('helpers.sweep_tasks:record_pid_and_wait', "
        f"{{'log': {str(log)!r}, 'seconds': 120 + k}}) for k in range(2)])\n"
    )
    env = {**os.environ, "PYTHONPATH": str(TESTS)}
    proc = subprocess.Popen([sys.executable, "-c", driver], env=env)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and (not log.exists() or len(log.read_text().split()) < 2):
        assert proc.poll() is None, "the driver failed before its workers started"
        time.sleep(0.2)
    workers = [int(p) for p in log.read_text().split()]
    assert len(workers) == 2
    proc.send_signal(signal.SIGKILL)
    proc.wait()

    assert wait_until_gone(workers, 10), "workers outlived their killed driver"


def test_a_corrupt_cached_result_is_run_again_with_a_warning(tmp_path):
    task = Task(FN + "draw", {"seed": 4}, "draw s=4")
    expected = Runner(workers=1, progress=False).map([task], cache=tmp_path)
    path = tmp_path / f"{task.key()}.json"
    path.write_text('{"result": [1, 2')  # a truncated file, as a full disk or an editor could leave it
    with pytest.warns(UserWarning, match=str(path.name)):
        again = Runner(workers=1, progress=False).map([task], cache=tmp_path)
    assert again == expected
    assert json.loads(path.read_text())["result"] == expected[0]


class _LosesFirstCancel:
    """Ray as a stopping driver sees it when the cancel of task "b" reaches it between dispatch and start: that
    first cancel is lost, and only a second one ends the task (ray-project/ray#24359)."""

    def __init__(self):
        self.cancels = {"a": 0, "b": 0}

    def cancel(self, ref, force):
        assert force
        self.cancels[ref] += 1

    def ended(self, ref) -> bool:
        return self.cancels[ref] >= (2 if ref == "b" else 1)

    def wait(self, refs, num_returns, timeout):
        return [r for r in refs if self.ended(r)], [r for r in refs if not self.ended(r)]


def test_a_stopping_driver_cancels_again_the_ray_tasks_a_lost_cancel_left_running():
    fake = _LosesFirstCancel()
    cancel_until_gone(fake, ["a", "b"], seconds=5.0)
    assert fake.cancels == {"a": 1, "b": 2}  # each cancelled until it ended, and no more


def test_a_stopping_driver_gives_up_cancelling_after_its_time():
    class NeverEnds(_LosesFirstCancel):
        def ended(self, ref) -> bool:
            return False

    fake = NeverEnds()
    cancel_until_gone(fake, ["a", "b"], seconds=0.0)
    assert fake.cancels == {"a": 1, "b": 1}
