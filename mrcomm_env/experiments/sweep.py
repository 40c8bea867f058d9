"""One runner for every sweep: reproductions' Monte-Carlo runs, ``reproduce-learning`` and ``mrcomm train --seeds``.

A sweep is a list of independent :class:`Task` s. A task names an importable function (``"module:function"``)
and its keyword arguments, which hold everything that decides its result: env id, arguments, policy and seed.
The runner only decides *where* a task runs; it never seeds anything, so a sweep gives identical numbers
whatever the backend, and results always come back in task order (the merge order is the list's order).

Backends, chosen by one flag of the CLI (:func:`add_runner_arguments`):

* ``--workers 1`` — serially in this process (tests and debugging: a breakpoint works);
* ``--workers N`` — ``N`` local processes (:class:`concurrent.futures.ProcessPoolExecutor`, ``spawn``), each
  with one BLAS/torch thread; the default is one per core;
* ``--ray auto|ADDRESS`` — one Ray task per sweep task on an existing cluster (the ``ray`` extra;
  docs/scaling.md). Ray schedules; we do not.

Every backend shows one progress bar over the tasks and retries a failed task once (on Ray, a task that raised
is resubmitted by the runner; a task whose worker or node died is rerun by Ray's own ``max_retries``). On Ray,
each task first checks that its node runs the driver's code (:func:`code_version`). With a ``cache`` folder, each result is written there atomically as soon
as its task ends, under a name that includes a hash of the task, and a rerun loads it instead of running
the task again: an interrupted sweep resumes where it stopped, and a task whose arguments changed runs anew.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import functools
import hashlib
import importlib
import importlib.util
import json
import multiprocessing
import os
import re
import signal
import socket
import sys
import threading
import time
import warnings
from collections.abc import Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm

from mrcomm_env.core.sharded import WORKERS_VARIABLE
from mrcomm_env.experiments.arguments import positive_int
from mrcomm_env.experiments.io import atomic_write_text

#: prctl(2) option: the signal a process gets when its parent dies
PR_SET_PDEATHSIG = 1

#: attempts per task: the first run and one retry
ATTEMPTS = 2
#: how long a stopping driver goes on cancelling its Ray tasks until each has ended (:func:`cancel_until_gone`)
CANCEL_SECONDS = 30.0


class SweepError(RuntimeError):
    """Tasks that failed twice; the message names each with its arguments (completed results are kept)."""


@dataclass(frozen=True)
class Task:
    """``fn(**kwargs)``, where ``fn`` is ``"package.module:function"`` (importable on every worker) and kwargs and
    the result are JSON data. ``name`` labels the task in progress output, errors and the cache."""

    fn: str
    kwargs: dict[str, Any] = field(default_factory=dict)
    name: str = ""

    def key(self) -> str:
        """A file-safe name that changes whenever the function, any argument or the package's code does."""

        blob = json.dumps([self.fn, self.kwargs, code_version()], sort_keys=True, default=str)
        digest = hashlib.sha1(blob.encode()).hexdigest()[:12]
        label = re.sub(r"[^A-Za-z0-9_.=,-]+", "_", self.name or self.fn.rsplit(":", 1)[-1])[:80]
        return f"{label}-{digest}"

    def describe(self) -> str:
        return f"{self.name or self.fn} {json.dumps(self.kwargs, sort_keys=True, default=str)}"


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """A hash of every Python source of the installed packages (env, baselines, agents): a cached result is
    reused only by the code that computed it, so an edit never mixes old numbers into a new run."""
    digest = hashlib.sha1()
    for package in ("mrcomm_env", "baselines", "agents"):
        spec = importlib.util.find_spec(package)  # located, not imported: importing agents loads torch
        if spec is None or spec.origin is None:
            continue
        root = Path(spec.origin).parent
        for path in sorted(root.rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def execute(fn: str, kwargs: dict[str, Any]) -> Any:
    """Run one task in the current process (what every backend calls on its worker)."""
    module, _, name = fn.partition(":")
    if not name:
        raise ValueError(f"task function must be 'module:function', got {fn!r}")
    return getattr(importlib.import_module(module), name)(**kwargs)


def _worker_start(parent: int) -> None:
    """What every local worker process runs first: it dies with the process that started it, and uses one core."""
    _die_with_parent(parent)
    one_thread()


def _die_with_parent(parent: int) -> None:
    """Ask Linux to kill this process when its parent dies (``prctl(PR_SET_PDEATHSIG)``): a ``kill -9`` of
    ``mrcomm reproduce`` must not leave its workers running. Elsewhere, a thread polls for the parent instead."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    else:
        threading.Thread(target=_exit_when_orphaned, args=(parent,), daemon=True).start()
    if os.getppid() != parent:  # the parent died before the request was made
        os._exit(1)


def _exit_when_orphaned(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(1.0)
    os._exit(1)


def one_thread() -> None:
    """Each worker process uses one core: BLAS and torch would otherwise start one thread per core each.

    The batched trainer still runs its update on its ``update_threads`` (two by default: a model's bits depend on
    the thread count, so a sweep's runs stay those of ``--workers 1``). Its OpenMP threads then wait passively:
    spinning, two workers' four threads on two cores ran MapSync's IPPO at 3,300 agent-steps/s each, two seeds of
    401,408 agent-steps in 132 s against 36 s one after the other; waiting passively, in 28-32 s
    (``OMP_WAIT_POLICY``, read when torch loads; alone, passive waiting halves the trainer's speed, so only workers
    set it)."""
    os.environ["OMP_NUM_THREADS"] = "1"
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    # the workers already share the cores: a batched run's copies step in the worker itself (core.sharded)
    os.environ[WORKERS_VARIABLE] = "1"
    os.environ["MKL_NUM_THREADS"] = "1"
    # torch reads OMP_NUM_THREADS when it is first imported (and ``mrcomm train`` sets one thread itself); a
    # worker that already has torch loaded is told directly. Importing torch here would cost each worker ~2 s.
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


def _plain(value: Any) -> Any:
    """numpy scalars and arrays as Python numbers and lists (``json`` calls this for what it cannot encode)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"a task result must be JSON data (numbers, strings, lists, dicts), got {type(value).__name__}")


def _normalise(result: Any) -> Any:
    """The result as JSON gives it back: a cached, a remote and a serial result are then the same values
    (floats survive exactly: ``json`` writes the shortest repr that reads back as the same double)."""
    return json.loads(json.dumps(result, default=_plain))


@dataclass
class Runner:
    """Where tasks run: ``workers`` local processes (1 = serially, here), or the Ray cluster at ``ray``."""

    workers: int = 1
    ray: str | None = None
    progress: bool = True
    #: what the last :meth:`map` did: tasks run here or remotely, loaded from the cache, and retried
    stats: dict[str, int] = field(default_factory=dict, compare=False)
    _pool: Any = field(default=None, init=False, repr=False, compare=False)
    _keep_pool: bool = field(default=False, init=False, repr=False, compare=False)

    def __post_init__(self):
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1:
            raise ValueError(f"argument 'workers' must be an integer ≥ 1, got {self.workers!r}")
        if self.ray is not None and (not isinstance(self.ray, str) or not self.ray.strip()):
            raise ValueError(
                f"argument 'ray' must be 'auto' or a cluster address such as 'HOST:6379', got {self.ray!r}"
            )

    @property
    def backend(self) -> str:
        return "ray" if self.ray else "serial" if self.workers == 1 else f"processes×{self.workers}"

    def map(self, tasks: Sequence[Task], cache: str | Path | None = None, desc: str = "tasks") -> list[Any]:
        """The results of ``tasks``, in their order. Raises :class:`SweepError` after all others have finished
        when any task failed twice."""
        tasks = list(tasks)
        keys = [t.key() for t in tasks]
        if len(set(keys)) != len(keys):
            dup = next(t for t, k in zip(tasks, keys) if keys.count(k) > 1)
            raise ValueError(f"a sweep must not hold the same task twice: {dup.describe()}")
        results: list[Any] = [None] * len(tasks)
        done = [False] * len(tasks)
        cache_dir = Path(cache) if cache is not None else None
        if cache_dir is not None:
            for i, key in enumerate(keys):
                path = cache_dir / f"{key}.json"
                if path.exists():
                    try:
                        results[i], done[i] = json.loads(path.read_text())["result"], True
                    except (json.JSONDecodeError, KeyError, TypeError, UnicodeDecodeError):
                        # a file damaged outside our atomic writes: run the task again and overwrite it
                        warnings.warn(f"cached result {path} is corrupt; running its task again", stacklevel=2)
        todo = [i for i in range(len(tasks)) if not done[i]]
        failures: list[str] = []
        errors: list[BaseException] = []
        self.stats = {"run": len(todo), "cached": len(tasks) - len(todo), "retried": 0}

        bar = tqdm(total=len(tasks), initial=len(tasks) - len(todo), desc=desc, disable=not self.progress)

        def finished(i: int, result: Any = None, error: BaseException | None = None) -> None:
            bar.update()
            if error is not None:
                failures.append(f"{tasks[i].describe()}: {type(error).__name__}: {error}")
                errors.append(error)
                return
            results[i] = _normalise(result)
            if cache_dir is not None:
                cache_dir.mkdir(parents=True, exist_ok=True)
                record = {"task": {"fn": tasks[i].fn, "kwargs": tasks[i].kwargs, "name": tasks[i].name}}
                atomic_write_text(cache_dir / f"{keys[i]}.json", json.dumps({**record, "result": results[i]}))

        try:
            if not todo:
                pass
            elif self.ray:
                self._map_ray(tasks, todo, finished)
            elif self.workers == 1 or len(todo) == 1:
                for i in todo:
                    self._serial(tasks[i], i, finished)
            else:
                self._map_processes(tasks, todo, finished)
        finally:
            bar.close()
        if failures:
            more = f" (and {len(failures) - 1} more)" if len(failures) > 1 else ""
            # chained to the first failure: ``mrcomm --debug`` then shows where that task failed, not only here
            raise SweepError(f"{len(failures)} of {len(tasks)} tasks failed twice; {failures[0]}{more}") from errors[0]
        return results

    # ------------------------------------------------------------------------------------------ backends
    def _serial(self, task: Task, i: int, finished) -> None:
        for attempt in range(ATTEMPTS):
            try:
                result = execute(task.fn, task.kwargs)
            except Exception as exc:  # noqa: BLE001 — a failed task is retried, then reported with its arguments
                if attempt == ATTEMPTS - 1:
                    finished(i, error=exc)
                else:
                    self.stats["retried"] += 1
                continue
            finished(i, result)
            return

    def _map_processes(self, tasks: Sequence[Task], todo: list[int], finished) -> None:

        pool = self._pool
        if pool is None:
            # spawn, not fork: a forked child inherits the parent's torch/BLAS thread pools and locks
            context = multiprocessing.get_context("spawn")
            size = self.workers if self._keep_pool else min(self.workers, len(todo))
            pool = ProcessPoolExecutor(size, mp_context=context, initializer=_worker_start, initargs=(os.getpid(),))
            if self._keep_pool:  # inside ``using``: the workers (and their imports) serve every sweep of the block
                self._pool = pool
        pending = {pool.submit(execute, tasks[i].fn, tasks[i].kwargs): (i, 1) for i in todo}
        try:
            while pending:
                complete, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in complete:
                    i, attempt = pending.pop(future)
                    error = future.exception()
                    if error is None:
                        finished(i, future.result())
                    elif attempt < ATTEMPTS:
                        self.stats["retried"] += 1
                        pending[pool.submit(execute, tasks[i].fn, tasks[i].kwargs)] = (i, attempt + 1)
                    else:
                        finished(i, error=error)
        except BaseException:
            # Ctrl-C (or an error here): waiting for the pool would run every queued task first
            self._pool = None
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        if pool is not self._pool:
            pool.shutdown(wait=True)

    def close(self) -> None:
        """Stop the worker processes a ``using`` block kept (idempotent)."""
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)

    def _map_ray(self, tasks: Sequence[Task], todo: list[int], finished) -> None:
        try:
            import ray
        except ImportError as exc:
            raise ValueError("argument 'ray' needs Ray: pip install 'mrcomm-env[ray]' (docs/scaling.md)") from exc

        driver = {"code": code_version()}
        if not ray.is_initialized():
            # one BLAS/torch thread per task, as for local processes; the package must be importable on every node
            # (installed there, as docs/scaling.md shows). A session the caller opened is used as it is.
            env_vars = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
            ray.init(address=self.ray, runtime_env={"env_vars": env_vars}, log_to_driver=False)
        # Ray itself reruns a task whose worker process or node died (max_retries). A task that raised is
        # resubmitted here instead of by Ray's retry_exceptions, so that the retry shows in ``stats`` as on the
        # other backends.
        remote = ray.remote(num_cpus=1, max_retries=ATTEMPTS - 1, retry_exceptions=False)(_ray_execute)

        def submit(i: int):
            return remote.options(name=tasks[i].key()).remote(tasks[i].fn, tasks[i].kwargs, driver)

        pending = {submit(i): (i, 1) for i in todo}
        try:
            while pending:
                complete, _ = ray.wait(list(pending), num_returns=1)
                for ref in complete:
                    i, attempt = pending.pop(ref)
                    outcome = _ray_outcome(ray, ref)
                    if isinstance(outcome, _RayTaskFailed) and attempt < ATTEMPTS:
                        self.stats["retried"] += 1
                        pending[submit(i)] = (i, attempt + 1)
                    elif isinstance(outcome, (_RayTaskFailed, _RayLost)):
                        finished(i, error=outcome.error)
                    else:
                        finished(i, outcome)
        finally:
            # an interrupted or failed driver leaves no task of its sweep running on the cluster
            cancel_until_gone(ray, list(pending))


