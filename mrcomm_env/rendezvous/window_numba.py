"""RendezvousMapping's window, compiled (numba): where each vehicle's action takes it, and which of the window's
observations its landmarks still yield (``RendezvousMappingEnv._window``, its only implementation in the package).

The reference (the numpy oracle, ``tests/helpers/rendezvous_reference.py``) walks each vehicle's legs in Python
(``_route``), lists every observation instant of every leg, sorts all of them by time (ties: vehicle id, then leg)
and keeps, per landmark, those within the sensor floor. This twin computes the legs with the reference's formulas,
in the same floating-point operations and order, and never lists the instants: a leg observes a contiguous run of
the window's sorted instants (the reference's two-sided tolerance test is a range of a sorted array), so it merges
the legs' runs in the reference's order and drops a leg once its landmark has reached the floor. What it returns,
the kept (vehicle, landmark) pairs in the reference's order, is what the reference keeps, and it never visits an
observation it does not keep (no sort: its kernels compile in a fraction of the time numba's sorts take); the noise
of each observation is drawn by the caller, in that order, as the reference draws it.
``tests/rendezvous_mapping/test_rendezvous_compiled.py`` compares whole seeded episodes with the oracle's, and this
window alone on crowded, tied and out-of-reach windows.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mrcomm_env.core.backend import configure_numba_cache

configure_numba_cache()  # before the @njit(cache=True) below: never cache into the package

#: action kinds, as ``env.GO`` … ``env.HOLD``
GO, DETOUR_RENDEZVOUS, RENDEZVOUS, HOLD = 0, 1, 2, 3


@numba.njit(cache=True)
def window(
    actions,
    mask,
    candidates,
    assignment,
    central,
    rendezvous_point,
    at_landmark,
    pos,
    estimates,
    ticks,
    window_s,
    speed,
    world_count,
    floor,
    action_kind,
    action_ok,
):
    """One window: ``(new_pos, new_at, vehicles, landmarks)``; writes ``action_kind`` and ``action_ok``.

    ``vehicles``/``landmarks`` are the observations the landmarks still yield (``world_count`` below ``floor``),
    in time order (ties: vehicle id, then the vehicle's leg), as the reference's ``_useful_events`` keeps them.
    """
    n = pos.shape[0]
    K = candidates.shape[1]
    new_pos = pos.copy()
    new_at = np.full(n, -1, dtype=np.int64)
    # the legs that observe: vehicle, position in its route, landmark, first and end index into ticks
    legs = np.empty((2 * n, 5), dtype=np.int64)
    n_legs = 0
    targets = np.empty((2, 2))
    landmarks = np.empty(2, dtype=np.int64)
    leaves = np.empty(2)  # departure time; NaN: stays to the end of the window
    for v in range(n):
        a = actions[v]
        ok = mask[v, a]
        action_ok[v] = ok
        if not ok:
            a = K + 1
        action_kind[v], count = _route(
            v, a, candidates, assignment, central, rendezvous_point, at_landmark, pos, estimates, window_s, speed,
            targets, landmarks, leaves,
        )  # fmt: skip
        n_legs, new_pos[v, 0], new_pos[v, 1], new_at[v] = _travel(
            v, count, pos, targets, landmarks, leaves, ticks, window_s, speed, legs, n_legs
        )
    vehicles, observed = _kept_observations(legs[:n_legs], world_count, floor)
    return new_pos, new_at, vehicles, observed


@numba.njit(cache=True)
def _route(
    v, a, candidates, assignment, central, rendezvous_point, at_landmark, pos, estimates, T, u, targets, landmarks,
    leaves,
):  # fmt: skip
    """Vehicle v's legs for action a (the oracle's ``_route``) into ``targets``/``landmarks``/``leaves``:
    ``(action kind, legs)``."""
    K = candidates.shape[1]
    if a < K:
        lm = candidates[v, a]
        targets[0, 0], targets[0, 1] = estimates[v, lm, 0], estimates[v, lm, 1]
        landmarks[0], leaves[0] = lm, np.nan
        return GO, 1
    if a == K:
        lp, lc = assignment[v], central[v]
        mx, my = rendezvous_point[v, 0], rendezvous_point[v, 1]
        if lp >= 0 and lp != lc:
            px, py = estimates[v, lp, 0], estimates[v, lp, 1]
            d1 = np.hypot(px - pos[v, 0], py - pos[v, 1])
            d2 = np.hypot(mx - px, my - py)
            if d1 + d2 < u * T:  # Fig. 5 condition 4: observe l_p(v), then reach l_c in time
                targets[0, 0], targets[0, 1] = px, py
                landmarks[0], leaves[0] = lp, T - d2 / u
                targets[1, 0], targets[1, 1] = mx, my
                landmarks[1], leaves[1] = lc, np.nan
                return DETOUR_RENDEZVOUS, 2
        targets[0, 0], targets[0, 1] = mx, my
        landmarks[0], leaves[0] = lc, np.nan
        return RENDEZVOUS, 1
    lm = at_landmark[v]
    if lm < 0:
        return HOLD, 0
    targets[0, 0], targets[0, 1] = pos[v, 0], pos[v, 1]
    landmarks[0], leaves[0] = lm, np.nan
    return HOLD, 1


@numba.njit(cache=True)
def _travel(v, count, pos, targets, landmarks, leaves, ticks, T, u, legs, n_legs):
    """Vehicle v travels its legs (``env._step_world``), appending those it reaches to ``legs``:
    ``(legs now, x, y, landmark it ends at or −1)``."""
    hx, hy, t, final = pos[v, 0], pos[v, 1], 0.0, -1
    for k in range(count):
        tx, ty = targets[k, 0], targets[k, 1]
        dist = np.hypot(tx - hx, ty - hy)
        arrive = t + dist / u
        if arrive > T + 1e-9:  # out of reach: travel towards it for the rest of the window
            f = (T - t) * u / dist
            return n_legs, hx + (tx - hx) * f, hy + (ty - hy) * f, -1
        end = T if math.isnan(leaves[k]) else leaves[k]
        # the instants with arrive − 1e-9 ≤ tick ≤ end + 1e-9: a run of the sorted ticks
        legs[n_legs, 0], legs[n_legs, 1], legs[n_legs, 2] = v, k, landmarks[k]
        legs[n_legs, 3] = _first_at_least(ticks, arrive - 1e-9)
        legs[n_legs, 4] = _first_above(ticks, end + 1e-9)
        n_legs += 1
        hx, hy, t, final = tx, ty, end, landmarks[k]
    return n_legs, hx, hy, final


@numba.njit(cache=True)
def _first_at_least(sorted_values, x):
    """The first index i with ``sorted_values[i] >= x`` (``np.searchsorted(..., side="left")``)."""
    lo, hi = 0, sorted_values.size
    while lo < hi:
        mid = (lo + hi) // 2
        if sorted_values[mid] < x:
            lo = mid + 1
        else:
            hi = mid
    return lo


@numba.njit(cache=True)
def _first_above(sorted_values, x):
    """The first index i with ``sorted_values[i] > x`` (``np.searchsorted(..., side="right")``)."""
    lo, hi = 0, sorted_values.size
    while lo < hi:
        mid = (lo + hi) // 2
        if sorted_values[mid] <= x:
            lo = mid + 1
        else:
            hi = mid
    return lo


@numba.njit(cache=True)
def _kept_observations(legs, world_count, floor):
    """The observations of all ``legs`` in time order (ties: vehicle, then the vehicle's leg, the order legs are
    listed in), each kept while its landmark is below the floor: ``(vehicles, landmarks)`` of the kept ones.

    A merge of the legs' runs of instants that drops a leg once its landmark is exhausted, so that it visits the
    kept observations only (a landmark's rank in this order is the reference's rank: ``_useful_events``).
    """
    n_legs = legs.shape[0]
    at = legs[:, 3].copy()
    left = np.full(world_count.size, -1, dtype=np.int64)  # observations each landmark of a leg still yields
    bound, runs = 0, 0  # at most what is kept: the landmarks' allowance, or every leg's run if fewer
    for j in range(n_legs):
        lm = legs[j, 2]
        if left[lm] < 0:
            left[lm] = max(floor - world_count[lm], 0)
            bound += left[lm]
        runs += max(legs[j, 4] - legs[j, 3], 0)
    bound = min(bound, runs)
    vehicles = np.empty(bound, dtype=np.int64)
    observed = np.empty(bound, dtype=np.int64)
    total = 0
    while True:
        best = -1
        for j in range(n_legs):  # the earliest instant; on a tie the first listed leg
            if at[j] < legs[j, 4] and left[legs[j, 2]] > 0 and (best < 0 or at[j] < at[best]):
                best = j
        if best < 0:
            break
        lm = legs[best, 2]
        vehicles[total], observed[total] = legs[best, 0], lm
        total += 1
        left[lm] -= 1
        at[best] += 1
    return vehicles[:total], observed[:total]


@numba.njit(cache=True)
def group_observations(vehicles, landmarks, contributions, n_landmarks, n_vehicles):
    """The kept observations as packets: ``(owners, bounds, ids, counts, dy, per_vehicle)``.

    Pairs (vehicle, landmark) in increasing order (``np.unique`` of ``vehicle·L + landmark``), each with its number
    of observations and the sum of its ``contributions`` rows (z·R⁻¹) in the order given (``np.add.at``'s order,
    from 0); vehicle ``owners[j]`` holds pairs ``bounds[j]`` to ``bounds[j+1]`` (exclusive). ``per_vehicle`` counts
    each vehicle's observations (``np.bincount``).
    """
    m = vehicles.size
    keys = vehicles * n_landmarks + landmarks
    # stable: a pair's observations stay in the order given (by landmark, then by vehicle: a radix sort)
    order = _stable_counting_order(vehicles, n_vehicles, _stable_counting_order(landmarks, n_landmarks, np.arange(m)))
    ids = np.empty(m, dtype=np.int64)
    counts = np.zeros(m, dtype=np.int64)
    dy = np.zeros((m, 2))
    bounds = np.empty(m + 1, dtype=np.int64)
    owner_ids = np.empty(m, dtype=np.int64)
    per_vehicle = np.zeros(n_vehicles, dtype=np.int64)
    pairs, owners, last_key, last_owner = 0, 0, -1, -1
    for i in range(m):
        e = order[i]
        if keys[e] != last_key:
            last_key = keys[e]
            ids[pairs] = landmarks[e]
            if vehicles[e] != last_owner:
                last_owner = vehicles[e]
                owner_ids[owners] = last_owner
                bounds[owners] = pairs
                owners += 1
            pairs += 1
        p = pairs - 1
        counts[p] += 1
        dy[p, 0] += contributions[e, 0]
        dy[p, 1] += contributions[e, 1]
        per_vehicle[vehicles[e]] += 1
    bounds[owners] = pairs
    return owner_ids[:owners], bounds[: owners + 1], ids[:pairs], counts[:pairs], dy[:pairs], per_vehicle


@numba.njit(cache=True)
def _stable_counting_order(values, size, order):
    """``order`` re-sorted stably by ``values[order]`` (integers in 0 … size − 1): a counting sort."""
    starts = np.zeros(size + 1, dtype=np.int64)
    for i in order:
        starts[values[i] + 1] += 1
    for v in range(size):
        starts[v + 1] += starts[v]
    out = np.empty(order.size, dtype=np.int64)
    for i in order:
        out[starts[values[i]]] = i
        starts[values[i]] += 1
    return out
