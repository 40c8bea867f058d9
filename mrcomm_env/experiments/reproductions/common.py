"""What the reproductions share: run sizes, progress bars, figures and the episode loop.

* :func:`size_of` / :func:`pick` — one reproduction, three sizes: ``full`` (the paper's), ``quick`` (a few
  minutes, indicative numbers) and ``tiny`` (seconds, for the smoke test: every file is written, the
  numbers mean nothing);
* :func:`progress` — the progress bar of a loop that stays in this process (a timing measurement);
* :func:`task` / :func:`run_sweep` — the Monte-Carlo work of a reproduction as independent tasks through the
  one sweep runner (:mod:`mrcomm_env.experiments.sweep`): each task seeds itself from its own arguments, so the
  numbers do not depend on where it runs, and its result is cached under ``<out>/tasks`` for a resumed run;
* :func:`figure` — a matplotlib figure on the Agg canvas (no pyplot: a reproduction never changes the
  caller's backend or leaks figures) that is laid out and saved atomically when the block ends, and
  :func:`label_axes` for the labels, scales, title and legend;
* :func:`run_episode` — :func:`mrcomm_env.experiments.evaluation.run_episode`, the one episode loop,
  re-exported so that a reproduction imports everything it shares from here;
* :func:`atomic_open`, :func:`atomic_write_csv`, :func:`atomic_write_json`, :func:`atomic_write_text` — every
  CSV/JSON goes through these (:mod:`mrcomm_env.experiments.io`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from tqdm.auto import tqdm

from mrcomm_env.experiments.evaluation import run_episode
from mrcomm_env.experiments.io import (
    atomic_open,
    atomic_savefig,
    atomic_write_csv,
    atomic_write_json,
    atomic_write_text,
)
from mrcomm_env.experiments.sweep import Task, run_tasks

__all__ = [
    "SIZES",
    "atomic_open",
    "atomic_write_csv",
    "atomic_write_json",
    "atomic_write_text",
    "figure",
    "label_axes",
    "pick",
    "progress",
    "run_episode",
    "run_sweep",
    "run_sweeps",
    "size_of",
    "task",
]

SIZES = ("full", "quick", "tiny")
T = TypeVar("T")
_UNSET: Any = object()
#: the folder, inside a reproduction's output folder, where each task's result is cached as it finishes
TASKS_DIR = "tasks"


def size_of(quick: bool, tiny: bool = False) -> str:
    """The size of a run: ``"tiny"`` wins over ``"quick"``, which wins over ``"full"``."""
    return "tiny" if tiny else "quick" if quick else "full"


def pick(size: str, *, full: T, quick: T, tiny: T = _UNSET) -> T:
    """The value for this run's ``size``; ``tiny`` defaults to the ``quick`` value."""
    if size not in SIZES:
        raise ValueError(f"size must be one of {', '.join(SIZES)}, got {size!r}")
    if size == "full":
        return full
    if size == "tiny" and tiny is not _UNSET:
        return tiny
    return quick


def progress(iterable: Iterable[T], desc: str) -> Iterable[T]:
    """A progress bar over ``iterable`` that disappears when done (the CLI's output stays readable)."""

    return tqdm(iterable, desc=desc, leave=False)


def task(fn: Callable, name: str, **kwargs: Any) -> Task:
    """A sweep task that calls ``fn(**kwargs)`` on whichever worker the runner picks.

    ``fn`` must be a module-level function (a spawned worker imports it by name) and ``kwargs`` JSON data that
    decide its result completely, seeds included: a task never draws from a generator shared with other tasks.
    """
    qualname, module = getattr(fn, "__qualname__", ""), getattr(fn, "__module__", "")
    if qualname != getattr(fn, "__name__", None) or module in ("", "__main__"):
        raise ValueError(f"argument 'fn' must be a module-level function of an importable module, got {fn!r}")
    return Task(f"{module}:{fn.__name__}", kwargs, name)


def run_sweep(out: str | Path, tasks: Sequence[Task], desc: str) -> list[Any]:
    """The tasks' results in their order, run on the caller's runner (``sweep.using``), each cached in
    ``out/tasks`` as soon as it finishes so that a rerun into the same folder skips it."""
    return run_tasks(tasks, cache=Path(out) / TASKS_DIR, desc=desc)


def run_sweeps(out: str | Path, sweeps: dict[str, Sequence[Task]], desc: str) -> dict[str, list[Any]]:
    """Several independent sweeps as one (``{experiment: tasks}`` → ``{experiment: results}``).

    One sweep keeps both cores busy to the end, where each small sweep alone would leave one idle behind its
    longest task, and it starts the worker processes once: each must import the env stack (3–5 s on a loaded
    two-core machine), which costs more than many a quick sweep's whole work."""
    flat = [t for tasks in sweeps.values() for t in tasks]
    results = iter(run_sweep(out, flat, desc))
    return {name: [next(results) for _ in tasks] for name, tasks in sweeps.items()}


@contextlib.contextmanager
def figure(
    path: str | Path,
    *,
    figsize: tuple[float, float],
    nrows: int = 1,
    ncols: int = 1,
    dpi: float | None = None,
    tight: bool = True,
) -> Iterator[tuple[Any, Any]]:
    """``with figure(out / "fig.png", figsize=(6, 4)) as (fig, ax): ax.plot(…)`` — saved on leaving the block.

    ``ax`` is one Axes for a 1×1 grid, else the array ``fig.subplots`` returns. ``tight`` lays the figure out
    with ``tight_layout`` before saving; ``dpi`` is the saved resolution (default: the figure's, 100).
    Nothing is written when the block raises.
    """

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols)
    yield fig, axes
    if tight:
        fig.tight_layout()
    atomic_savefig(fig, path, **({} if dpi is None else {"dpi": dpi}))


def label_axes(
    ax,
    *,
    xlabel: str | None = None,
    ylabel: str | None = None,
    title: str | None = None,
    xscale: str | None = None,
    yscale: str | None = None,
    legend: float | None = None,
) -> None:
    """Set whichever of the labels, title and axis scales are given; ``legend`` is the legend's font size."""
    if xscale:
        ax.set_xscale(xscale)
    if yscale:
        ax.set_yscale(yscale)
    if xlabel is not None:
        ax.set_xlabel(xlabel)
    if ylabel is not None:
        ax.set_ylabel(ylabel)
    if title is not None:
        ax.set_title(title)
    if legend is not None:
        ax.legend(fontsize=legend)
