"""Which implementation of an env's hot loops runs: compiled (numba) or numpy.

Some envs keep a numba twin of their innermost kernels (AsyncCL's EKF column steps and table
exchange). The numpy code is the reference; the twin computes the same thing with far fewer
interpreter round trips, and tests check that both agree. numba is optional
(``pip install mrcomm-env[fast]``): without it everything runs on numpy.

``MRCOMM_BACKEND=numpy`` forces the reference even when numba is installed, ``MRCOMM_BACKEND=numba``
requires numba. The choice is made once per process.

Compiled kernels are cached on disk (``cache=True``) so that only the first process compiles them. numba's
own default writes the cache beside the source, into the installed package: that fails on a read-only
install and dirties a source tree. Unless ``NUMBA_CACHE_DIR`` is set, the cache goes to the user's cache
folder instead: ``$XDG_CACHE_HOME/mrcomm-env/numba`` (``~/.cache/mrcomm-env/numba``).
"""

from __future__ import annotations

import os
from functools import cache
from pathlib import Path

import numpy as np

VARIABLE = "MRCOMM_BACKEND"
CHOICES = ("auto", "numba", "numpy")


@cache
def compiled() -> bool:
    """True when the numba twins run (numba importable and ``MRCOMM_BACKEND`` is not ``numpy``)."""
    choice = os.environ.get(VARIABLE, "auto") or "auto"
    if choice not in CHOICES:
        raise ValueError(f"environment variable {VARIABLE} must be one of {CHOICES}, got {choice!r}")
    if choice == "numpy":
        return False
    try:
        import numba  # noqa: F401
    except ImportError:
        if choice == "numba":
            raise ValueError(f"{VARIABLE}=numba needs numba: pip install mrcomm-env[fast]") from None
        return False
    configure_numba_cache()
    return True


def configure_numba_cache() -> None:
    """Point numba's on-disk cache at ``NUMBA_CACHE_DIR`` or the user cache folder; call before ``@njit``."""
    import numba

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
