"""M copies of one environment stepped by several processes at once (``ShardedBatchedEnv``).

Where an env's own step is most of a training's time (AsyncCL's EKF, RendezvousMapping's decision phases: 85–88 %
of the batched trainer's wall time), the copies of a batch can step on more than one core. ``ShardedBatchedEnv``
splits the M copies into K contiguous shards: shard 0 is a :class:`~mrcomm_env.core.batched.BatchedEnv` in the
calling process, every other shard a ``BatchedEnv`` in a worker process of its own. A step sends each worker its
shard's actions, steps shard 0 meanwhile, then joins the shards' results along the copy axis, so the caller sees
one :class:`~mrcomm_env.core.batched.BatchStep` of M copies, as from one ``BatchedEnv`` (PufferLib and SB3's
``SubprocVecEnv`` split their copies the same way; ours keep the copy-axis worlds inside each shard).

**The same numbers.** A shard beginning at copy a is reset with seed ``s + a``, so copy i is still the single env
seeded ``s + i``, byte for byte, and a training run sees the same observations, rewards and infos whatever K is
(``tests/core/test_sharded.py`` compares whole episodes, and ``tests/policies/test_batched_ppo.py`` a training's
weights). Only the wall time changes.

**Processes.** Each worker is a fresh interpreter (``python -m mrcomm_env.core.sharded``: no copy of the caller's torch
threads or open files, and unlike multiprocessing's ``spawn`` no second import of the caller's script) that imports
only this package's env modules; they ignore Ctrl-C, which the caller handles (the trainer saves
its checkpoint first), and they exit when the caller closes the batch, drops it (garbage collection) or dies (the
caller's end of their socket pair closes, even after ``kill -9``). An exception in a worker is raised in the caller as a ``RuntimeError`` carrying the worker's
traceback. Each worker holds its shard's copies plus an interpreter with numpy, numba, scipy and the env modules (about
210 MiB, ``WORKER_BYTES``), which the memory check adds to the copies' own estimate.
"""

from __future__ import annotations

import os
import pickle
import signal
import socket
import subprocess
import sys
import traceback
import weakref
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from numbers import Integral
from typing import Any

import numpy as np
from gymnasium import spaces

from mrcomm_env.core.base import MrcommParallelEnv
from mrcomm_env.core.batched import BatchedEnv, BatchStep, checked_actions, copy_options, copy_seeds
from mrcomm_env.core.memory import BUDGET_ARGUMENT, GIB

#: environment variable: the default number of stepping processes (``default_workers``); a sweep's worker processes,
#: which already share the cores among themselves, set it to 1
WORKERS_VARIABLE = "MRCOMM_ENV_WORKERS"
#: a worker's own memory besides its copies: the interpreter with numpy, numba, scipy, matplotlib and the env modules
#: (measured resident: 211 MiB for one small AsyncCL copy; 243 MiB for 52 default AsyncCL copies, whose estimate is
#: 56 MiB; 228 MiB for 26 RendezvousMapping copies, estimate 28 MiB)
WORKER_BYTES = 224 << 20


