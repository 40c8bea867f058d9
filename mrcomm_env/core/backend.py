"""Which implementation of an env's hot loops runs: compiled (numba) or numpy.

Some envs keep a numba twin of their innermost kernels (AsyncCL's EKF column steps and table
exchange). The numpy code is the reference; the twin computes the same thing with far fewer
interpreter round trips, and tests check that both agree. numba is optional
(``pip install mrcomm-env[fast]``): without it everything runs on numpy.

``MRCOMM_BACKEND=numpy`` forces the reference even when numba is installed, ``MRCOMM_BACKEND=numba``
requires numba. The choice is made once per process.
"""

from __future__ import annotations

import os
from functools import cache

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
    return True


def name() -> str:
    return "numba" if compiled() else "numpy"
