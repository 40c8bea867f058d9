"""Result files that are never half-written.

Every CSV, JSON and PNG that ``mrcomm reproduce``, ``mrcomm evaluate --json`` and ``mrcomm bench`` produce
goes through :func:`atomic_open`: the bytes go to a hidden temporary file in the destination's own
directory, which is flushed, synced and then renamed over the destination with :func:`os.replace`.
A rename within one file system is atomic on POSIX and Windows, so a reader (or a run interrupted by
Ctrl-C, a full disk or a kill) sees either the previous complete file or the new complete file, never a
truncated one. On any error the temporary file is removed.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import json
import math
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

#: temporary files are named ``.<destination name>.<random>`` + this suffix, so they are easy to spot and skip
TEMP_SUFFIX = ".partial"


@functools.cache
def _umask() -> int:
    # os.umask can only be read by setting it; read once per process and set straight back
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def json_safe(obj: Any) -> Any:
    """``obj`` with every non-finite float (NaN, ±inf; numpy's too, and inside numpy arrays) made None, so that it is
    written as strict JSON (null), which every JSON parser reads (``NaN`` is Python's extension, not JSON)."""
    if isinstance(obj, np.ndarray):
        obj = obj.tolist()
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", **open_kwargs: Any) -> Iterator[IO]:
    """Open a temporary file next to ``path`` for writing; on a clean exit it replaces ``path``.

    ``mode`` is ``"w"`` (text; ``open_kwargs`` such as ``newline`` or ``encoding`` are passed on) or
    ``"wb"``. The destination's directory must exist. An exception inside the block (``KeyboardInterrupt``
    included) leaves ``path`` as it was and removes the temporary file.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
    path = Path(path)
    fd, temp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=TEMP_SUFFIX)
    try:
        # mkstemp creates the file 0600; give the result the permissions a plain open() would have
        os.chmod(temp_name, 0o666 & ~_umask())
        if "b" not in mode:
            open_kwargs.setdefault("encoding", "utf-8")
        with os.fdopen(fd, mode, **open_kwargs) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temp_name, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.close(fd)  # only still open when fdopen itself failed
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temp_name)
        raise


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_open(path, "w") as handle:
        handle.write(text)


def atomic_write_json(path: str | os.PathLike, obj: Any, **dump_kwargs: Any) -> None:
    """``json.dump(obj, …, **dump_kwargs)`` into ``path`` as strict JSON: a non-finite float is written as null
    (:func:`json_safe`); the object is serialised before the file is touched."""
    atomic_write_text(path, json.dumps(json_safe(obj), allow_nan=False, **dump_kwargs))


def atomic_write_csv(path: str | os.PathLike, rows: list[dict[str, Any]]) -> None:
    """``rows`` (dicts with the keys of the first, in its order) as a CSV with a header, atomically."""
    with atomic_open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def atomic_savefig(fig, path: str | os.PathLike, **savefig_kwargs: Any) -> None:
    """``fig.savefig(path, …)`` through a temporary file; the format follows the file name's extension."""
    path = Path(path)
    savefig_kwargs.setdefault("format", path.suffix.lstrip(".") or None)
    with atomic_open(path, "wb") as handle:
        fig.savefig(handle, **savefig_kwargs)


def atomic_remove(path: str | os.PathLike) -> None:
    """Remove ``path`` if it exists (a single unlink: the file is there whole or not at all)."""
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)
