"""MultiHop's TDMA frame compiled (numba) over a copy axis: what the copy-axis world (:mod:`.copy_axis`) calls.

Written slot by slot in numpy (the test oracle, ``tests/helpers/multihop_reference.py``), the frame is a handful of
numpy calls per slot (the oracle's ``deliver_one``): about 4 ms of the 5 ms a 100-robot frame took. This runs the
whole frame in one call, with the same rules in the same order (§2.1: every sender stamps its own estimate with the
current time; it sends its own estimate and the first ``m − 1`` further candidates of its ranked list that it holds;
each neighbour keeps the newer time stamp per robot; a first arrival is dated at the end of the slot). Every number
it writes is the oracle's, bit for bit: the clock is advanced by the same float additions, and the rest are copies
and comparisons (``tests/multihop/test_multihop.py`` and ``test_multihop_world.py`` compare whole seeded episodes).
While robots move (the ``field`` scene with ``speed`` above 0), each slot's links and the robots' motion come first
(:func:`slot_receivers`, :func:`move_to_waypoints`), then :func:`send_moving_slots`; the coverage controller moves
the robots between slots, since where it flies depends on what was received.

Arrays carry a leading copy axis M so that a batch of copies is run in one call; a single env is the world of its
one copy (M = 1).
"""

from __future__ import annotations

import numba
import numpy as np

from mrcomm_env.core.backend import configure_numba_cache
from mrcomm_env.core.sums_numba import numpy_sum

configure_numba_cache()  # before the @njit(cache=True) below: never cache into the package


@numba.njit(cache=True)
def _fill_slot(stamps, s, now, ranked, count, m, picked, last_sent, sent_stamp):
    """Sender ``s``'s slot in one copy (§2.1): it stamps its own estimate with ``now`` and sends it and the first
    ``m − 1`` further candidates of its ranked list (``ranked``, of which ``count`` are selected) that it holds, into
    ``picked``; marks them in ``last_sent`` and ``sent_stamp``. Returns how many it sends."""
    stamps[s, s] = now  # own state is always current
    held = 0
    for q in range(count):
        if held == m:
            break
        j = ranked[q]
        if stamps[s, j] > -np.inf:
            picked[held] = j
            held += 1
    for q in range(held):
        j = picked[q]
        last_sent[s, j] = True
        sent_stamp[s, j] = stamps[s, j]
    return held


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
            held = _fill_slot(stamps[c], s, now, rank[c, s], count[c, s], m, picked, last_sent[c], sent_stamp[c])
            sent[c, s] = held
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


@numba.njit(cache=True)
def send_moving_slots(
    stamps,
    est,
    order,
    rank,
    count,
    m,
    t,
    slot_dur,
    receivers,
    sender_pos,
    first_known,
    track_first,
    last_sent,
    sent_stamp,
    sent,
    first,
    last,
):
    """Slots ``first`` to ``last − 1`` of a frame of robots that move (a ``field`` with ``speed`` above 0, or the
    ``coverage`` scene), as :func:`send_frame` sends a whole frame, in place: the links of each slot are where the
    robots are at that slot, and every estimate carries the position it was stamped with.

    ``est`` (M, n, n, 2) each robot's estimate of each position; ``receivers`` (M, n, n) bool: who is within range
    of the k-th slot's sender at that slot; ``sender_pos`` (M, n, 2): that sender's position then (its own estimate
    is stamped there, as ``ReferenceMultiHop._step_world`` does). The rest as :func:`send_frame`: the same selection,
    clock and first arrivals, and a receiver takes a position with each newer stamp (the oracle's ``deliver_one``).
    ``last_sent`` is cleared at the frame's first slot; ``t`` (M,) ends at the last slot sent."""
    n_copies, n = order.shape
    for c in range(n_copies):
        now = t[c]
        track = track_first[c]
        picked = np.empty(m, dtype=np.int64)
        if first == 0:
            for i in range(n):
                for j in range(n):
                    last_sent[c, i, j] = False
        for k in range(first, last):
            s = order[c, k]
            held = _fill_slot(stamps[c], s, now, rank[c, s], count[c, s], m, picked, last_sent[c], sent_stamp[c])
            sent[c, s] = held
            now += slot_dur
            est[c, s, s, 0] = sender_pos[c, k, 0]
            est[c, s, s, 1] = sender_pos[c, k, 1]
            for r in range(n):
                if not receivers[c, k, r]:
                    continue
                for q in range(held):
                    j = picked[q]
                    new = stamps[c, s, j]
                    old = stamps[c, r, j]
                    if new > old:
                        stamps[c, r, j] = new
                        est[c, r, j, 0] = est[c, s, j, 0]
                        est[c, r, j, 1] = est[c, s, j, 1]
                        if track and old == -np.inf:
                            first_known[c, r, j] = now
        t[c] = now


