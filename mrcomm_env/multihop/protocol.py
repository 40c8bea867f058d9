"""The multi-hop broadcast core of Julian et al. (paper 003), vectorised over a batch of runs.

Everything here works on a leading batch axis ``B`` so that the environment (``B = 1``, or ``B = n``
robots when a policy plans every robot's slot at once) and the Monte-Carlo reproduction (``B`` random
slot orders side by side) run *the same code*:

* :func:`importance` — eq. (1), ``f_ij = d(p_i, p̂_j)^-α`` (0 for an unknown estimate), scaled per row;
* :func:`location_based_select` — Algorithm 1 with persistent counters, ``O(m n)`` per slot; ``rule``
  ``"text"`` takes the *lowest* counter (§3.2), ``"listing"`` the *highest* (the printed listing);
* :func:`probabilistic_select` — eq. (2) sampling without replacement, in one shot (Plackett–Luce:
  repeatedly drawing by eq. (2) is the same as ranking ``log f + Gumbel``, :func:`gumbel_ranks`);
* :func:`age_aware_select` — our rule: importance × freshness gained since last sent;
* :func:`deliver` — a broadcast: each receiver keeps the newest time stamp per robot (§2.1), batched;
* :func:`record_arrivals` — first time a receiver holds a stamp ``>= threshold`` (propagation time).

Time stamps are float64 seconds; an unknown estimate has stamp ``-inf`` (§2.1's "infinity").
"""

from __future__ import annotations

import numpy as np

UNKNOWN = -np.inf
#: distances are clamped here so that f = d^-α stays finite for co-located robots (own estimate excepted)
MIN_DIST = 1e-3
LOG_MIN_DIST = float(np.log(MIN_DIST))
#: largest scaled log-importance (≈ 1e150): own and co-located estimates never overflow a sum or an age product
LOG_WEIGHT_CAP = 345.0
#: the hop-distance buckets of the per-hop age metrics (1, 2, 3, 4 or more hops); the env and its copy-axis world
#: both size their statistics by it
HOP_BUCKETS = ("1", "2", "3", "4plus")


def importance(dist: np.ndarray, known: np.ndarray, alpha: float) -> np.ndarray:
    """Eq. (1), ``d^-α`` for known estimates and 0 for unknown ones (they cannot be chosen), scaled per row.

    Every use of the importances compares them within one robot's row (eq. (2) normalises them, the
    selection rules rank them), so each row is divided by the importance of the nearest other known robot
    (distance > 0; the robot's own estimate, at distance 0, does not set the scale). Computed in log form:
    raw ``d^-α`` underflows to exactly 0 for every d > 11 at α = 300, which made eq. (2) 0/0. After scaling
    the nearest robot weighs 1, farther ones less (underflowing to 0 only when their share of eq. (2) is
    below 1e-308 anyway), and entries closer than that robot (its own, co-located ones clamped at
    ``MIN_DIST``) weigh at most ``e^LOG_WEIGHT_CAP`` so that sums and products with ages stay finite.
    """
    log_d = np.log(np.maximum(dist, MIN_DIST))
    others = known & (np.asarray(dist) > 0.0)
    ref = np.min(np.where(others, log_d, np.inf), axis=-1, keepdims=True)
    ref = np.where(np.isfinite(ref), ref, LOG_MIN_DIST)  # nothing else known: the scale does not matter
    log_f = np.minimum(-alpha * (log_d - ref), LOG_WEIGHT_CAP)
    return np.where(known, np.exp(log_f), 0.0)