def cancel_until_gone(ray, refs: list, seconds: float = CANCEL_SECONDS) -> None:
    """Cancel ``refs`` (``force``: a running task's worker exits) and cancel again, once a second, those that have
    not ended, for at most ``seconds``. Ray can lose a cancel that reaches a task between its dispatch to a worker
    and its start (ray-project/ray#24359, #52703); the task then runs to its end and holds its CPU. This happened
    once in our CI: one of two cancelled tasks of two minutes still held its CPU a minute later."""
    deadline = time.monotonic() + seconds
    while refs:
        for ref in refs:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return
        try:
            _, refs = ray.wait(refs, num_returns=len(refs), timeout=min(1.0, remaining))
        except Exception:  # noqa: BLE001 - the session went away: nothing is left to cancel from here
            return


@dataclass(frozen=True)
class _RayTaskFailed:
    """The task's function raised (it is retried once): ``error`` is the exception as the task raised it."""

    error: BaseException


@dataclass(frozen=True)
class _RayLost:
    """Ray gave up on the task: its worker or node died twice, or it was cancelled (not retried here)."""

    error: BaseException


def _ray_outcome(ray, ref) -> Any:
    """The task's result, or why there is none (:class:`_RayTaskFailed`, :class:`_RayLost`)."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as exc:
        cause = getattr(exc, "cause", None)
        if not isinstance(cause, BaseException):
            return _RayTaskFailed(exc)
        if cause.__cause__ is None:
            # the error as the task raised it, chained to Ray's copy that holds the remote traceback (what
            # ``mrcomm --debug`` then shows)
            cause.__cause__ = exc
        return _RayTaskFailed(cause)
    except ray.exceptions.RayError as exc:
        return _RayLost(exc)


class CodeMismatch(RuntimeError):
    """A Ray node runs other mrcomm-env code than the driver: its numbers would not be the driver's, and would be
    cached under the driver's key."""


