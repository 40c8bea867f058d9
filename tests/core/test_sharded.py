"""``ShardedBatchedEnv``: M copies stepped by several processes give the numbers of one process, copy by copy; its
workers end with it, even when its process is killed; bad arguments and a failing worker are reported."""

from __future__ import annotations

import functools
import gc
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from helpers.batches import as_bytes, assert_copies_are_single_envs
from helpers.processes import process_alive, wait_until_gone

import mrcomm_env
from mrcomm_env.core import sharded
from mrcomm_env.core.batched import BatchedEnv, sample_actions
from mrcomm_env.core.sharded import ShardedBatchedEnv, default_workers, stepping_batch
from mrcomm_env.testing import same

#: copies that step in turn (AsyncCL), a copy-axis world (MapSync's unlimited links) and a scene whose episodes end
#: by themselves; uneven shards (5 copies on 3 processes: 2, 2 and 1)
CASES = [
    ("AsyncCL-v0", {"n_robots": 3, "max_cycles": 6}, 3, 2),
    ("MapSync-v0", {"max_cycles": 6}, 5, 3),
    ("ChannelAssociation-v0", {"scene": "neighborhood", "w": 3, "v": 2, "max_cycles": 12}, 3, 2),
]


def maker(env_id: str, **kwargs):
    return functools.partial(mrcomm_env.make, env_id, **kwargs)


@pytest.mark.parametrize(("env_id", "kwargs", "copies", "workers"), CASES, ids=lambda v: str(v))
def test_copy_i_of_a_sharded_batch_is_the_single_env_seeded_s_plus_i(env_id, kwargs, copies, workers):
    batch = ShardedBatchedEnv(maker(env_id, **kwargs), copies, workers)
    try:
        assert [b - a for a, b in zip(batch.bounds, batch.bounds[1:])] == [
            len(part) for part in np.array_split(np.arange(copies), workers)
        ]
        assert_copies_are_single_envs(batch, env_id, kwargs, horizon=3 * kwargs["max_cycles"] + 2)
    finally:
        batch.close()


def test_restart_and_metrics_reach_the_copies_of_every_shard():
    kwargs = {"n_robots": 3, "max_cycles": 8}
    batch = ShardedBatchedEnv(maker("AsyncCL-v0", **kwargs), 4, 2)
    singles = [mrcomm_env.make("AsyncCL-v0", **kwargs) for _ in range(4)]
    try:
        batch.reset(seed=4)
        agents = singles[0].possible_agents
        for i, env in enumerate(singles):
            env.reset(seed=4 + i)
        rng = np.random.default_rng(1)
        for _ in range(3):
            actions = sample_actions(batch.action_space, rng, (4, batch.n_agents))
            batch.step(actions)
            for i, env in enumerate(singles):
                env.step(dict(zip(agents, actions[i])))
        assert same(batch.metrics(), [env.metrics() for env in singles])
        reset_infos = batch.restart([1, 3])  # one copy of each shard
        assert sorted(reset_infos) == [1, 3]
        for i in (1, 3):
            first, first_infos = singles[i].reset()  # no seed: the copy's own stream goes on
            assert as_bytes(batch.observations[i]) == as_bytes(np.stack([first[a] for a in agents]))
            assert {k: v.tolist() for k, v in reset_infos[i].items()} == {
                k: [first_infos[a][k] for a in agents] for k in first_infos[agents[0]]
            }
        actions = sample_actions(batch.action_space, rng, (4, batch.n_agents))
        out = batch.step(actions)
        for i, env in enumerate(singles):
            obs = env.step(dict(zip(agents, actions[i])))[0]
            assert as_bytes(out.observations[i]) == as_bytes(np.stack([obs[a] for a in agents]))
        assert batch.bits_sent().tolist() == [env.bits_sent() for env in singles]
        for i in (1, 3):  # drawn by the process that steps the copy: the single env's frame
            assert as_bytes(batch.render_copy(i)) == as_bytes(singles[i].rgb_frame())
        with pytest.raises(ValueError, match=r"'index' must be in \[0, 3\]"):
            batch.render_copy(4)
    finally:
        batch.close()


def test_bad_arguments_are_refused_naming_them():
    make = maker("AsyncCL-v0", n_robots=3)
    with pytest.raises(ValueError, match=r"'workers' must be an integer in \[1, n_copies = 2\]"):
        ShardedBatchedEnv(make, 2, 3)
    for workers in (0, True, 1.5):
        with pytest.raises(ValueError, match="'workers' must be an integer"):
            ShardedBatchedEnv(make, 2, workers)
    with pytest.raises(ValueError, match="'n_copies' must be an integer ≥ 1"):
        ShardedBatchedEnv(make, 0, 1)
    with pytest.raises(ValueError, match="'make_copy' must pickle"):
        ShardedBatchedEnv(lambda: mrcomm_env.make("AsyncCL-v0", n_robots=3), 2, 2)
    batch = ShardedBatchedEnv(make, 2, 2)
    try:
        with pytest.raises(RuntimeError, match="reset"):
            batch.step(np.zeros((2, 3), dtype=np.int64))
        batch.reset(seed=0)
        with pytest.raises(ValueError, match="'actions' must have shape"):
            batch.step(np.zeros((2, 2), dtype=np.int64))
    finally:
        batch.close()


