"""numpy's pairwise summation of float64, compiled (numba): kernels whose sums must be the numpy reference's,
bit for bit, sum with :func:`numpy_sum`."""

from __future__ import annotations

import numba
import numpy as np

from mrcomm_env.core.backend import configure_numba_cache

configure_numba_cache()  # before the @njit(cache=True) below: never cache into the package


@numba.njit(cache=True)
def _block_sum(values, start, size):
    """numpy's pairwise sum of a run of at most 128 values (one leaf of :func:`numpy_sum`)."""
    if size < 8:
        total = 0.0
        for i in range(size):
            total += values[start + i]
        return total
    r0, r1, r2, r3 = values[start], values[start + 1], values[start + 2], values[start + 3]
    r4, r5, r6, r7 = values[start + 4], values[start + 5], values[start + 6], values[start + 7]
    i = 8
    whole = size - size % 8
    while i < whole:
        at = start + i
        r0 += values[at]
        r1 += values[at + 1]
        r2 += values[at + 2]
        r3 += values[at + 3]
        r4 += values[at + 4]
        r5 += values[at + 5]
        r6 += values[at + 6]
        r7 += values[at + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < size:
        total += values[start + i]
        i += 1
    return total


@numba.njit(cache=True)
def numpy_sum(values, start, size):
    """``values[start:start + size].sum()`` as numpy sums a contiguous float64 run, bit for bit: numpy's pairwise
    summation (``pairwise_sum`` in numpy's ``loops_utils.h.src``: runs under 8 added in turn, up to 128 in eight
    interleaved partial sums, longer ones split in two at a multiple of 8 and the halves' sums added). A kernel
    that must give numpy's sums sums its own scratch rows with it: MultiHop's copy-axis world a copy's ages,
    instead of writing (M, n, n) arrays for numpy to sum; MapSync the disagreement of its maps.
    ``tests/multihop/test_multihop_world.py`` compares it with ``ndarray.sum`` up to a million values.

    The halving is walked with an explicit stack: numba's on-disk cache of a self-recursive function crashed the
    process that loaded it (a segmentation fault on the second run)."""
    if size <= 128:
        return _block_sum(values, start, size)
    depth = 64  # a run of 2**63 values halves fewer than 64 times
    starts = np.empty(depth, dtype=np.int64)
    sizes = np.empty(depth, dtype=np.int64)
    left_sums = np.empty(depth)
    stage = np.zeros(depth, dtype=np.int8)  # 0: not split yet, 1: left half running, 2: right half running
    top = 0
    starts[0], sizes[0], stage[0] = start, size, 0
    while True:
        if sizes[top] > 128:
            half = sizes[top] // 2
            half -= half % 8
            stage[top] = 1
            top += 1
            starts[top], sizes[top], stage[top] = starts[top - 1], half, 0
            continue
        total = _block_sum(values, starts[top], sizes[top])
        while True:  # hand the finished run's sum to the runs it is half of
            if top == 0:
                return total
            top -= 1
            if stage[top] == 1:  # the left half is done: keep its sum, run the right half
                left_sums[top] = total
                stage[top] = 2
                half = sizes[top] // 2
                half -= half % 8
                top += 1
                starts[top], sizes[top], stage[top] = starts[top - 1] + half, sizes[top - 1] - half, 0
                break
            total = left_sums[top] + total  # both halves are done: left + right, as numpy adds them
