"""``world.spanning_forest`` compiled (numba): the connected groups of vehicles and the shortest-path trees they
fuse over (§III).

``world.dijkstra_forest`` builds a sparse matrix and calls scipy's multi-source Dijkstra (``min_only``, one root per group:
its lowest-index vehicle). On the 5–30 vehicles of a team, scipy's set-up (validation, the CSR matrix and its
transpose) costs several times the search itself, and the decision phase calls it every time. This kernel runs
the same search on the dense distance matrix.

**Why its trees are scipy's.** scipy relaxes a neighbour only on a strictly shorter path (``val > next_val``) and
never touches a scanned node. Every tentative distance here is computed as scipy computes it (the scanned node's
distance plus the link length, from the same link lengths, bit for bit), so the search can differ from scipy only
in the order it takes nodes of equal distance off the heap, and that order can matter only when

1. a relaxation offers a node in the heap exactly its present distance (two shortest paths of equal length: the
   first one found wins, and which is first depends on the heap), or
2. a link length is absorbed by the distance it is added to (d + w = d in floating point), so that a node and
   its successor have equal distances.

Without either, each node's distance exceeds its predecessor's and its predecessor is the unique first-found
minimum, whatever the order among equal distances. The kernel reports either case as *ambiguous* and the caller
then runs scipy's (exact grids and co-located groups meet case 1 often:
``tests/rendezvous_mapping/test_rendezvous_compiled.py``
checks that both branches agree with scipy and that both are taken).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mrcomm_env.core.backend import configure_numba_cache
from mrcomm_env.rendezvous.plan_numba import _components

configure_numba_cache()  # before the @njit(cache=True) below: never cache into the package

_NOT_IN_HEAP, _IN_HEAP, _SCANNED = 0, 1, 2


@numba.njit(cache=True)
def spanning_forest(pos, links, floor):
    """``(labels, parent, ambiguous)`` for vehicles at ``pos`` (N, 2) with bool ``links`` (N, N, symmetric, no
    self loops) and link length = distance + ``floor``: ``world.spanning_forest``'s labels and parents, valid
    when ``ambiguous`` is False (see the module docstring)."""
    n = len(pos)
    adj = links.copy()
    for i in range(n):
        adj[i, i] = True
    k, small_labels = _components(adj)
    labels = small_labels.astype(np.int64)
    parent = np.full(n, -1, dtype=np.int64)
    if k == n:  # nobody linked: no trees to build
        return labels, parent, False
    # link lengths as the reference computes them: sqrt(dx² + dy²) + floor, the sum over (x, y) in that order
    length = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            dx = pos[i, 0] - pos[j, 0]
            dy = pos[i, 1] - pos[j, 1]
            length[i, j] = math.sqrt(dx * dx + dy * dy) + floor
    value = np.full(n, np.inf)
    state = np.zeros(n, dtype=np.int8)
    # every group's root (its lowest member) starts scanned at distance 0, as scipy's multi-source set-up has it
    seen = np.zeros(k, dtype=np.bool_)
    for i in range(n):
        if not seen[labels[i]]:
            seen[labels[i]] = True
            value[i] = 0.0
            state[i] = _SCANNED
            if _relax(i, value, state, parent, links, length):
                return labels, parent, True
    while True:
        v = -1
        for i in range(n):
            if state[i] == _IN_HEAP and (v < 0 or value[i] < value[v]):
                v = i
        if v < 0:
            return labels, parent, False
        state[v] = _SCANNED
        if _relax(v, value, state, parent, links, length):
            return labels, parent, True


@numba.njit(cache=True)
def _relax(v, value, state, parent, links, length):
    """Relax v's links as scipy does (strictly shorter only); True when the result could depend on heap order."""
    for j in range(len(value)):
        if not links[v, j] or state[j] == _SCANNED:
            continue
        offer = value[v] + length[v, j]
        if offer <= value[v]:  # the link length was absorbed: equal distances along a link (case 2)
            return True
        if state[j] == _NOT_IN_HEAP:
            state[j] = _IN_HEAP
            value[j] = offer
            parent[j] = v
        elif value[j] > offer:
            value[j] = offer
            parent[j] = v
        elif value[j] == offer:  # a second shortest path: scipy keeps whichever its heap found first (case 1)
            return True
    return False
