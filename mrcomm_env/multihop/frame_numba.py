"""Compiled twin (numba) of MultiHop's TDMA frame on a static topology: the slot loop of ``MultiHopEnv._step_world``.

The numpy reference runs the frame slot by slot in Python, a handful of numpy calls per slot
(``protocol.deliver_one``): about 4 ms of the 5 ms a 100-robot frame takes. This twin runs the whole frame in
one call, with the same rules in the same order (§2.1: every sender stamps its own estimate with the current
time; it sends its own estimate and the first ``m − 1`` further candidates of its ranked list that it holds;
each neighbour keeps the newer time stamp per robot; a first arrival is dated at the end of the slot). Every
number it writes is the reference's, bit for bit: the clock is advanced by the same float additions, and
the rest are copies and comparisons (``tests/test_multihop.py`` compares whole seeded episodes on both
backends). Only static topologies: while robots move, each slot's links and the robots' motion come
first, and the reference runs.

Arrays carry a leading copy axis M so that a batch of copies can be run in one call; the env passes its own
state as M = 1 views. Used when ``core.backend.compiled()`` (docs/architecture.md).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def send_frame(
    stamps, order, rank, count, m, t, slot_dur, nbr_ptr, nbr_idx, first_known, track_first, last_sent, sent_stamp, sent
):
    """One frame of every copy, in place.

    ``stamps`` (M, n, n) time stamps (−inf: unknown); ``order`` (M, n) the senders in slot order; ``rank``
    (M, n, n) each robot's candidates, own index first, of which ``count`` (M, n) are selected; ``m`` estimates
    per slot; ``t`` (M,) the clock at the frame's start, advanced to its end; ``nbr_ptr`` (M, n + 1) and
    ``nbr_idx`` (M, E) each robot's neighbours (CSR rows); ``first_known`` (M, n, n) first arrival times,
    written where ``track_first[c]``; ``last_sent`` (M, n, n) set to what each robot sent this frame;
    ``sent_stamp`` (M, n, n) the stamp each robot last sent of each other; ``sent`` (M, n) estimates sent.
    """
    n_copies, n = order.shape
    for c in range(n_copies):
        now = t[c]
        track = track_first[c]
        picked = np.empty(m, dtype=np.int64)
        for i in range(n):
            for j in range(n):
                last_sent[c, i, j] = False
        for k in range(n):
            s = order[c, k]
            stamps[c, s, s] = now  # own state is always current
            held = 0
            for q in range(count[c, s]):
                if held == m:
                    break
                j = rank[c, s, q]
                if stamps[c, s, j] > -np.inf:
                    picked[held] = j
                    held += 1
            sent[c, s] = held
            for q in range(held):
                j = picked[q]
                last_sent[c, s, j] = True
                sent_stamp[c, s, j] = stamps[c, s, j]
            now += slot_dur
            for e in range(nbr_ptr[c, s], nbr_ptr[c, s + 1]):
                r = nbr_idx[c, e]
                for q in range(held):
                    j = picked[q]
                    new = stamps[c, s, j]
                    old = stamps[c, r, j]
                    if new > old:
                        stamps[c, r, j] = new
                        if track and old == -np.inf:
                            first_known[c, r, j] = now
        t[c] = now


def neighbour_lists(adjacency: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An (n, n) boolean adjacency as CSR rows for :func:`send_frame` (one copy: shapes (1, n + 1), (1, E))."""
    rows, cols = np.nonzero(adjacency)
    ptr = np.zeros(adjacency.shape[0] + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=adjacency.shape[0]), out=ptr[1:])
    return ptr[None, :], cols.astype(np.int64)[None, :]
