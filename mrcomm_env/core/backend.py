"""Which implementation of an env's hot loops runs: compiled (numba, the default) or numpy.

numba is a required dependency. Every env's hot loops are compiled kernels. MultiHop's frame (its copy-axis world),
AsyncCL's EKF, table exchange, observation and team errors, MapSync's walk, sensing, changing world, disagreement,
observation, Protocol 1 and sketch, and RendezvousMapping's window, packets, observation, candidate lists, map
fusion, plan and spanning forest exist only compiled; the numpy code they are checked against lives under
``tests/helpers`` (the forest's ties are settled by scipy's Dijkstra, ``world.dijkstra_forest``). MapSync's
Algorithm 1 still keeps its numpy rounds in the package (they also run step 4 as printed, and a run whose picks
from a generator other than PCG64 would not fit in memory drawn ahead): ``MRCOMM_BACKEND=numpy`` runs those, and
steps MapSync's copies in turn rather than as its copy-axis world (the tests compare both); ``auto`` or ``numba``
the kernels. The choice is made once per process.

Compiled kernels are cached on disk (``cache=True``) so that only the first process compiles them. numba's
own default writes the cache beside the source, into the installed package: that fails on a read-only
install and dirties a source tree. Unless ``NUMBA_CACHE_DIR`` is set, the cache goes to the user's cache
folder instead: ``$XDG_CACHE_HOME/mrcomm-env/numba`` (``~/.cache/mrcomm-env/numba``).
"""

from __future__ import annotations

import os
from functools import cache
from pathlib import Path

import numba
import numpy as np

VARIABLE = "MRCOMM_BACKEND"
CHOICES = ("auto", "numba", "numpy")


@cache
def compiled() -> bool:
    """True unless ``MRCOMM_BACKEND=numpy`` asks for the numpy references (of the envs that still keep them)."""
    choice = os.environ.get(VARIABLE, "auto") or "auto"
    if choice not in CHOICES:
        raise ValueError(f"environment variable {VARIABLE} must be one of {CHOICES}, got {choice!r}")
    configure_numba_cache()
    return choice != "numpy"


def configure_numba_cache() -> None:
    """Point numba's on-disk cache at ``NUMBA_CACHE_DIR`` or the user cache folder; call before ``@njit``."""
    numba.config.CACHE_DIR = os.environ.get("NUMBA_CACHE_DIR") or str(user_cache_dir())


def user_cache_dir() -> Path:
    """Where compiled kernels are cached when ``NUMBA_CACHE_DIR`` is not set (never inside the package)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "mrcomm-env" / "numba"


def name() -> str:
    return "numba" if compiled() else "numpy"


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
