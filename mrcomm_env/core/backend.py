"""The compiled kernels' common ground (numba, a required dependency): where they are cached, and the arrays they take.

Every env's hot loops exist once, compiled: MultiHop's frame (its copy-axis world), AsyncCL's EKF, table exchange,
observation and team errors, MapSync's walk, sensing, changing world, disagreement, observation, Protocol 1,
Algorithm 1 and sketch, and RendezvousMapping's window, packets, observation, candidate lists, map fusion, plan and
spanning forest. The numpy code they are checked against lives under ``tests/helpers`` (the forest's ties are
settled by scipy's Dijkstra, ``world.dijkstra_forest``).

Compiled kernels are cached on disk (``cache=True``) so that only the first process compiles them. numba's
own default writes the cache beside the source, into the installed package: that fails on a read-only
install and dirties a source tree. Unless ``NUMBA_CACHE_DIR`` is set, the cache goes to the user's cache
folder instead: ``$XDG_CACHE_HOME/mrcomm-env/numba`` (``~/.cache/mrcomm-env/numba``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numba
import numpy as np


def configure_numba_cache() -> None:
    """Point numba's on-disk cache at ``NUMBA_CACHE_DIR`` or the user cache folder; call before ``@njit``."""
    numba.config.CACHE_DIR = os.environ.get("NUMBA_CACHE_DIR") or str(user_cache_dir())


def user_cache_dir() -> Path:
    """Where compiled kernels are cached when ``NUMBA_CACHE_DIR`` is not set (never inside the package)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "mrcomm-env" / "numba"


def kernel_array(array, dtype=None) -> np.ndarray:
    """``array`` as a writable C-contiguous array (of ``dtype`` when given), a copy only when it is not one.

    What a compiled kernel should be handed: numba compiles one signature per dtype, memory layout and
    writability it meets, each compiled (or loaded) when first met, while fancy indexing may give Fortran order
    and ``np.broadcast_to`` read-only views. The values are the same, so the results are too."""
    if not isinstance(array, np.ndarray):
        array = np.asarray(array)
    if (dtype is None or array.dtype == dtype) and array.flags.c_contiguous and array.flags.writeable:
        return array
    return np.array(array, dtype=dtype, order="C")