def test_copies_and_workers_over_the_memory_budget_are_refused_naming_both():
    # one AsyncCL copy's estimate fits a budget of WORKER_BYTES; with a worker's own interpreter beside it, two do not
    budget = sharded.WORKER_BYTES / 2**30
    make = maker("AsyncCL-v0", n_robots=3, memory_budget_gib=budget)
    BatchedEnv(make, 2).close()  # the copies alone fit in one process
    with pytest.raises(ValueError, match=r"arguments 'n_copies' \(2\) and 'workers' \(2\) need an estimated"):
        ShardedBatchedEnv(make, 2, 2)


def test_a_failing_worker_is_raised_in_the_caller_with_its_traceback():
    batch = ShardedBatchedEnv(maker("AsyncCL-v0", n_robots=3), 2, 2)
    try:
        batch.reset(seed=0)
        actions = np.zeros((2, 3), dtype=np.int64)
        actions[1, 0] = 99  # copy 1 steps in the worker: not one of the 7 modes
        with pytest.raises(RuntimeError, match=r"(?s)a worker of the sharded batch failed.*Traceback"):
            batch.step(actions)
        actions[1, 0] = 0  # every answer of the failed call was read: the next call gets its own
        assert batch.step(actions).observations.shape == (2, 3, batch.observation_space.shape[0])
    finally:
        batch.close()


def test_a_call_interrupted_midway_leaves_the_batch_refusing_further_calls(monkeypatch):
    batch = ShardedBatchedEnv(maker("AsyncCL-v0", n_robots=3), 2, 2)
    try:
        batch.reset(seed=0)

        def interrupted(actions):
            raise KeyboardInterrupt  # Ctrl-C while the worker's answer is outstanding

        monkeypatch.setattr(batch.local, "step", interrupted)
        with pytest.raises(KeyboardInterrupt):
            batch.step(np.zeros((2, 3), dtype=np.int64))
        with pytest.raises(RuntimeError, match="interrupted in the middle of a call"):
            batch.metrics()
    finally:
        batch.close()


def test_workers_end_when_the_batch_closes_or_is_collected_and_when_its_process_is_killed():
    batch = ShardedBatchedEnv(maker("AsyncCL-v0", n_robots=3), 3, 3)
    pids = batch.worker_pids
    assert len(pids) == 2 and all(process_alive(pid) for pid in pids)
    batch.close()
    assert not any(process_alive(pid) for pid in pids)
    forgotten = ShardedBatchedEnv(maker("AsyncCL-v0", n_robots=3), 2, 2)  # never closed: garbage-collected
    pids = forgotten.worker_pids
    del forgotten
    gc.collect()
    assert not any(process_alive(pid) for pid in pids)
    script = textwrap.dedent(
        """
        import functools, sys, time
        import mrcomm_env
        from mrcomm_env.core.sharded import ShardedBatchedEnv
        batch = ShardedBatchedEnv(functools.partial(mrcomm_env.make, "AsyncCL-v0", n_robots=3), 2, 2)
        batch.reset(seed=0)
        print(*batch.worker_pids, flush=True)
        time.sleep(120)
        """
    )
    caller = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    (worker,) = [int(pid) for pid in caller.stdout.readline().split()]
    assert process_alive(worker)
    os.kill(caller.pid, signal.SIGKILL)
    caller.wait()
    assert wait_until_gone([worker], 30), "a worker outlived its killed caller"


def test_two_processes_by_default_only_where_the_copies_step_in_turn(monkeypatch):
    monkeypatch.delenv(sharded.WORKERS_VARIABLE, raising=False)
    monkeypatch.setattr(sharded, "usable_cores", lambda: 2)
    in_turn = mrcomm_env.make("AsyncCL-v0", n_robots=3)  # no copy-axis world: its copies step one after another
    world = mrcomm_env.make("MapSync-v0")  # a copy-axis world
    assert type(in_turn).copy_axis_world(in_turn.cfg) is None and type(world).copy_axis_world(world.cfg) is not None
    assert default_workers(in_turn, 8) == 2
    assert default_workers(in_turn, 1) == 1
    assert default_workers(world, 8) == 1
    monkeypatch.setattr(sharded, "usable_cores", lambda: 1)
    assert default_workers(in_turn, 8) == 1
    monkeypatch.setenv(sharded.WORKERS_VARIABLE, "3")
    assert default_workers(world, 8) == 3 and default_workers(world, 2) == 2
    monkeypatch.setenv(sharded.WORKERS_VARIABLE, "none")
    with pytest.raises(ValueError, match="MRCOMM_ENV_WORKERS must be an integer ≥ 1"):
        default_workers(world, 8)
    monkeypatch.setenv(sharded.WORKERS_VARIABLE, "1")
    assert isinstance(stepping_batch(maker("AsyncCL-v0", n_robots=3), 4), BatchedEnv)
    sharded_batch = stepping_batch(maker("AsyncCL-v0", n_robots=3), 4, 2)
    assert isinstance(sharded_batch, ShardedBatchedEnv) and sharded_batch.workers == 2
    sharded_batch.close()
