"""Compiled twin (numba) of one pass of the recommendation phase's partition loop (§IV-C/D, ``protocol.recommend``).

A pass assigns vehicles to landmarks (Munkres), clusters the assigned landmarks, picks the main cluster μ_max
(eq. 6) and its central landmark l_c, and, while the assignment is not connected, the outlier l_o (eq. 7) whose
half-plane cut (eq. 8) shrinks the working set. The numpy reference spends ~90 µs of interpreter round trips
per pass on 2–10 landmarks, and a 10-vehicle team at d_comms = 10 m makes about a dozen passes per decision
phase. This twin does the clustering, eq. (6), the centrality ties and eq. (7) in one call. Munkres (scipy),
the column pre-selection that feeds it (numpy's ``argpartition`` picks among ties its own way), the
eigenvector of a cluster that is not complete (numba's ``eigh`` is scipy's LAPACK, not numpy's) and the eq. (8)
product (numpy's ``@`` is a BLAS call whose rounding differs from two products and a sum) stay with the
reference code, so that every number is the reference's (``tests/test_rendezvous_mapping.py`` compares whole
seeded episodes and single passes on both backends).

Used when ``core.backend.compiled()`` (docs/architecture.md).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def cluster_pass(U, landmark_pos, rows, lp, d_comms):
    """Clusters and l_c of one assignment: ``(k, labels, main, members, central, adj)``.

    ``rows``/``lp`` are the matched vehicle rows and landmark ids. ``labels`` numbers the connected components of
    the assigned landmarks' adjacency (separation < d_comms, with the diagonal; ``protocol.adjacency``) in order
    of their lowest member, as ``protocol.clusters``; ``main`` is the cluster of largest eq. (6) value J (first on
    ties, ``np.argmax``), ``members`` its positions in ``lp``, in order. ``central`` is l_c's index in ``members``
    when the Perron vector ties every member (a single landmark, or a complete cluster: the reference's
    eigenvector is then uniform to round-off, ≪ its 1e-9 tie tolerance), chosen as ``protocol.central_landmark``
    breaks ties: nearest the centroid, then lowest index. Otherwise ``central`` is −1 and the caller takes the
    eigenvector.
    """
    adj = _adjacency(landmark_pos, lp, d_comms)
    k, labels = _components(adj)
    main = _main_cluster(U, rows, lp, labels, k)
    members = np.flatnonzero(labels == main)
    return k, labels, main, members, _tied_central(adj, landmark_pos, lp, members), adj


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
def _tied_central(adj, landmark_pos, lp, members):
    """l_c's index in ``members`` when every member ties (see :func:`cluster_pass`), else −1."""
    size = len(members)
    if size == 1:
        return 0
    for a in range(size):
        for b in range(size):
            if not adj[members[a], members[b]]:
                return -1
    # complete: the nearest to the centroid wins, the first on ties (the mean sums rows in order, as
    # ndarray.mean(0) does for these sizes)
    cx = landmark_pos[lp[members[0]], 0]
    cy = landmark_pos[lp[members[0]], 1]
    for a in range(1, size):
        cx += landmark_pos[lp[members[a]], 0]
        cy += landmark_pos[lp[members[a]], 1]
    cx /= size
    cy /= size
    best = 0
    best_d = np.inf
    for a in range(size):
        dx = landmark_pos[lp[members[a]], 0] - cx
        dy = landmark_pos[lp[members[a]], 1] - cy
        d = dx * dx + dy * dy
        if d < best_d:
            best, best_d = a, d
    return best


@numba.njit(cache=True)
def outlier(landmark_pos, lp, labels, main, lc):
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
