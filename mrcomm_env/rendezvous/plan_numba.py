"""The recommendation phase's partition loop compiled (numba; §IV-C/D, ``protocol.recommend``).

A pass assigns vehicles to landmarks (Munkres), clusters the assigned landmarks, picks the main cluster μ_max
(eq. 6) and its central landmark l_c (eigenvector centrality [16]), and, while the assignment is not connected,
the outlier l_o (eq. 7) whose half-plane cut (eq. 8) shrinks the working set. Written in numpy (the oracle,
``tests/helpers/rendezvous_reference.py``), a pass spends ~90 µs of interpreter round trips on 2–10 landmarks, and a 10-vehicle team at d_comms = 10 m makes
about a dozen passes per decision phase.

:func:`recommend_loop` runs the whole loop, Munkres included (:func:`lsap_max`, scipy's algorithm step for step),
and the candidate columns Munkres sees: every row's n best, ties to the lowest column (:func:`_best_union`, as the
reference's stable sort). It hands back to the caller where numpy's rounding could matter: an eq. (8) product
within rounding of 0, whose sign numpy's ``@`` (a BLAS call, rounding otherwise than two products and a sum) might
round differently; the caller's passes then go on, each with :func:`partition_pass` (the
clustering, eq. (6), l_c, eq. (7) and eq. (8)'s offsets in one call). l_c's eigenvector is numba's ``eigh``
(LAPACK's ``syevd`` through scipy, numpy's ``eigh`` runs the same routine through its own build): it gave the
reference's eigenvector bit for bit on 20,000 random and grid clusters here, and l_c depends on it only through a
1e-9 relative tie tolerance, so two builds could disagree only on entries within round-off of that tolerance.
``tests/rendezvous_mapping/test_rendezvous_compiled.py`` compares Munkres, the eq. (8) signs, single passes, whole
plans (also resumed from any pass) and whole seeded episodes with the oracle's.

The phase's other per-step arrays: eq. (1)–(4)'s utility of one map per vehicle up to numpy's ``log1p``
(:func:`utility_argument`) and the env's candidate lists (:func:`negated_work`, :func:`ranked_candidates`), each
compared with numpy byte for byte.

Ties go to the lowest column or landmark id everywhere, never to numpy's ``argpartition``: numpy dispatches that to
SIMD selection code by CPU (x86-simd-sort on AVX2 and AVX-512), whose choice among equal values differs from one
CPU to another, so a seeded episode would too.
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


#: outcomes of :func:`recommend_loop`: the plan; the working set from which the caller must run the reference's passes
PLANNED, AMBIGUOUS = 0, 1

#: |x·y| of eq. (8) above this many ulps of |x₀y₀| + |x₁y₁| has the same sign however the product is rounded
_SIGN_ULPS = 4.0 * np.finfo(np.float64).eps


@numba.njit(cache=True)
def recommend_loop(U, landmark_pos, d_comms, working):
    """The passes of ``protocol.recommend`` (not recorded) for a group of n ≥ 2 vehicles, from the working set
    ``working``: ``(status, working, assignment, in_main, central, connected)``.

    Two steps of the reference could round or choose in ways of their own; this loop takes the first as the
    reference does and stops where the second could matter, returning the working set of the pass it stopped at:

    * Munkres: never, :func:`lsap_max` is scipy's algorithm step for step (and its candidate columns are
      ``protocol.candidate_columns``'s, ties to the lowest column);
    * eq. (8), when a product x·y is so close to 0 that numpy's BLAS ``@`` and two products and a sum could round
      it to different signs, or fewer working landmarks than vehicles (scipy transposes that problem). AMBIGUOUS:
      the caller runs the reference's passes from ``working``.

    Every pass depends only on its working set, so a caller that resumes from the returned one plans exactly what
    the reference plans."""
    n = U.shape[0]
    assignment = np.full(n, -1, dtype=np.int64)
    in_main = np.zeros(n, dtype=np.bool_)
    rows = np.arange(n)
    while True:
        if len(working) < n:
            return AMBIGUOUS, working, assignment, in_main, -1, False
        columns = _candidate_columns(U, working, n)
        lp = _munkres(U, columns, n)
        k, labels, main, lc, lo, axis, offsets = partition_pass(U, landmark_pos, rows, lp, d_comms, working)
        if k == 1:
            return PLANNED, working, lp, np.ones(n, dtype=np.bool_), lc, True
        keep = np.empty(len(working), dtype=np.bool_)
        kept = 0
        for w in range(len(working)):
            sign = _sign_of_dot(offsets[w, 0], offsets[w, 1], axis[0], axis[1])
            if sign == 2:
                return AMBIGUOUS, working, assignment, in_main, -1, False
            keep[w] = sign > 0
            kept += keep[w]
        if kept < n:
            for i in range(n):
                in_main[i] = labels[i] == main
            return PLANNED, working, lp, in_main, lc, False
        working = working[keep]


@numba.njit(cache=True)
def _sign_of_dot(x0, x1, y0, y1):
    """Sign (−1, 0, 1) of x₀y₀ + x₁y₁ as any rounding of the two products and their sum gives it (BLAS with or
    without a fused multiply-add), or 2 when the roundings could disagree. Both products exact (Dekker's
    two-product error is 0): every rounding is the rounded exact sum. Otherwise the sign is sure when the sum
    exceeds the rounding errors' bound, ≈ 2 ulps of |x₀y₀| + |x₁y₁|."""
    p0 = x0 * y0
    p1 = x1 * y1
    s = p0 + p1
    if _product_error(x0, y0, p0) != 0.0 or _product_error(x1, y1, p1) != 0.0:
        if abs(s) <= _SIGN_ULPS * (abs(p0) + abs(p1)):
            return 2
    return 1 if s > 0.0 else (-1 if s < 0.0 else 0)