def location_based_select(
    counters: np.ndarray, f: np.ndarray, known: np.ndarray, own: np.ndarray, m: int, rule: str = "text"
) -> np.ndarray:
    """Algorithm 1 for a batch of senders; updates ``counters`` (B, n) in place.

    ``f`` (B, n) importances of eq. (1) with ``f[b, own[b]]`` ignored (it is infinite: the first pick is
    always the sender itself, §3.1), ``known`` (B, n) which estimates exist. Returns ``order`` (B, m)
    of selected robot indices in selection order, ``-1`` where fewer than ``m`` estimates are known.

    Counters are the probability of *not* having been selected (§3.2). Each pick multiplies the
    counters of every still-selectable index by ``1 - P`` (eq. 2 over the remaining set ``M_i``), takes
    the lowest (``"text"``) or highest (``"listing"``) counter and resets it to 1. Unknown indices have
    ``P = 0`` so their counters never move, exactly as in the listing where ``M_i`` holds all indices; they
    are never selected (there is nothing to send).
    """
    bsz, n = counters.shape
    rows = np.arange(bsz)
    order = np.full((bsz, m), -1, dtype=np.int64)
    # first pick: own index (P_ii = 1, every other P = 0): c_ii -> 0, selected, reset to 1. (The listing's
    # argmax would skip it, since 0 is the lowest counter; the own estimate is always sent, §2.2/§3.1.)
    order[:, 0] = own
    counters[rows, own] = 1.0
    avail = known.copy()
    avail[rows, own] = False
    n_avail = avail.sum(axis=1)
    rounds = int(min(m - 1, n_avail.max(initial=0)))
    if rounds <= 0:
        return order
    # rows that can send every known estimate need no arithmetic: every pick ends with c = 1 (shortcut,
    # identical to iterating). Only rows with more candidates than room run the m-1 picks.
    full = n_avail <= m - 1
    if full.any():
        fr = np.flatnonzero(full)
        sub = avail[fr]
        counters[fr] = np.where(sub, 1.0, counters[fr])
        # selection order among a full row does not matter for delivery; list by index
        idx = np.argsort(~sub, axis=1, kind="stable")[:, : m - 1]
        order[fr, 1:] = np.where(np.take_along_axis(sub, idx, axis=1), idx, -1)
    hard = np.flatnonzero(~full)
    if hard.size == 0:
        return order
    c = counters[hard]
    av = avail[hard]
    fh = np.where(av, f[hard], 0.0)
    hr = np.arange(hard.size)
    pick_lowest = rule == "text"
    for k in range(1, m):
        total = fh.sum(axis=1, keepdims=True)  # > 0: these rows still have >= 1 candidate
        c *= 1.0 - fh / total  # eq. (2) inside Algorithm 1; unknown / removed indices have f = 0
        if pick_lowest:
            pick = np.argmin(np.where(av, c, np.inf), axis=1)
        else:
            pick = np.argmax(np.where(av, c, -np.inf), axis=1)
        order[hard, k] = pick
        c[hr, pick] = 1.0
        av[hr, pick] = False
        fh[hr, pick] = 0.0
    counters[hard] = c
    return order


def gumbel_ranks(rng: np.random.Generator, f: np.ndarray) -> np.ndarray:
    """Keys whose descending order is a draw of eq. (2) without replacement (Gumbel-top-k).

    Zero-importance (unknown) entries get ``-inf``.
    """
    with np.errstate(divide="ignore"):
        logf = np.log(f)
    return logf + rng.gumbel(size=f.shape)


def probabilistic_select(
    rng: np.random.Generator, f: np.ndarray, known: np.ndarray, own: np.ndarray, m: int
) -> np.ndarray:
    """Eq. (2) for a batch: own estimate, then ``m - 1`` draws without replacement ∝ ``f`` among known
    estimates. Returns ``order`` (B, m), ``-1`` padded."""
    rows = np.arange(len(own))
    keys = gumbel_ranks(rng, np.where(known, f, 0.0))
    keys[rows, own] = np.inf
    cand = np.argsort(-keys, axis=1, kind="stable")[:, :m]
    ok = np.take_along_axis(known, cand, axis=1)
    ok[:, 0] = True
    return np.where(ok, cand, -1)


def age_aware_select(
    f: np.ndarray, stamps: np.ndarray, sent: np.ndarray, known: np.ndarray, own: np.ndarray, m: int
) -> np.ndarray:
    """Our rule (beyond the paper): rank estimates by ``f_ij × (t_ij − s_ij)``, the eq. (1) importance
    times the freshness the robot gained since it last broadcast ``j`` (``s_ij``: the stamp it sent then).

    On a lossless broadcast every neighbour already holds ``s_ij``, so an estimate with no gain is pure
    redundancy, while ``f × gain`` is the importance-weighted age the neighbours shed by hearing it.
    Estimates without gain only fill room left over (nearest first). Returns ``order`` (B, m)."""
    rows = np.arange(len(own))
    gain = np.where(known, stamps - sent, 0.0)
    score = f * gain
    novel = known & (gain > 0)
    smax = np.maximum(np.where(novel, score, 0.0).max(axis=1, keepdims=True), 1e-300)
    fmax = np.maximum(np.where(known, f, 0.0).max(axis=1, keepdims=True), 1e-300)
    key = np.where(novel, 1.0 + 0.999 * score / smax, np.where(known, 0.999 * f / fmax, -1.0))
    key[rows, own] = np.inf
    cand = np.argsort(-key, axis=1, kind="stable")[:, :m]
    ok = np.take_along_axis(known, cand, axis=1)
    ok[:, 0] = True
    return np.where(ok, cand, -1)