@numba.njit(cache=True)
def slot_receivers(pos, senders, r2, receivers, sender_pos):
    """Who is within range (squared: ``r2``) of each copy's slot sender (``senders`` (M,)) where the robots ``pos``
    (M, n, 2) are now, into ``receivers`` (M, n), and the sender's position into ``sender_pos`` (M, 2)
    (``ReferenceMultiHop._receivers``). A squared distance is ``dx·dx + dy·dy``, as numpy's ``einsum`` sums two squares."""
    n_copies, n, _ = pos.shape
    for c in range(n_copies):
        s = senders[c]
        sx, sy = pos[c, s, 0], pos[c, s, 1]
        sender_pos[c, 0], sender_pos[c, 1] = sx, sy
        for r in range(n):
            dx, dy = pos[c, r, 0] - sx, pos[c, r, 1] - sy
            receivers[c, r] = r != s and dx * dx + dy * dy <= r2


@numba.njit(cache=True)
def move_to_waypoints(pos, waypoint, step, arrived):
    """One slot of the field's random-waypoint motion in every copy (``ReferenceMultiHop._move``), in place: every robot
    moves ``step`` toward its waypoint, arriving exactly where it is closer than that. ``arrived`` (M, n) says who
    arrived, and the return value how many; the caller draws their next waypoints from each copy's generator
    (nothing here draws). The env's float operations in its order (``linalg.norm`` of two components is the square
    root of ``dx·dx + dy·dy``)."""
    n_copies, n, _ = pos.shape
    arrivals = 0
    for c in range(n_copies):
        for r in range(n):
            dx, dy = waypoint[c, r, 0] - pos[c, r, 0], waypoint[c, r, 1] - pos[c, r, 1]
            dist = np.sqrt(dx * dx + dy * dy)
            arrived[c, r] = dist <= step
            if arrived[c, r]:
                pos[c, r, 0], pos[c, r, 1] = waypoint[c, r, 0], waypoint[c, r, 1]
                arrivals += 1
            else:
                scale = step / max(dist, 1e-12)
                pos[c, r, 0] += dx * scale
                pos[c, r, 1] += dy * scale
    return arrivals


@numba.njit(cache=True)
def _next_level(rows, frontier, size, seen, level, found):
    """One level of a breadth-first search over links as 64-bit words: the robots linked to any of the ``size``
    robots of ``frontier`` and not yet ``seen`` (a bit set, updated) into ``found``; returns how many."""
    one = np.uint64(1)
    level[:] = 0
    for f in range(size):
        u = frontier[f]
        for w in range(level.size):
            level[w] |= rows[u, w]
    count = 0
    for w in range(level.size):
        new = level[w] & ~seen[w]
        seen[w] |= new
        while new:
            low = new & (~new + one)  # the lowest set bit
            bit = 0
            while (low >> np.uint64(bit)) != one:
                bit += 1
            found[count] = (w << 6) + bit
            count += 1
            new ^= low
    return count


@numba.njit(cache=True)
def hop_buckets(adj, hop_flat, hop_bounds):
    """Each copy's pairs by hop distance over its links ``adj`` (M, n, n) bool, as ``MultiHopEnv._hops`` buckets them
    (1, 2, 3, and 4 or more or never reached; not a robot with itself): the flat pair indices of bucket after bucket,
    each bucket in ascending order, into ``hop_flat`` (M, n(n − 1)) with bounds ``hop_bounds`` (M, 5). A
    breadth-first search from every robot over the links as 64-bit words (a level is the union of its robots' rows,
    n/64 words each: n³/64 word operations for a copy whose robots all hear each other, where one robot at a time cost
    n³): hop counts are integers, so they are ``scipy``'s shortest paths exactly
    (``tests/multihop/test_multihop_world.py`` compares the buckets with scipy's)."""
    n_copies, n, _ = adj.shape
    words = (n + 63) // 64
    rows = np.zeros((n, words), dtype=np.uint64)
    seen = np.empty(words, dtype=np.uint64)
    level = np.empty(words, dtype=np.uint64)
    frontier = np.empty(n, dtype=np.int64)
    found = np.empty(n, dtype=np.int64)
    bucket = np.empty(n * n, dtype=np.int8)
    one = np.uint64(1)
    for c in range(n_copies):
        rows[:] = 0
        for u in range(n):
            for v in range(n):
                if adj[c, u, v]:
                    rows[u, v >> 6] |= one << np.uint64(v & 63)
        for i in range(n):
            bucket[i * n : (i + 1) * n] = 3  # 4 or more hops, or never reached
            bucket[i * n + i] = -1
            seen[:] = 0
            seen[i >> 6] |= one << np.uint64(i & 63)
            frontier[0] = i
            size = 1
            for hops in range(1, 4):  # levels 1–3 are buckets of their own; the rest is bucket 3 already
                size = _next_level(rows, frontier, size, seen, level, found)
                for f in range(size):
                    bucket[i * n + found[f]] = hops - 1
                    frontier[f] = found[f]
        e = 0
        hop_bounds[c, 0] = 0
        for k in range(4):
            for f in range(n * n):
                if bucket[f] == k:
                    hop_flat[c, e] = f
                    e += 1
            hop_bounds[c, k + 1] = e