@numba.njit(cache=True)
def _product_error(a, b, p):
    """a·b − p exactly, for p = fl(a·b) (Dekker's two-product with Veltkamp's split; no overflow at these sizes)."""
    split = 134217729.0  # 2^27 + 1
    t = split * a
    a_hi = t - (t - a)
    a_lo = a - a_hi
    t = split * b
    b_hi = t - (t - b)
    b_lo = b - b_hi
    return ((a_hi * b_hi - p) + a_hi * b_lo + a_lo * b_hi) + a_lo * b_lo


@numba.njit(cache=True)
def _best_union(U, working, n, chosen):
    """Marks in ``chosen`` the n best working columns of every row: the largest utilities, a NaN after every number
    and ties to the lowest position (``protocol.best_positions``: a stable sort of −U)."""
    keys = np.empty(len(working))
    order = np.empty(n, dtype=np.int64)
    for r in range(n):
        for w in range(len(working)):
            keys[w] = -U[r, working[w]]
        for i in range(_k_best(keys, n, order)):
            chosen[order[i]] = True


@numba.njit(cache=True)
def _k_best(keys, k, order):
    """The positions of the k smallest ``keys`` in the order a stable sort ranks them (a NaN after every number,
    ties to the lower position) into ``order``, by insertion (k is a handful); returns how many, min(k, len(keys))."""
    count = 0
    for p in range(len(keys)):
        key = keys[p]
        if count == k and not _ranks_before(key, p, keys[order[k - 1]], order[k - 1]):
            continue  # (a later position never ranks before an equal key: the lowest positions stay)
        i = min(count, k - 1)
        while i > 0 and _ranks_before(key, p, keys[order[i - 1]], order[i - 1]):
            order[i] = order[i - 1]
            i -= 1
        order[i] = p
        count = min(count + 1, k)
    return count


@numba.njit(cache=True)
def _candidate_columns(U, working, n):
    """``protocol.candidate_columns``: every working column up to n², else the sorted union of every row's n best."""
    W = len(working)
    if W <= n * n:
        return working
    chosen = np.zeros(W, dtype=np.bool_)
    _best_union(U, working, n, chosen)
    return working[np.flatnonzero(chosen)]


@numba.njit(cache=True)
def _munkres(U, columns, n):
    """``protocol.assign``'s matching on the candidate ``columns`` (at least n): the landmark of each vehicle."""
    sub = np.empty((n, len(columns)))
    for r in range(n):
        for c in range(len(columns)):
            sub[r, c] = U[r, columns[c]]
    return columns[lsap_max(sub)]