def order_to_mask(order: np.ndarray, n: int) -> np.ndarray:
    """(B, m) index lists (``-1`` padded) to a (B, n) selection mask."""
    bsz, m = order.shape
    sel = np.zeros((bsz, n), dtype=bool)
    rows = np.repeat(np.arange(bsz), m)
    cols = order.ravel()
    ok = cols >= 0
    sel[rows[ok], cols[ok]] = True
    return sel


def deliver(
    stamps: np.ndarray,
    bi: np.ndarray,
    sender: np.ndarray,
    receivers: np.ndarray,
    sel: np.ndarray,
    positions: np.ndarray | None = None,
) -> None:
    """One TDMA slot for a batch: ``sender`` (B,) broadcasts the estimates in mask ``sel`` (B, n) to
    ``receivers`` (B, K) (row indices into ``stamps``; a dummy row may pad). Each receiver keeps the
    newest time stamp per robot (§2.1); ``positions`` (B, R, n, d) follow their stamps."""
    out = np.where(sel, stamps[bi, sender], UNKNOWN)  # (B, n)
    b2 = bi[:, None]
    cur = stamps[b2, receivers]  # (B, K, n)
    upd = out[:, None, :] > cur
    if not upd.any():
        return
    stamps[b2, receivers] = np.where(upd, out[:, None, :], cur)
    if positions is not None:
        src = positions[bi, sender][:, None]  # (B, 1, n, d)
        positions[b2, receivers] = np.where(upd[..., None], src, positions[b2, receivers])


def record_arrivals(
    arrival: np.ndarray,
    stamps: np.ndarray,
    bi: np.ndarray,
    receivers: np.ndarray,
    threshold: float | np.ndarray,
    now: float | np.ndarray,
) -> None:
    """Set ``arrival[b, r, j] = now`` where receiver ``r`` first holds a stamp of ``j`` ``>= threshold``."""
    b2 = bi[:, None]
    a = arrival[b2, receivers]
    thr = np.asarray(threshold, dtype=np.float64)
    if thr.ndim:
        thr = thr[:, None, None]
    new = np.isinf(a) & (stamps[b2, receivers] >= thr)
    if new.any():
        nw = np.asarray(now, dtype=np.float64)
        if nw.ndim:
            nw = nw[:, None, None]
        arrival[b2, receivers] = np.where(new, nw, a)


def centred_block(side: int, k: int) -> np.ndarray:
    """Robot indices of the ``k × k`` subgraph centred on a ``side × side`` grid (row-major ids)."""
    if k > side:
        return np.empty(0, dtype=np.int64)
    lo = (side - k) // 2
    r = np.arange(lo, lo + k)
    return (r[:, None] * side + r[None, :]).ravel()


# ---------------------------------------------------------------------------- what a robot heard (observe_heard)
def hear(heard: np.ndarray, last_sent: np.ndarray, sent_stamp: np.ndarray, adj: np.ndarray) -> None:
    """What each robot heard this frame, into ``heard`` (n, n, n) in place: on a lossless broadcast channel over
    static links, robot i heard every neighbour k broadcast, and k heard i, so k holds at least the stamps either
    sent (``last_sent``, ``sent_stamp``: what each robot broadcast this frame; ``adj``: the links)."""
    sent = np.where(last_sent, sent_stamp, UNKNOWN)  # row k: the stamps k broadcast this frame
    either = np.maximum(sent[None, :, :], sent[:, None, :])  # [i, k, j]: k's or i's broadcast of j
    np.copyto(either, UNKNOWN, where=~(adj[:, :, None] > 0))  # only neighbours hear each other
    np.maximum(heard, either, out=heard)


