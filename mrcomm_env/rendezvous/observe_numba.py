"""RendezvousMapping's observation, compiled (numba): every vehicle's observation in one call
(``RendezvousMappingEnv._observe``, its only implementation in the package).

The reference (the numpy oracle, ``tests/helpers/rendezvous_reference.py``) assembles the observation from some
forty numpy operations on arrays of 10 × 4 entries, and their interpreter round trips cost more than the arithmetic
(about 150 µs a step for 10 vehicles, an eighth of the step). This twin computes every entry with the reference's
formulas in float64, in the same operations and order (``hypot`` is the C library's in both; nothing is contracted
into fused multiply-adds), and rounds once to float32 at the end, as the reference's ``astype`` does. The K nearest
other vehicles are taken in the reference's stable order: distance, then vehicle id.
``tests/rendezvous_mapping/test_rendezvous_compiled.py`` compares whole seeded episodes with the oracle's,
observations byte for byte.
"""

from __future__ import annotations

import numba
import numpy as np

from mrcomm_env.core.backend import configure_numba_cache

configure_numba_cache()  # before the @njit(cache=True) below: never cache into the package


@numba.njit(cache=True, inline="always")
def _rel(d, side):
    """A relative offset mapped to [0, 1], 0.5 = here (the reference's ``rel``)."""
    return min(max(d / (2.0 * side) + 0.5, 0.0), 1.0)


@numba.njit(cache=True, inline="always")
def _travel(dist, speed, window):
    """Travel time over travel time plus the window (the reference's ``travel``)."""
    t = dist / speed
    return t / (t + window)


@numba.njit(cache=True)
def _stable_order(values, count):
    """The indices of the ``count`` smallest ``values`` in ascending order, ties by index (the first ``count`` of
    ``np.argsort(values, kind="stable")``), by insertion: the vehicles of a team are few."""
    order = np.empty(count, dtype=np.int64)
    size = 0
    for i in range(values.size):
        if size == count and not values[i] < values[order[size - 1]]:
            continue  # not below the last kept one: a tie goes to the lower index, already kept
        j = size if size < count else count - 1
        while j > 0 and values[i] < values[order[j - 1]]:
            order[j] = order[j - 1]
            j -= 1
        order[j] = i
        if size < count:
            size += 1
    return order


@numba.njit(cache=True)
def observe(
    pos,
    side,
    clock,
    group,
    one_group,
    own_fraction,
    candidates,
    candidate_utility,
    u_max,
    estimates,
    in_main,
    assignment,
    rendezvous_point,
    plan_connected,
    known_pos,
    known_phase,
    phases,
    speed,
    window,
    d_max,
):
    """``(n, 11 + 12 K)`` float32: head (6), K candidates (7 each), rendezvous (5), K nearest vehicles (5 each)."""
    n, K = candidates.shape
    width = 11 + 12 * K
    out = np.zeros((n, width), dtype=np.float64)
    for v in range(n):
        row = out[v]
        x, y = pos[v, 0], pos[v, 1]
        # head: position, clock, group share, one group, own information fraction
        row[0] = min(max(x / side, 0.0), 1.0)
        row[1] = min(max(y / side, 0.0), 1.0)
        row[2] = clock
        members = 0
        for w in range(n):
            members += group[v, w]
        row[3] = members / n
        row[4] = 1.0 if one_group else 0.0
        row[5] = min(max(own_fraction[v], 0.0), 1.0)
        # candidates (empty slots stay 0)
        for k in range(K):
            lm = candidates[v, k]
            if lm < 0:
                continue
            base = 6 + 7 * k
            dx = estimates[v, lm, 0] - x
            dy = estimates[v, lm, 1] - y
            recommended = lm == assignment[v]
            row[base] = _rel(dx, side)
            row[base + 1] = _rel(dy, side)
            row[base + 2] = min(max(candidate_utility[v, k] / u_max, 0.0), 1.0)
            row[base + 3] = _travel(np.hypot(dx, dy), speed, window)
            row[base + 4] = 1.0 if in_main[v] and recommended else 0.0
            row[base + 5] = 1.0 if recommended else 0.0
            row[base + 6] = 1.0
        # the rendezvous point, and whether the recommended landmark fits on the way
        base = 6 + 7 * K
        lp = max(assignment[v], 0)
        lpx, lpy = estimates[v, lp, 0], estimates[v, lp, 1]
        lcx, lcy = rendezvous_point[v, 0], rendezvous_point[v, 1]
        d1 = np.hypot(lpx - x, lpy - y)
        d2 = np.hypot(lcx - lpx, lcy - lpy)
        row[base] = _rel(lcx - x, side)
        row[base + 1] = _rel(lcy - y, side)
        row[base + 2] = _travel(np.hypot(lcx - x, lcy - y), speed, window)
        row[base + 3] = 1.0 if assignment[v] >= 0 and d1 + d2 < d_max else 0.0
        row[base + 4] = 1.0 if plan_connected[v] else 0.0
        # the K nearest other vehicles at their last known positions, nearest first (ties: lower id)
        if n > 1:
            dist = np.empty(n)
            for w in range(n):
                dist[w] = np.hypot(known_pos[v, w, 0] - x, known_pos[v, w, 1] - y)
            dist[v] = np.inf
            nearest = _stable_order(dist, min(K, n - 1))
            base += 5
            for k in range(nearest.size):
                w = nearest[k]
                age = phases - known_phase[v, w]
                slot = base + 5 * k
                row[slot] = _rel(known_pos[v, w, 0] - x, side)
                row[slot + 1] = _rel(known_pos[v, w, 1] - y, side)
                row[slot + 2] = 1.0 if group[v, w] else 0.0
                row[slot + 3] = age / (age + 1.0)
                row[slot + 4] = 1.0
    return out.astype(np.float32)