def neighbour_lists(adjacency: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An (n, n) boolean adjacency as CSR rows for :func:`send_frame` (one copy: shapes (1, n + 1), (1, E))."""
    rows, cols = np.nonzero(adjacency)
    ptr = np.zeros(adjacency.shape[0] + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=adjacency.shape[0]), out=ptr[1:])
    return ptr[None, :], cols.astype(np.int64)[None, :]


@numba.njit(cache=True)
def selected_ranks(candidates, selected, rank, count):
    """The ``relative`` layout's frame lists of every copy (``ReferenceMultiHop._priorities`` then the oracle's
    ``priority_ranking``): each robot's own index, then its selected candidates in candidate order.
    The selected ranks' priorities fall strictly with the rank, so that order is the descending one.

    ``candidates`` (M, n, n − 1) robot index per rank; ``selected`` (M, n, n − 1) bool; writes ``rank`` (M, n, n)
    (the first ``count`` (M, n) entries of each row are valid, as :func:`send_frame` reads them)."""
    n_copies, n, n_cand = candidates.shape
    for c in range(n_copies):
        for i in range(n):
            rank[c, i, 0] = i
            q = 1
            for k in range(n_cand):
                # without a branch: random select bits mispredicted every other one (3x slower); the write lands at
                # q <= k + 1 < n and is overwritten by the next selected candidate when this one is not selected
                rank[c, i, q] = candidates[c, i, k]
                q += selected[c, i, k]
            count[c, i] = q


#: picks by scanning a row for its best remaining robot before the rest of the row is sorted instead (each scan is
#: O(n); a row whose robots are mostly not yet held needs many picks, early in an episode)
SCAN_PICKS = 16


@numba.njit(cache=True)
def priority_ranks(priority, stamps, m, rank, count):
    """The ``absolute`` layout's frame lists of every copy (the oracle's ``priority_ranking``), as far as
    :func:`send_frame` reads them: each robot's own index, then the robots it gives a priority above 0, by
    descending priority (ties: lower index first), up to the (m − 1)-th one it holds at the frame's start.

    ``priority`` (M, n, n) float64 and ``stamps`` (M, n, n) at the frame's start; writes ``rank`` (M, n, n), of
    whose rows the first ``count`` (M, n) entries are valid. The reference ranks every robot with priority above 0
    (numpy's stable sort of the whole row); :func:`send_frame` reads a list until the sender holds ``m`` of its
    entries at its slot, and a robot holds at its slot at least what it held at the frame's start, so it never
    reads past the entries written here: every copy sends what the reference sends. The best remaining robot is
    found by a scan (strictly greater, so a tie goes to the lower index); after ``SCAN_PICKS`` picks the rest of
    the row is sorted with a stable merge sort of its positive entries in index order (a stable sort's order is
    unique: the reference's)."""
    n_copies, n, _ = priority.shape
    taken = np.zeros(n, dtype=np.bool_)
    index = np.empty(n, dtype=np.int64)
    key = np.empty(n)
    for c in range(n_copies):
        for i in range(n):
            rank[c, i, 0] = i
            q, held = 1, 1
            taken[:] = False
            while held < m and q <= SCAN_PICKS:
                best, best_p = -1, 0.0
                for j in range(n):
                    p = priority[c, i, j]
                    if p > best_p and j != i and not taken[j]:
                        best, best_p = j, p
                if best < 0:
                    break
                taken[best] = True
                rank[c, i, q] = best
                q += 1
                if stamps[c, i, best] > -np.inf:
                    held += 1
            if held < m and q > SCAN_PICKS:  # many robots not yet held: sort the rest of the row
                k = 0
                for j in range(n):
                    if priority[c, i, j] > 0.0 and j != i and not taken[j]:
                        index[k] = j
                        key[k] = -priority[c, i, j]
                        k += 1
                order = np.argsort(key[:k], kind="mergesort")
                for e in range(k):
                    rank[c, i, q] = index[order[e]]
                    q += 1
            count[c, i] = q


@numba.njit(cache=True)
def observe_indices(stamps, t, dist, phase, slot, m, frame_dur, diag, out, known_fraction):
    """The ``absolute`` observation of every copy (``MultiHopEnv._observe``), into ``out`` (M, n, 3n + 2) float32: by
    robot index, the age ``a/(a + T_frame)`` (not held: 1), the distance over the diagonal (not held: 1) and the slot
    phase; then my slot ``s_i/n`` and ``m/n``. The same float64 operations as the env's, rounded to float32 once.
    ``known_fraction`` (M, n) float64: the fraction of the others each robot holds, the info of that name."""
    n_copies, n, _ = stamps.shape
    for c in range(n_copies):
        now = t[c]
        for i in range(n):
            held = 0
            for j in range(n):
                s = stamps[c, i, j]
                if s > -np.inf:
                    if j != i:
                        held += 1
                    age = now - s
                    out[c, i, j] = age / (age + frame_dur)
                    out[c, i, n + j] = min(dist[c, i, j] / diag, 1.0)
                else:
                    out[c, i, j] = 1.0
                    out[c, i, n + j] = 1.0
                out[c, i, 2 * n + j] = phase[c, i, j]
            out[c, i, 3 * n] = slot[c, i] / n
            out[c, i, 3 * n + 1] = m / n
            known_fraction[c, i] = held / (n - 1)


@numba.njit(cache=True)
def close_frames(stamps, t, first_known, tracking, weights, weight_sum, hop_flat, hop_bounds, totals, mean_age, wage):
    """The end of a frame of every copy (``MultiHopEnv._step_world`` after the slots, then ``_frame_end``): own
    stamps set to ``t``, ``tracking`` (M,) cleared once every first arrival is known, and the frame's ages folded
    into the time averages. ``totals`` (M, 3 + 2·4) holds per copy the frames, the summed mean age, the summed
    weighted mean age of eq. (1), the largest age per hop bucket and the summed mean age per hop bucket; writes
    ``mean_age`` (M, n), each robot's mean age of the others (the info), and ``wage`` (M,), this frame's weighted
    mean age. ``hop_flat`` (H, K) and ``hop_bounds`` (H, 5): flat pair indices of the hop buckets one after the
    other, for every copy (H = M) or for all at once (H = 1: the grid's links are the same in every copy).

    The ages are the env's ``t − stamp`` (unknown: ``t``); every sum and mean is numpy's over the same values in
    the same order (:func:`numpy_sum`), so every number is the env's, bit for bit."""
    n_copies, n, _ = stamps.shape
    n_buckets = hop_bounds.shape[1] - 1
    ages = np.empty(n * n)
    weighted = np.empty(n * n)
    off = np.empty(n * (n - 1))
    picked = np.empty(hop_flat.shape[1])
    for c in range(n_copies):
        now = t[c]
        for i in range(n):
            stamps[c, i, i] = now  # own state is current
        if tracking[c]:
            complete = True
            for i in range(n):
                for j in range(n):
                    if not np.isfinite(first_known[c, i, j]):
                        complete = False
                        break
                if not complete:
                    break
            tracking[c] = not complete
        for i in range(n):
            row = i * n
            for j in range(n):  # no branch but a select: the loop vectorises
                s = stamps[c, i, j]
                age = now - s if s > -np.inf else now
                ages[row + j] = age
                weighted[row + j] = weights[c, i, j] * age
            # the off-diagonal ages in row-major order: the row without its own entry
            start = i * (n - 1)
            off[start : start + i] = ages[row : row + i]
            off[start + i : start + n - 1] = ages[row + i + 1 : row + n]
        totals[c, 0] += 1.0
        totals[c, 1] += numpy_sum(off, 0, off.size) / off.size
        wage[c] = numpy_sum(weighted, 0, n * n) / weight_sum[c]
        totals[c, 2] += wage[c]
        h = c if hop_flat.shape[0] > 1 else 0
        for k in range(n_buckets):
            lo, hi = hop_bounds[h, k], hop_bounds[h, k + 1]
            if hi > lo:
                largest = -np.inf
                for e in range(lo, hi):
                    picked[e - lo] = ages[hop_flat[h, e]]
                    largest = max(largest, picked[e - lo])
                totals[c, 3 + k] = max(totals[c, 3 + k], largest)
                totals[c, 3 + n_buckets + k] += numpy_sum(picked, 0, hi - lo) / (hi - lo)
        for i in range(n):
            # the diagonal age is 0 (own stamp = t): the env's (ages · off) row sum is this row's sum
            mean_age[c, i] = numpy_sum(ages, i * n, n) / (n - 1)


@numba.njit(cache=True)
def observe_candidates(stamps, sent_stamp, t, dist, phase, candidates, slot, m, frame_dur, diag, out, known_fraction):
    """The ``relative`` observation of every copy (``MultiHopEnv._observe``), into ``out`` (M, n, 5(n − 1) + 3)
    float32: per candidate rank held, distance over the diagonal, age ``a/(a + T_frame)``, freshness gained since
    last sent ``g/(g + T_frame)`` and slot position after mine; then my slot ``s_i/n``, ``m/n`` and the fraction of
    the others I hold. The same float64 operations as the env's, rounded to float32 once. ``known_fraction``
    (M, n) float64: that last fraction unrounded, the info of the same name."""
    n_copies, n, n_cand = candidates.shape
    tail = 5 * n_cand
    for c in range(n_copies):
        now = t[c]
        for i in range(n):
            held = 0  # the candidates are the others: those held are the others held
            for k in range(n_cand):
                j = candidates[c, i, k]
                s = stamps[c, i, j]
                base = 5 * k
                if s > -np.inf:
                    held += 1
                    age = now - s
                    gain = max(s - sent_stamp[c, i, j], 0.0)
                    out[c, i, base] = 1.0
                    out[c, i, base + 1] = min(dist[c, i, j] / diag, 1.0)
                    out[c, i, base + 2] = age / (age + frame_dur)
                    out[c, i, base + 3] = gain / (gain + frame_dur)
                else:
                    out[c, i, base] = 0.0
                    out[c, i, base + 1] = 1.0
                    out[c, i, base + 2] = 1.0
                    out[c, i, base + 3] = 0.0
                out[c, i, base + 4] = phase[c, i, j]
            out[c, i, tail] = slot[c, i] / n
            out[c, i, tail + 1] = m / n
            known_fraction[c, i] = held / (n - 1)
            out[c, i, tail + 2] = known_fraction[c, i]


@numba.njit(cache=True)
def rerank_candidates(stamps, ranked_known, near_order, slot_order, candidates):
    """``MultiHopEnv._rank_candidates`` of every copy of a static scene whose held estimates changed since its last
    ranking (the rest would be ranked the same); returns how many copies were re-ranked.

    The env sorts each row by the key ``d̂/diag`` (held) or ``2 + slot phase`` (not held), own entry last, with a
    stable sort. On a static scene both keys are fixed for the episode, and a held key (at most 1: every distance
    is within the arena's diagonal) always sorts before a missing one (at least 2), so the sorted row is the held
    robots in the order of ``near_order`` (M, n, n), each row's stable argsort of ``d̂/diag``, followed by the
    missing ones in the order of ``slot_order``, the stable argsort of the phases: a merge of two fixed orders,
    equal index for index to the env's sort. Writes ``candidates`` (M, n, n − 1) and ``ranked_known`` (M, n, n)."""
    n_copies, n, _ = stamps.shape
    reranked = 0
    for c in range(n_copies):
        same = True
        for i in range(n):
            for j in range(n):
                if (stamps[c, i, j] > -np.inf) != ranked_known[c, i, j]:
                    same = False
                    break
            if not same:
                break
        if same:
            continue
        reranked += 1
        for i in range(n):
            for j in range(n):
                ranked_known[c, i, j] = stamps[c, i, j] > -np.inf
            q = 0
            for k in range(n):
                j = near_order[c, i, k]
                if j != i and ranked_known[c, i, j]:
                    candidates[c, i, q] = j
                    q += 1
            for k in range(n):
                j = slot_order[c, i, k]
                if j != i and not ranked_known[c, i, j]:
                    candidates[c, i, q] = j
                    q += 1
    return reranked