def neighbour_lack(stamps: np.ndarray, heard: np.ndarray, adj: np.ndarray, frame_dur: float) -> np.ndarray:
    """(n, n): for robot i and estimate j, the mean over i's neighbours k ≠ j (``adj``: the links) of the freshness
    of i's estimate of j beyond the freshest stamp i knows k holds (``heard``),
    ``g/(g + T_frame)``: 1 where i never heard that k holds j; 0 where i holds no estimate of j, or has no neighbour
    but j. A neighbour's own estimate is always current, so k = j lacks nothing. Two n³ temporaries at most."""
    held = stamps > UNKNOWN
    values = np.where(held, stamps, 0.0)  # an estimate i does not hold lacks nothing (zeroed below)
    share = values[:, None, :] - heard  # [i, k, j]: freshness beyond what k is known to hold; inf: never heard
    np.maximum(share, 0.0, out=share)
    with np.errstate(invalid="ignore"):  # inf / inf where never heard: taken as 1 below
        np.divide(share, share + frame_dur, out=share)
    share[np.isnan(share)] = 1.0
    share *= adj[:, :, None]  # k a neighbour of i …
    diagonal = np.arange(len(adj))
    share[:, diagonal, diagonal] = 0.0  # … and k ≠ j
    judges = adj.sum(axis=1)[:, None] - adj  # [i, j]: the neighbours k ≠ j of i
    lack = share.sum(axis=1) / np.maximum(judges, 1)
    return np.where(held & (judges > 0), lack, 0.0)


def neighbourhood_staleness(weighted_ages: np.ndarray, weights: np.ndarray, adj: np.ndarray) -> np.ndarray:
    """(n,): the ``neighbourhood`` reward's age, per robot i the mean over the neighbours its broadcast reaches of
    their own eq. (1)-weighted age (``weighted_ages`` = ``weights`` × ages), its own where it has no neighbour."""
    own = weighted_ages.sum(axis=1) / np.maximum(weights.sum(axis=1), 1e-300)
    deg = adj.sum(axis=1)
    return np.where(deg > 0, (adj @ own) / np.maximum(deg, 1), own)


def reward_weights(pos: np.ndarray, alpha: float) -> tuple[np.ndarray, float | np.ndarray]:
    """Eq. (1)'s weights of the reward at positions ``pos`` (n, 2): ``d_ij^-α`` divided by the largest one (the reward
    is a weighted mean, so the scale cancels), 0 on the diagonal, and their sum. Log form: raw ``d^-α`` underflowed
    to 0 for every pair at α = 300 (a reward of −0.0) and overflowed to inf at α = 200 in a 1 m arena (NaN).

    With a leading copy axis (``pos`` (M, n, 2)) every copy's weights (M, n, n) and sums (M,) at once, each copy's
    the numbers it has alone: elementwise float64 operations, an exact minimum, and numpy's row sums of a C-ordered
    (M, n²) array (each row summed as numpy sums it alone)."""
    n = pos.shape[-2]
    eye = np.eye(n, dtype=bool)
    d = np.linalg.norm(pos[..., :, None, :] - pos[..., None, :, :], axis=-1)
    log_d = np.log(np.maximum(d, MIN_DIST))
    # n ≥ 2 in every scene, so every copy has a nearest pair
    nearest = log_d[..., ~eye].min(axis=-1)[..., None, None]
    # ≤ 1 off the diagonal, = 1 for the nearest pair (the diagonal, clipped to 1 here, is zeroed below)
    w = np.exp(-alpha * np.maximum(log_d - nearest, 0.0))
    w[..., eye] = 0.0
    total = w.reshape(*w.shape[:-2], n * n).sum(axis=-1)  # ≥ 1: the nearest pair weighs 1
    return w, (float(total) if pos.ndim == 2 else total)


def estimated_distances(est: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """(…, n, n) distance from each robot's own position ``pos`` (…, n, 2) to its estimate ``est`` (…, n, n, 2) of
    each other robot, for one team or with a leading copy axis (two squares summed, the same in either)."""
    delta = est - pos[..., :, None, :]
    return np.sqrt(np.einsum("...ijk,...ijk->...ij", delta, delta))


def ranked_candidates(known: np.ndarray, dist: np.ndarray, diag: float, phase: np.ndarray) -> np.ndarray:
    """(…, n, n − 1) each robot's others, nearest estimated first (``dist`` over the arena's ``diag``, at most 1);
    those whose estimate it lacks (``known`` False) last, by slot ``phase`` after its own (at least 2), with a stable
    sort: for one team or with a leading copy axis. Agent-relative: nothing in the ranking depends on absolute robot
    indices (slot phases are distinct)."""
    n = known.shape[-1]
    key = np.where(known, dist / diag, 2.0 + phase)
    key[..., np.eye(n, dtype=bool)] = np.inf
    return np.argsort(key, axis=-1, kind="stable")[..., : n - 1]
