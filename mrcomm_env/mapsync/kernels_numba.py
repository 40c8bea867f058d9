"""Compiled twin (numba) of :func:`protocol.segment_inner_products`, Protocol 1's inner loop.

The numpy reference spends its time in a few dozen small array operations per call (one call per round of
Algorithm 1); this twin computes the same parities in one call: for every segment and index, the words of
``r_i`` restricted to the segment (from the materialised database, or Philox4x32-10 on demand exactly as
:func:`philox.stream_words`), ANDed with each robot's map, popcount, parity. ``tests/test_mapsync.py``
compares both kernel by kernel, bit for bit. Used when ``core.backend.compiled()`` (docs/architecture.md).
"""

from __future__ import annotations

import numba
import numpy as np

_M0 = np.uint64(0xD2511F53)
_M1 = np.uint64(0xCD9E8D57)
_W0 = np.uint64(0x9E3779B9)
_W1 = np.uint64(0xBB67AE85)
_LOW = np.uint64(0xFFFFFFFF)
_SHIFT = np.uint64(32)


@numba.njit(cache=True, inline="always")
def _popcount32(v):
    v = v - ((v >> np.uint64(1)) & np.uint64(0x55555555))
    v = (v & np.uint64(0x33333333)) + ((v >> np.uint64(2)) & np.uint64(0x33333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F)
    return ((v * np.uint64(0x01010101)) & _LOW) >> np.uint64(24)


@numba.njit(cache=True)
def _philox_lane(block, index, domain, k0, k1, lane):
    """Word ``lane`` of Philox4x32-10 at counter (block, index, domain, 0), key (k0, k1)."""
    c0, c1, c2, c3 = np.uint64(block), np.uint64(index), np.uint64(domain), np.uint64(0)
    a, b = np.uint64(k0), np.uint64(k1)
    for _ in range(10):
        p0 = _M0 * c0
        p1 = _M1 * c2
        c0, c1, c2, c3 = (p1 >> _SHIFT) ^ c1 ^ a, p1 & _LOW, (p0 >> _SHIFT) ^ c3 ^ b, p0 & _LOW
        a = (a + _W0) & _LOW
        b = (b + _W1) & _LOW
    if lane == 0:
        return c0
    if lane == 1:
        return c1
    if lane == 2:
        return c2
    return c3


@numba.njit(cache=True)
def inner_products(
    maps, database, use_database, k0, k1, domain, words_per_string, last_mask, index, lo, hi, from_bit, to_bit
):
    """Parities ``(M, S, k)``: ``maps[m][lo_s..hi_s] · r_{index[s, j]}[lo_s..hi_s] mod 2``."""
    n_maps = maps.shape[0]
    n_seg, k = index.shape
    out = np.zeros((n_maps, n_seg, k), dtype=np.uint8)
    acc = np.zeros(n_maps, dtype=np.uint64)
    for s in range(n_seg):
        first = lo[s] >> 5
        last = hi[s] >> 5
        for j in range(k):
            i = index[s, j]
            acc[:] = 0
            for w in range(first, last + 1):
                if use_database:
                    r = np.uint64(database[i, w])
                else:
                    r = _philox_lane(w >> 2, i, domain, k0, k1, w & 3)
                    if w == words_per_string - 1:
                        r &= np.uint64(last_mask)
                mask = _LOW
                if w == first:
                    mask &= np.uint64(from_bit[lo[s] & 31])
                if w == last:
                    mask &= np.uint64(to_bit[hi[s] & 31])
                r &= mask
                for m in range(n_maps):
                    acc[m] += _popcount32(np.uint64(maps[m, w]) & r)
            for m in range(n_maps):
                out[m, s, j] = np.uint8(acc[m] & np.uint64(1))
    return out
