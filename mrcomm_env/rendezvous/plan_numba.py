"""Compiled twin (numba) of one pass of the recommendation phase's partition loop (§IV-C/D, ``protocol.recommend``).

A pass assigns vehicles to landmarks (Munkres), clusters the assigned landmarks, picks the main cluster μ_max
(eq. 6) and its central landmark l_c (eigenvector centrality [16]), and, while the assignment is not connected,
the outlier l_o (eq. 7) whose half-plane cut (eq. 8) shrinks the working set. The numpy reference spends
~90 µs of interpreter round trips per pass on 2–10 landmarks, and a 10-vehicle team at d_comms = 10 m makes
about a dozen passes per decision phase. This twin does the clustering, eq. (6), l_c, eq. (7) and eq. (8)'s
offsets in one call.

Munkres (scipy), the column pre-selection that feeds it (numpy's ``argpartition`` picks among ties its own way)
and the eq. (8) product (numpy's ``@`` is a BLAS call whose rounding differs from two products and a sum) stay
with the reference code. l_c's eigenvector is numba's ``eigh`` (LAPACK's ``syevd`` through scipy, numpy's
``eigh`` runs the same routine through its own build): it gave the reference's eigenvector bit for bit on
20,000 random and grid clusters here, and l_c depends on it only through a 1e-9 relative tie tolerance, so
two builds could disagree only on entries within round-off of that tolerance. ``tests/test_rendezvous_mapping.py``
compares single passes and whole seeded episodes on both backends.

Used when ``core.backend.compiled()`` (docs/architecture.md).
"""

from __future__ import annotations

import numba
import numpy as np

from mrcomm_env.core.backend import configure_numba_cache

configure_numba_cache()  # before the @njit(cache=True) below: never cache into the package


@numba.njit(cache=True)
def partition_pass(U, landmark_pos, rows, lp, d_comms, working):
    """One pass after Munkres: ``(k, labels, main, lc, lo, axis, offsets)``.

    ``rows``/``lp`` are the matched vehicle rows and landmark ids, ``working`` the pass's working landmarks.
    ``labels`` numbers the connected components of the assigned landmarks' adjacency (separation < d_comms, with
    the diagonal; ``protocol.adjacency``) in order of their lowest member, as ``protocol.clusters``; ``main`` is
    the cluster of largest eq. (6) value J (first on ties, ``np.argmax``); ``lc`` is its central landmark
    (``protocol.central_landmark``). When the assignment is not connected (k > 1), ``lo`` is the outlier of eq. (7)
    and ``axis`` = x_lo − x_lc and ``offsets`` = x_lo − x_l for every working l are the two factors of eq. (8),
    whose product the caller takes with numpy's ``@`` as the reference does; otherwise ``lo`` is −1.
    """
    adj = _adjacency(landmark_pos, lp, d_comms)
    k, labels = _components(adj)
    main = _main_cluster(U, rows, lp, labels, k)
    members = np.flatnonzero(labels == main)
    lc = lp[members[_central(adj, landmark_pos, lp, members)]]
    axis = np.empty(2)
    if k == 1:  # connected: no cut
        return k, labels, main, lc, -1, axis, np.empty((0, 2))
    offsets = np.empty((len(working), 2))
    lo = _outlier(landmark_pos, lp, labels, main, lc)
    axis[0] = landmark_pos[lo, 0] - landmark_pos[lc, 0]
    axis[1] = landmark_pos[lo, 1] - landmark_pos[lc, 1]
    for w in range(len(working)):
        offsets[w, 0] = landmark_pos[lo, 0] - landmark_pos[working[w], 0]
        offsets[w, 1] = landmark_pos[lo, 1] - landmark_pos[working[w], 1]
    return k, labels, main, lc, lo, axis, offsets