@numba.njit(cache=True)
def lsap_max(C):
    """``scipy.optimize.linear_sum_assignment(C, maximize=True)`` for C (nr, nc) with nr ≤ nc and finite entries:
    the column of each row. scipy 1.17's ``rectangular_lsap.cpp`` (Crouse's shortest augmenting path) step for
    step, with the same floating-point operations in the same order, so that ties resolve as scipy resolves them."""
    nr, nc = C.shape
    cost = -C  # maximisation: scipy negates the matrix
    u = np.zeros(nr)
    v = np.zeros(nc)
    shortest = np.empty(nc)
    path = np.full(nc, -1, dtype=np.int64)
    col4row = np.full(nr, -1, dtype=np.int64)
    row4col = np.full(nc, -1, dtype=np.int64)
    SR = np.zeros(nr, dtype=np.bool_)
    SC = np.zeros(nc, dtype=np.bool_)
    remaining = np.empty(nc, dtype=np.int64)
    for current in range(nr):
        # augmenting_path(): the shortest augmenting path from row `current`
        min_val = 0.0
        n_remaining = nc
        for it in range(nc):
            remaining[it] = nc - it - 1  # reversed: a constant matrix gives the identity (scipy #11602)
        SR[:] = False
        SC[:] = False
        shortest[:] = np.inf
        sink = -1
        i = current
        while sink == -1:
            index = -1
            lowest = np.inf
            SR[i] = True
            for it in range(n_remaining):
                j = remaining[it]
                r = min_val + cost[i, j] - u[i] - v[j]
                if r < shortest[j]:
                    path[j] = i
                    shortest[j] = r
                if shortest[j] < lowest or (shortest[j] == lowest and row4col[j] == -1):
                    lowest = shortest[j]
                    index = it
            min_val = lowest
            j = remaining[index]
            if row4col[j] == -1:
                sink = j
            else:
                i = row4col[j]
            SC[j] = True
            n_remaining -= 1
            remaining[index] = remaining[n_remaining]
        # update the dual variables
        u[current] += min_val
        for i in range(nr):
            if SR[i] and i != current:
                u[i] += min_val - shortest[col4row[i]]
        for j in range(nc):
            if SC[j]:
                v[j] -= min_val - shortest[j]
        # augment the previous solution
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            previous = col4row[i]
            col4row[i] = j
            j = previous
            if i == current:
                break
    return col4row


@numba.njit(cache=True)
def utility_argument(
    Y, count, vehicle_pos, landmark_pos, speed, t_window, info_per_obs, obs_rate, budget, eps_obs_time
):
    """``protocol.utility_matrix`` of one map per vehicle up to its last step: the (n, L) argument of eq. (1)'s
    log1p, |Y + gI|/|Y| − 1 = (g tr Y + g²)/|Y|, with numpy's operations one element at a time in numpy's order
    (so the same roundings; numpy's ``log1p`` itself stays numpy's, which may use SIMD code of its own)."""
    n, L = count.shape
    out = np.empty((n, L))
    for v in range(n):
        px, py = vehicle_pos[v, 0], vehicle_pos[v, 1]
        for m in range(L):
            ox = px - landmark_pos[v, m, 0]
            oy = py - landmark_pos[v, m, 1]
            d = np.sqrt(ox * ox + oy * oy)
            t_obs = t_window - d / speed  # eq. (4)
            if not t_obs > 0.0:  # np.where(t_obs > 0, t_obs, ε): NaN too takes ε
                t_obs = eps_obs_time
            remaining = float(max(budget - count[v, m], 0))
            x = t_obs * obs_rate
            g = (x if x != x or x < remaining else remaining) * info_per_obs  # np.minimum (NaN propagates)
            a, b, dd = Y[v, m, 0, 0], Y[v, m, 0, 1], Y[v, m, 1, 1]
            out[v, m] = (g * (a + dd) + g * g) / (a * dd - b * b)
    return out


@numba.njit(cache=True, inline="always")
def _ranks_before(key_a, id_a, key_b, id_b):
    """``np.lexsort((ids, keys))``'s order: key, then id; a NaN key after every number (numpy sorts NaN last)."""
    if key_a != key_a:
        return key_b != key_b and id_a < id_b
    if key_b != key_b:
        return True
    return key_a < key_b or (key_a == key_b and id_a < id_b)


@numba.njit(cache=True)
def negated_work(utility, assignment):
    """``env.candidate_lists``'s −work: −utility, with −∞ at each row's recommendation when it is worth something."""
    n, L = utility.shape
    negated = np.empty((n, L))
    for r in range(n):
        for m in range(L):
            negated[r, m] = -utility[r, m]
        a = assignment[r]
        if a >= L:  # numba does not check indices; numpy would raise here too
            raise IndexError("a recommended landmark is out of range")
        if a >= 0 and utility[r, a] > 0:  # the recommendation ranks first
            negated[r, a] = -np.inf
    return negated


@numba.njit(cache=True)
def ranked_candidates(utility, negated, k, K):
    """``env.candidate_lists`` after −work: each row's k best landmarks by (−work, id), as its stable sort ranks
    them, then the ones worth something (utility > 0) in their slots, the rest −1 (utility 0)."""
    n, L = negated.shape
    cand = np.full((n, K), -1, dtype=np.int64)
    cand_u = np.zeros((n, K))
    order = np.empty(k, dtype=np.int64)
    for r in range(n):
        _k_best(negated[r], k, order)  # k ≤ L: all k found
        for j in range(k):
            real = utility[r, order[j]]
            if real > 0:
                cand[r, j] = order[j]
                cand_u[r, j] = real
    return cand, cand_u
