"""Compiled (numba), and only so, the information maps' hot operations (``filters.py``): adding packet entries to a
map (``np.add.at`` of their ``count · R⁻¹``, ``dy`` and counts), the landmark means μ = Y⁻¹ y of every map, and the
bits over each edge of a fusion tree.

On the 2–10 packets and 10 × 200 maps of a decision phase, numpy's per-call overhead is most of their cost: a
vehicle's own packet, each fusion and the common map each take three ``np.add.at`` calls. The twins do the same
additions in the same order (``np.add.at`` adds its rows one after another, in index order; the 2 × 2 blocks
entry by entry) and the same closed-form inverse, operation for operation, so every map and mean is numpy's bit for
bit (``tests/rendezvous_mapping/test_rendezvous_compiled.py`` compares them with their numpy oracles in
``tests/helpers/rendezvous_reference.py``).
"""

from __future__ import annotations

import numba
import numpy as np

from mrcomm_env.core.backend import configure_numba_cache

configure_numba_cache()  # before the @njit(cache=True) below: never cache into the package


@numba.njit(cache=True)
def add_counted(Y, y, count, landmarks, dy, dcount, R_inv):
    """``np.add.at`` of ``dcount · R_inv``, ``dy`` and ``dcount`` at ``landmarks`` into ``Y`` (L, 2, 2), ``y`` (L, 2)
    and ``count`` (L,) (repeated landmarks add up in the order given): each product rounded once, then added, as
    numpy's ``dcount[:, None, None] * R_inv`` and ``np.add.at`` do. A landmark outside 0 … L − 1 raises
    ``IndexError`` before anything is added (numba does not check indices)."""
    for i in range(landmarks.size):
        if landmarks[i] < 0 or landmarks[i] >= Y.shape[0]:
            raise IndexError("a packet's landmark index is out of range")
    for i in range(landmarks.size):
        lm = landmarks[i]
        c = np.float64(dcount[i])
        Y[lm, 0, 0] += c * R_inv[0, 0]
        Y[lm, 0, 1] += c * R_inv[0, 1]
        Y[lm, 1, 0] += c * R_inv[1, 0]
        Y[lm, 1, 1] += c * R_inv[1, 1]
        y[lm, 0] += dy[i, 0]
        y[lm, 1] += dy[i, 1]
        count[lm] += dcount[i]


@numba.njit(cache=True)
def mean_of(Y, y):
    """``filters.mean_of`` of ``Y`` (..., 2, 2) and ``y`` (..., 2) given as (K, 2, 2) and (K, 2)."""
    out = np.empty(y.shape)
    for k in range(y.shape[0]):
        a, b, c, d = Y[k, 0, 0], Y[k, 0, 1], Y[k, 1, 0], Y[k, 1, 1]
        det = a * d - b * c
        out[k, 0] = (d * y[k, 0] - b * y[k, 1]) / det
        out[k, 1] = (a * y[k, 1] - c * y[k, 0]) / det
    return out


@numba.njit(cache=True)
def edge_bits(known, members, side_starts, side_members, cum_bits, origin):
    """``TeamMaps.fuse_group``'s bits over each tree edge (a, parent[a]) of a group: ``(S, 2)``, a → b then b → a,
    for the sides given as ``side_members[side_starts[s] : side_starts[s + 1]]`` (a's subtree). Each direction
    carries the packets the sender's side holds beyond the receiver's side (``missing_bits`` of the two sides' union
    version vectors, in ``tests/helpers/rendezvous_reference.py``), summed from the cumulative bits of u's first k
    packets, ``cum_bits[origin[u] + k]`` (every vehicle's kept log, one after another: ``TeamMaps._edge_bits``):
    whole numbers, so the sums are the reference's."""
    n = known.shape[0]
    S = side_starts.size - 1
    out = np.zeros((S, 2), dtype=np.int64)
    in_side = np.zeros(n, dtype=np.bool_)
    for s in range(S):
        in_side[:] = False
        for i in range(side_starts[s], side_starts[s + 1]):
            in_side[side_members[i]] = True
        for u in range(n):
            union_a = -1
            union_b = -1
            for m in members:
                if in_side[m]:
                    union_a = max(union_a, known[m, u])
                else:
                    union_b = max(union_b, known[m, u])
            if union_a > union_b:
                out[s, 0] += cum_bits[origin[u] + union_a] - cum_bits[origin[u] + union_b]
            elif union_b > union_a:
                out[s, 1] += cum_bits[origin[u] + union_b] - cum_bits[origin[u] + union_a]
    return out