@numba.njit(cache=True)
def _adjacency(landmark_pos, lp, d_comms):
    """``protocol.adjacency`` of the assigned landmarks: squared separation below d_comms², with the diagonal."""
    m = len(lp)
    adj = np.ones((m, m), dtype=np.bool_)
    if np.isinf(d_comms):
        return adj
    limit = d_comms * d_comms
    for i in range(m):
        for j in range(m):
            if i != j:
                dx = landmark_pos[lp[i], 0] - landmark_pos[lp[j], 0]
                dy = landmark_pos[lp[i], 1] - landmark_pos[lp[j], 1]
                adj[i, j] = dx * dx + dy * dy < limit
    return adj


@numba.njit(cache=True)
def _components(adj):
    """Connected components numbered in order of their lowest member (``protocol.clusters``): (k, labels)."""
    m = len(adj)
    labels = np.full(m, -1, dtype=np.int32)
    stack = np.empty(m, dtype=np.int64)
    k = 0
    for start in range(m):
        if labels[start] >= 0:
            continue
        labels[start] = k
        stack[0] = start
        top = 1
        while top > 0:
            top -= 1
            i = stack[top]
            for j in range(m):
                if adj[i, j] and labels[j] < 0:
                    labels[j] = k
                    stack[top] = j
                    top += 1
        k += 1
    return k, labels


@numba.njit(cache=True)
def _main_cluster(U, rows, lp, labels, k):
    """μ_max: the cluster of largest eq. (6) value J, summed in index order as np.bincount sums its weights,
    the first on ties as np.argmax."""
    if k == 1:
        return 0
    J = np.zeros(k)
    for i in range(len(lp)):
        J[labels[i]] += U[rows[i], lp[i]]
    main = 0
    for c in range(1, k):
        if J[c] > J[main]:
            main = c
    return main


@numba.njit(cache=True)
def _central(adj, landmark_pos, lp, members):
    """``protocol.central_landmark`` of the main cluster: l_c's index in ``members``.

    The largest entries of the Perron eigenvector of the cluster's adjacency (zero diagonal) within the
    reference's relative tolerance 1e-9 tie; ties go to the member nearest the centroid of the whole cluster (the
    mean sums rows in order, as ndarray.mean(0) does for these sizes), then to the lowest index. A single
    landmark, or a complete cluster (whose Perron vector is uniform to round-off, ≪ the tolerance), ties every
    member without an eigenvector."""
    size = len(members)
    if size == 1:
        return 0
    complete = True
    for a in range(size):
        for b in range(size):
            if not adj[members[a], members[b]]:
                complete = False
    tied = np.ones(size, dtype=np.bool_)
    if not complete:
        sub = np.zeros((size, size))
        for a in range(size):
            for b in range(size):
                if a != b and adj[members[a], members[b]]:
                    sub[a, b] = 1.0
        _, vecs = np.linalg.eigh(sub)
        lead = np.abs(vecs[:, size - 1])
        floor = lead.max() * (1.0 - 1e-9)
        first, count = -1, 0
        for a in range(size):
            tied[a] = lead[a] >= floor
            if tied[a]:
                count += 1
                if first < 0:
                    first = a
        if count == 1:
            return first
    cx = landmark_pos[lp[members[0]], 0]
    cy = landmark_pos[lp[members[0]], 1]
    for a in range(1, size):
        cx += landmark_pos[lp[members[a]], 0]
        cy += landmark_pos[lp[members[a]], 1]
    cx /= size
    cy /= size
    best = -1
    best_d = np.inf
    for a in range(size):
        if tied[a]:
            dx = landmark_pos[lp[members[a]], 0] - cx
            dy = landmark_pos[lp[members[a]], 1] - cy
            d = dx * dx + dy * dy
            if best < 0 or d < best_d:
                best, best_d = a, d
    return best


@numba.njit(cache=True)
def _outlier(landmark_pos, lp, labels, main, lc):
    """Eq. (7): the assigned landmark outside μ_max farthest from l_c (first on ties, as ``np.argmax``)."""
    lo = -1
    best = 0.0
    for i in range(len(lp)):
        if labels[i] != main:
            dx = landmark_pos[lp[i], 0] - landmark_pos[lc, 0]
            dy = landmark_pos[lp[i], 1] - landmark_pos[lc, 1]
            d = dx * dx + dy * dy
            if lo < 0 or d > best:
                lo, best = lp[i], d
    return lo