def _ray_execute(fn: str, kwargs: dict[str, Any], driver: dict[str, str] | None = None) -> Any:
    """What a Ray worker runs: :func:`execute`, after checking that this node has the driver's code (the cache
    key holds the driver's :func:`code_version`)."""
    one_thread()
    if driver is not None:
        here = code_version()
        if here != driver["code"]:
            raise CodeMismatch(
                f"node {socket.gethostname()} runs mrcomm-env code {here}, the driver code {driver['code']}: install "
                f"the same version of mrcomm-env, with the same extras, on every node (docs/scaling.md)"
            )
    return execute(fn, kwargs)


# ---------------------------------------------------------------------------------- the runner in use
_ACTIVE: list[Runner] = []


def current() -> Runner:
    """The runner chosen by the caller (:func:`using`); serial, with a progress bar, by default."""
    return _ACTIVE[-1] if _ACTIVE else Runner()


@contextlib.contextmanager
def using(runner: Runner) -> Iterator[Runner]:
    """Run every sweep inside the block (e.g. a whole reproduction) on ``runner``; local worker processes are
    started once, at the first sweep, and stopped when the block ends (each costs seconds of imports)."""
    _ACTIVE.append(runner)
    keep, runner._keep_pool = runner._keep_pool, True
    try:
        yield runner
    finally:
        _ACTIVE.pop()
        runner._keep_pool = keep
        if not keep:
            runner.close()


def run_tasks(tasks: Sequence[Task], cache: str | Path | None = None, desc: str = "tasks") -> list[Any]:
    """``current().map(tasks, cache, desc)``: what a reproduction calls for its Monte-Carlo runs."""
    return current().map(tasks, cache=cache, desc=desc)


# ------------------------------------------------------------------------------------------------- CLI
def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def add_runner_arguments(parser: argparse.ArgumentParser) -> None:
    """``--workers N`` and ``--ray auto|ADDRESS`` (mutually exclusive)."""

    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="local processes, one core each (default: one per core; 1 runs serially)",
    )
    group.add_argument("--ray", metavar="auto|ADDRESS", help="run each task on this Ray cluster (docs/scaling.md)")


def runner_from_args(args: argparse.Namespace, progress: bool = True) -> Runner:
    workers = args.workers if getattr(args, "workers", None) is not None else default_workers()
    return Runner(workers=workers, ray=getattr(args, "ray", None), progress=progress)