def _serve(connection) -> None:
    """A worker: builds one ``BatchedEnv`` from the first message, ``(make_copy, n_copies)``, then answers
    (command, argument) messages on ``connection`` until "close" or until the caller's end closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the caller handles Ctrl-C and closes the workers
    try:
        make_copy, n_copies = connection.recv()
        batch = BatchedEnv(make_copy, n_copies, copy=False)
    except (EOFError, OSError):  # the caller is gone
        return
    except BaseException:  # noqa: BLE001 — reported to the caller, which raises it
        _answer(connection, ("error", traceback.format_exc()))
        return
    if not _answer(connection, ("ok", None)):
        return
    while True:
        try:
            command, argument = connection.recv()
        except (EOFError, OSError):  # the caller is gone
            return
        if command == "close":
            batch.close()
            return
        try:
            if command == "step":
                reply: Any = batch.step(argument)  # pickling copies the batch's own buffers
            elif command == "reset":
                seeds, options = argument
                reply = batch.reset(seed=seeds, options=options)
            elif command == "restart":
                infos = batch.restart(argument)
                reply = (batch.observations, infos)
            elif command == "bits_sent":
                reply = batch.bits_sent()
            elif command == "metrics":
                reply = batch.metrics()
            elif command == "render_copy":
                reply = None if argument is None else batch.render_copy(argument)
            else:
                raise ValueError(f"unknown command {command!r}")
        except BaseException:  # noqa: BLE001 — reported to the caller, which raises it
            message: tuple[str, Any] = ("error", traceback.format_exc())
        else:
            message = ("ok", reply)
        if not _answer(connection, message):
            return


def _answer(connection, message: tuple[str, Any]) -> bool:
    """Send ``message`` to the caller; False when the caller is gone (the worker then exits quietly)."""
    try:
        connection.send(message)
    except OSError:  # a broken pipe: the caller closed its end or died
        return False
    return True


def _start_worker(make_copy: Callable[[], MrcommParallelEnv], n_copies: int) -> tuple[Connection, subprocess.Popen]:
    """A fresh interpreter running :func:`_serve` on one end of a socket pair (``python -m`` this module): unlike
    multiprocessing's ``spawn``, it never imports the caller's main script again, so a script needs no
    ``if __name__ == "__main__"`` guard."""
    try:
        payload = pickle.dumps((make_copy, n_copies))
    except Exception as error:  # noqa: BLE001 — any pickling failure means the same thing to the caller
        raise ValueError(
            "argument 'make_copy' must pickle (a module-level function, or functools.partial(make, env_id, **kwargs)) "
            f"for the worker processes to build their copies: {error}"
        ) from None
    mine, theirs = socket.socketpair()
    try:
        process = subprocess.Popen(
            [sys.executable, "-m", __name__, str(theirs.fileno())], pass_fds=[theirs.fileno()], close_fds=True
        )
    finally:
        theirs.close()
    connection = Connection(mine.detach())
    connection.send_bytes(payload)
    return connection, process


def _end_workers(connections: list[Connection], processes: list[subprocess.Popen]) -> None:
    """Tell each worker to close its copies and exit, and close our ends (a worker still busy with a call the caller
    gave up on, e.g. at Ctrl-C, exits when its answer finds the end closed); one not gone within 5 s is killed."""
    for connection in connections:
        try:
            connection.send(("close", None))
        except OSError:  # already gone
            pass
        connection.close()
    for process in processes:
        try:
            process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


class ShardedBatchedEnv:
    """M copies of one mrcomm environment stepped by ``workers`` processes (see the module docstring): the same
    interface and numbers as :class:`~mrcomm_env.core.batched.BatchedEnv` for ``reset``, ``step``, ``restart``,
    ``observations``, ``render_copy``, ``bits_sent``, ``metrics`` and ``close``.

    :param make_copy: returns a new env per call, and must pickle (``functools.partial(make, env_id, **kwargs)``):
        each worker builds its own copies with it.
    :param n_copies: M ≥ 1.
    :param workers: K ≥ 1 processes, the caller's included; at most M (each shard holds at least one copy).
    :param copy: as ``BatchedEnv``'s: False returns the batch's own observation buffer, valid until the next call.
    :raises ValueError: an argument out of range, or copies and workers that together need more memory than the
        env's budget (naming ``n_copies`` and ``workers``).
    """

    n_copies: int
    n_agents: int
    workers: int
    copy: bool
    #: the copies of each shard: shard k steps copies ``bounds[k]`` … ``bounds[k + 1] − 1``
    bounds: list[int]
    #: shard 0, stepped in this process
    local: BatchedEnv
    possible_agents: list[str]
    observation_space: spaces.Space
    action_space: spaces.Space
    #: ends the workers once: at close(), when the batch is garbage-collected, or at the interpreter's exit
    _finalizer: weakref.finalize
    #: a call's answers are outstanding (set while it runs; left set when it was interrupted midway)
    _interrupted: bool

    def __init__(
        self, make_copy: Callable[[], MrcommParallelEnv], n_copies: int, workers: int = 2, copy: bool = True
    ) -> None:
        if isinstance(n_copies, bool) or not isinstance(n_copies, Integral) or n_copies < 1:
            raise ValueError(f"argument 'n_copies' must be an integer ≥ 1, got {n_copies!r}")
        if isinstance(workers, bool) or not isinstance(workers, Integral) or not 1 <= workers <= n_copies:
            raise ValueError(
                f"argument 'workers' must be an integer in [1, n_copies = {n_copies}] (each process steps at least "
                f"one copy), got {workers!r}"
            )
        self.n_copies, self.workers, self.copy = int(n_copies), int(workers), bool(copy)
        self.bounds = [int(part[0]) for part in np.array_split(np.arange(self.n_copies), self.workers)] + [
            self.n_copies
        ]
        sizes = [b - a for a, b in zip(self.bounds[:-1], self.bounds[1:])]
        self._connections: list[Connection] = []
        self._processes: list[subprocess.Popen] = []
        self._finalizer = weakref.finalize(self, _end_workers, self._connections, self._processes)
        self.local = BatchedEnv(make_copy, sizes[0], copy=False)
        first = self.local.envs[0]
        self._check_memory(first, sizes)
        self.n_agents = self.local.n_agents
        self.possible_agents = list(self.local.possible_agents)
        self.observation_space = self.local.observation_space
        self.action_space = self.local.action_space
        self._action_shape: tuple[int, ...] = (self.n_copies, self.n_agents, *(self.action_space.shape or ()))
        self._observations: np.ndarray | None = None
        self._interrupted = False
        try:
            for size in sizes[1:]:
                connection, process = _start_worker(make_copy, size)
                self._connections.append(connection)
                self._processes.append(process)
            for connection in self._connections:  # built, or the worker's construction error
                status, payload = self._read(connection)
                if status == "error":
                    raise RuntimeError(f"a worker of the sharded batch failed:\n{payload}")
        except BaseException:
            self.close()
            raise

    def _check_memory(self, env: MrcommParallelEnv, sizes: list[int]) -> None:
        """The copies' own estimate (``BatchedEnv``'s check) plus each worker's interpreter, against the budget."""
        BatchedEnv.check_memory(env, self.n_copies)
        budget = float(env.cfg[BUDGET_ARGUMENT]) * GIB
        need = sum(float(env.batch_memory_estimate(env.cfg, size)) for size in sizes) + WORKER_BYTES * len(sizes[1:])
        if need > budget:
            raise ValueError(
                f"{env.ENV_ID}: arguments 'n_copies' ({self.n_copies}) and 'workers' ({self.workers}) need an estimated "
                f"{need / GIB:.3g} GiB together, over the memory budget of {budget / GIB:g} GiB; use fewer copies or "
                f"workers, or raise the budget on purpose with '{BUDGET_ARGUMENT}'"
            )

    def _call(self, command: str, arguments: Sequence[Any], local: Callable[[], Any]) -> list[Any]:
        """Send each worker ``command`` with its argument, run ``local`` here meanwhile, then read every worker's
        answer: ``[local's result, *the workers' results]``. Every answer is read even when ``local`` or a worker
        fails (the first failure is then raised), so the next call pairs with its own answers; a call interrupted
        while answers are outstanding (Ctrl-C) leaves the batch unusable, and says so at the next call."""
        if self._interrupted:
            raise RuntimeError(
                "the sharded batch was interrupted in the middle of a call and its workers' answers are out of step: "
                "close it and make a new one"
            )
        self._interrupted = True  # until every answer is in
        for connection, argument in zip(self._connections, arguments):
            connection.send((command, argument))
        failure: BaseException | None = None
        mine = None
        try:
            mine = local()
        except Exception as error:  # noqa: BLE001 — raised below, once the workers' answers are read
            failure = error
        answers = [self._read(connection) for connection in self._connections]
        self._interrupted = False
        if failure is not None:
            raise failure
        for status, payload in answers:
            if status == "error":
                raise RuntimeError(f"a worker of the sharded batch failed:\n{payload}")
        return [mine, *(payload for _, payload in answers)]

    def _read(self, connection: Connection) -> tuple[str, Any]:
        try:
            return connection.recv()
        except EOFError:
            raise RuntimeError("a worker of the sharded batch exited unexpectedly") from None

    def _shard_slices(self) -> list[slice]:
        return [slice(a, b) for a, b in zip(self.bounds[:-1], self.bounds[1:])]

    # ----------------------------------------------------------------- reset and step
    def reset(
        self, seed: int | Sequence[int | None] | None = None, options: dict | Sequence[dict | None] | None = None
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Reset every copy (``BatchedEnv.reset``'s meaning of ``seed`` and ``options``: copy i gets s + i)."""
        seeds = copy_seeds(seed, self.n_copies)
        per_options = copy_options(options, self.n_copies)
        slices = self._shard_slices()
        results = self._call(
            "reset",
            [(seeds[part], per_options[part]) for part in slices[1:]],
            lambda: self.local.reset(seed=seeds[slices[0]], options=per_options[slices[0]]),
        )
        self._observations = np.concatenate([observations for observations, _ in results])
        infos = {key: np.concatenate([columns[key] for _, columns in results]) for key in results[0][1]}
        return self._returned(self._observations), infos

    def step(self, actions: np.ndarray) -> BatchStep:
        """Step every copy with ``actions`` ``(M, N, *action_shape)``; copies that end are reset (``BatchStep``)."""
        actions = checked_actions(actions, self._action_shape, self._observations is not None)
        slices = self._shard_slices()
        steps = self._call("step", [actions[part] for part in slices[1:]], lambda: self.local.step(actions[slices[0]]))
        return self._joined(steps)

    def _joined(self, steps: list[BatchStep]) -> BatchStep:
        """The shards' steps as one step of M copies (their per-copy dicts re-indexed by global copy)."""
        observations = np.concatenate([step.observations for step in steps])
        rewards = np.concatenate([step.rewards for step in steps])
        terminated = np.concatenate([step.terminated for step in steps])
        truncated = np.concatenate([step.truncated for step in steps])
        infos = {key: np.concatenate([step.infos[key] for step in steps]) for key in steps[0].infos}
        joined = BatchStep(observations, rewards, terminated, truncated, infos)
        for start, step in zip(self.bounds, steps):
            joined.final_observations.update((start + i, v) for i, v in step.final_observations.items())
            joined.final_metrics.update((start + i, v) for i, v in step.final_metrics.items())
            joined.reset_infos.update((start + i, v) for i, v in step.reset_infos.items())
        self._observations = observations
        joined.observations = self._returned(observations)
        return joined

    def _returned(self, observations: np.ndarray) -> np.ndarray:
        return observations.copy() if self.copy else observations

    def restart(self, copies: Sequence[int]) -> dict[int, dict[str, np.ndarray]]:
        """Begin a new episode of each copy in ``copies`` only (``BatchedEnv.restart``)."""
        if self._observations is None:
            raise RuntimeError("restart() called before reset(); call reset() first")
        slices = self._shard_slices()
        chosen = [[int(i) - part.start for i in copies if part.start <= int(i) < part.stop] for part in slices]
        mine, *theirs = self._call("restart", chosen[1:], lambda: self.local.restart(chosen[0]))
        reset_infos = {slices[0].start + i: v for i, v in mine.items()}
        self._observations[slices[0]] = self.local.observations
        for part, (observations, infos) in zip(slices[1:], theirs):
            self._observations[part] = observations
            reset_infos.update((part.start + i, v) for i, v in infos.items())
        return reset_infos

    @property
    def worker_pids(self) -> list[int]:
        """The process ids of the workers (shards 1 … K − 1; shard 0 steps in this process)."""
        return [process.pid for process in self._processes]

    @property
    def observations(self) -> np.ndarray:
        """``(M, N, *obs_shape)``: what every agent of every copy acts on next (``BatchedEnv.observations``)."""
        if self._observations is None:
            raise RuntimeError("observations read before reset(); call reset() first")
        return self._observations

    def render_copy(self, index: int = 0) -> np.ndarray:
        """Copy ``index`` drawn as ``render()`` draws in ``rgb_array`` mode (``BatchedEnv.render_copy``), by the process
        that steps it."""
        if not 0 <= int(index) < self.n_copies:
            raise ValueError(f"argument 'index' must be in [0, {self.n_copies - 1}], got {index!r}")
        shard = next(k for k in range(self.workers) if int(index) < self.bounds[k + 1])
        local = int(index) - self.bounds[shard]
        if shard == 0:
            return self.local.render_copy(local)
        # every worker answers (None: it draws nothing); the one that steps the copy draws it
        arguments = [local if k == shard - 1 else None for k in range(len(self._connections))]
        return self._call("render_copy", arguments, lambda: None)[shard]

    # ----------------------------------------------------------------- per-copy readings
    def bits_sent(self) -> np.ndarray:
        """``(M,)``: bits every robot of each copy has sent since the copy's last reset, summed."""
        return np.concatenate(self._call("bits_sent", [None] * len(self._connections), self.local.bits_sent))

    def metrics(self) -> list[dict[str, float]]:
        """Each copy's metrics of its current episode so far."""
        shards = self._call("metrics", [None] * len(self._connections), self.local.metrics)
        return [entry for shard in shards for entry in shard]

    def close(self) -> None:
        """Close every copy and end the workers (waiting briefly for each, then killing it). A batch that is never
        closed ends its workers when it is garbage-collected, or when this process exits."""
        self._finalizer()
        if getattr(self, "local", None) is not None:
            self.local.close()


def usable_cores() -> int:
    """The cores this process may run on (its affinity where the platform says, else the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def default_workers(env: MrcommParallelEnv, n_copies: int) -> int:
    """How many processes step ``n_copies`` copies of ``env`` when the caller names none: ``MRCOMM_ENV_WORKERS`` if
    set, else two (at most the usable cores and the copies) where the copies step in turn, one env object after
    another, and one where a copy-axis world steps them all as arrays. Measured on two cores (docs/performance.md,
    "stepping processes"): two processes stepped copies that step in turn 1.5–2.0× as fast as one (AsyncCL,
    RendezvousMapping, MapSync's limited links, MultiHop's moving robots before they had a world, ChannelAssociation's
    miss tolerance), and the copy-axis worlds of ChannelAssociation, MapSync and MultiHop 0.3–0.7× as fast (a step
    of theirs costs less than the exchange with a worker)."""
    given = os.environ.get(WORKERS_VARIABLE)
    if given:
        try:
            workers = int(given)
        except ValueError:
            workers = 0
        if workers < 1:
            raise ValueError(f"environment variable {WORKERS_VARIABLE} must be an integer ≥ 1, got {given!r}")
        return max(1, min(workers, int(n_copies)))
    if n_copies < 2 or type(env).copy_axis_world(env.cfg) is not None:
        return 1
    return max(1, min(2, usable_cores(), int(n_copies)))


def stepping_batch(
    make_copy: Callable[[], MrcommParallelEnv], n_copies: int, workers: int | None = None, copy: bool = True
) -> BatchedEnv | ShardedBatchedEnv:
    """``n_copies`` copies stepped by ``workers`` processes (None: :func:`default_workers`): a ``BatchedEnv`` for
    one, a :class:`ShardedBatchedEnv` for more (``make_copy`` must then pickle). Both give the same numbers."""
    if workers is None:
        probe = make_copy()
        workers = default_workers(probe, int(n_copies))
        probe.close()
    if workers == 1:
        return BatchedEnv(make_copy, n_copies, copy=copy)
    return ShardedBatchedEnv(make_copy, n_copies, workers, copy=copy)


if __name__ == "__main__":  # a worker process (``_start_worker``): its end of the socket pair is argv[1]
    _serve(Connection(int(sys.argv[1])))
