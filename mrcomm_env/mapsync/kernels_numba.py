"""MapSync's compiled kernels (numba), the only implementation of its hot loops: Protocol 1's inner loop
(:func:`inner_products`), :func:`philox.stream_words` for the sketch's parity strings, Algorithm 1 (:func:`bisection`,
``protocol.bisection``) and the streaming PinSketch (:func:`sketch`, integer arithmetic only, ``protocol.sketch``).

A numpy inner product spends its time in a few dozen small array operations per call (one call per round of
Algorithm 1); the kernel computes the same parities in one call: for every segment and index, the words of ``r_i``
restricted to the segment (from the materialised database, or Philox4x32-10 on demand exactly as
:func:`philox.stream_words`), ANDed with each robot's map, popcount, parity. ``tests/mapsync/test_mapsync.py``
compares every kernel with its numpy oracle in ``tests/helpers/mapsync_reference.py``, bit for bit.

The env's other hot loops are here too, and only here (the walk and sensing, the changing world, the
disagreement, the observation), and the copy-axis world of ``copy_axis.py`` steps M copies through
:func:`open_syncs`, :func:`settle_syncs` and :func:`advance_copies`, which run those kernels and the protocols' on
every copy's rows.
"""

from __future__ import annotations

import numba
import numpy as np

from mrcomm_env.core.backend import configure_numba_cache
from mrcomm_env.core.pcg64_numba import draw_integers, integers_fill, random_fill
from mrcomm_env.core.sums_numba import numpy_sum

# the sync kinds of ``settle_syncs`` are the actions that ask for them (numba reads them as constants)
from mrcomm_env.mapsync.actions import BISECTION, EQUALITY, FULL

configure_numba_cache()  # before the @njit(cache=True) below: never cache into the package

_M0 = np.uint64(0xD2511F53)
_M1 = np.uint64(0xCD9E8D57)
_W0 = np.uint64(0x9E3779B9)
_W1 = np.uint64(0xBB67AE85)
_LOW = np.uint64(0xFFFFFFFF)
# protocol._FROM_BIT and protocol._TO_BIT (frozen into the compiled code as constants)
_FROM_BIT = np.array([(0xFFFFFFFF << b) & 0xFFFFFFFF for b in range(32)], dtype=np.uint32)  # bits ≥ b
_TO_BIT = np.array([0xFFFFFFFF >> (31 - b) for b in range(32)], dtype=np.uint32)  # bits ≤ b
_SHIFT = np.uint64(32)


@numba.njit(cache=True, inline="always")
def _popcount32(v):
    v = v - ((v >> np.uint64(1)) & np.uint64(0x55555555))
    v = (v & np.uint64(0x33333333)) + ((v >> np.uint64(2)) & np.uint64(0x33333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F)
    return ((v * np.uint64(0x01010101)) & _LOW) >> np.uint64(24)


@numba.njit(cache=True, inline="always")
def _philox_block(block, index, domain, k0, k1):
    """The four words of Philox4x32-10 at counter (block, index, domain, 0), key (k0, k1)."""
    c0, c1, c2, c3 = np.uint64(block), np.uint64(index), np.uint64(domain), np.uint64(0)
    a, b = np.uint64(k0), np.uint64(k1)
    for _ in range(10):
        p0 = _M0 * c0
        p1 = _M1 * c2
        c0, c1, c2, c3 = (p1 >> _SHIFT) ^ c1 ^ a, p1 & _LOW, (p0 >> _SHIFT) ^ c3 ^ b, p0 & _LOW
        a = (a + _W0) & _LOW
        b = (b + _W1) & _LOW
    return c0, c1, c2, c3


@numba.njit(cache=True)
def _philox_lane(block, index, domain, k0, k1, lane):
    """Word ``lane`` of Philox4x32-10 at counter (block, index, domain, 0), key (k0, k1)."""
    c0, c1, c2, c3 = _philox_block(block, index, domain, k0, k1)
    if lane == 0:
        return c0
    if lane == 1:
        return c1
    if lane == 2:
        return c2
    return c3


@numba.njit(cache=True, inline="always")
def _string_word(database, use_database, i, w, domain, k0, k1, words_per_string, last_mask):
    """Word ``w`` of Protocol 1's shared string r_i (uint64): from the materialised database, or Philox4x32-10 on
    demand with the string's last word masked to the map (as :func:`philox.stream_words` and the database hold it)."""
    if use_database:
        return np.uint64(database[i, w])
    r = _philox_lane(w >> 2, i, domain, k0, k1, w & 3)
    if w == words_per_string - 1:
        r &= np.uint64(last_mask)
    return r


@numba.njit(cache=True)
def stream_words(k0, k1, index, first_word, n_words, domain):
    """:func:`philox.stream_words`: words ``first_word[s] … first_word[s] + n_words − 1`` of stream ``index[s]``,
    ``(S, n_words)`` uint32, one Philox4x32-10 block per four words as the reference computes them."""
    out = np.empty((len(index), n_words), dtype=np.uint32)
    for s in range(len(index)):
        w = 0
        while w < n_words:
            word = first_word[s] + w
            lanes = _philox_block(word >> 2, index[s], domain, k0, k1)
            for lane in range(word & 3, 4):  # the rest of this block's words
                if w == n_words:
                    break
                out[s, w] = np.uint32(lanes[lane])
                w += 1
    return out


@numba.njit(cache=True)
def inner_products(
    maps, database, use_database, k0, k1, domain, words_per_string, last_mask, index, lo, hi, from_bit, to_bit
):
    """Parities ``(M, S, k)``: ``maps[m][lo_s..hi_s] · r_{index[s, j]}[lo_s..hi_s] mod 2``."""
    n_maps = maps.shape[0]
    n_seg, k = index.shape
    out = np.zeros((n_maps, n_seg, k), dtype=np.uint8)
    acc = np.zeros(n_maps, dtype=np.uint64)
    for s in range(n_seg):
        first = lo[s] >> 5
        last = hi[s] >> 5
        for j in range(k):
            i = index[s, j]
            acc[:] = 0
            for w in range(first, last + 1):
                r = _string_word(database, use_database, i, w, domain, k0, k1, words_per_string, last_mask)
                mask = _LOW
                if w == first:
                    mask &= np.uint64(from_bit[lo[s] & 31])
                if w == last:
                    mask &= np.uint64(to_bit[hi[s] & 31])
                r &= mask
                for m in range(n_maps):
                    acc[m] += _popcount32(np.uint64(maps[m, w]) & r)
            for m in range(n_maps):
                out[m, s, j] = np.uint8(acc[m] & np.uint64(1))
    return out


@numba.njit(cache=True)
def bisection(
    x,
    y,
    database,
    use_database,
    k0,
    k1,
    domain,
    words_per_string,
    last_mask,
    source,
    k,
    res,
    p1_bits,
    pick_range,
    as_printed,
):
    """Algorithm 1 as request/response rounds, every round in one call (``protocol.bisection``; its numpy rounds are
    ``reference_bisection`` in ``tests/helpers/mapsync_reference.py``). Alice's picks of i are drawn round by round,
    ``integers(0, pick_range, (segments, k))``, from ``source``: a copy's PCG64 state or a ``numpy.random.Generator``
    (:func:`~mrcomm_env.core.pcg64_numba.draw_integers`). ``as_printed``: step 4 as printed, under which every test
    says "different" (its inner products are then not computed: they decide nothing, while the picks are drawn).

    Returns ``(found, stats, messages)``: the sorted cells Bob found; ``stats`` = (alice bits, bob bits, rounds,
    Protocol 1 calls, cells compared bit by bit, detected, tests that missed a difference, picks used);
    ``messages[r]`` = (Alice's, Bob's) bits in round r, Bob's −1 when he sent nothing.
    """
    n = x.size
    differs = np.zeros(n + 1, np.int64)  # prefix counts of differing cells
    maps = np.zeros((2, words_per_string), np.uint32)  # both maps packed as protocol.pack packs them
    for c in range(n):
        differs[c + 1] = differs[c] + (1 if x[c] != y[c] else 0)
        if x[c]:
            maps[0, c >> 5] |= np.uint32(1) << np.uint32(c & 31)
        if y[c]:
            maps[1, c >> 5] |= np.uint32(1) << np.uint32(c & 31)
    found = np.empty(differs[n], np.int64)
    n_found = 0
    messages = np.full((72, 2), -1, np.int64)  # rounds ≤ recursion depth + 1 ≤ 65 for n < 2^64
    stats = np.zeros(8, np.int64)
    lo = np.zeros(1, np.int64)
    hi = np.full(1, n - 1, np.int64)
    alice = bob = rounds = tests = compared = missed = used = 0
    detected = -1
    while lo.size > 0:
        alice_before = alice
        bob_before = bob
        n_inner = 0
        for s in range(lo.size):
            length = hi[s] - lo[s] + 1
            if length <= res:  # lines 2–6, EQUALLINEAR: Alice sends her bits of the segment, Bob compares
                compared += length
                alice += length
                if differs[hi[s] + 1] - differs[lo[s]] > 0:
                    for c in range(lo[s], hi[s] + 1):
                        if x[c] != y[c]:
                            found[n_found] = c
                            n_found += 1
            else:
                n_inner += 1
        if detected < 0 and n_inner < lo.size:
            detected = 1 if n_found > 0 else 0
        if n_inner == 0:
            messages[rounds, 0] = alice - alice_before
            rounds += 1
            break
        inner_lo = np.empty(n_inner, np.int64)
        inner_hi = np.empty(n_inner, np.int64)
        j = 0
        for s in range(lo.size):
            if hi[s] - lo[s] + 1 > res:
                inner_lo[j] = lo[s]
                inner_hi[j] = hi[s]
                j += 1
        index = np.empty((n_inner, k), np.int64)
        draw_integers(source, 0, pick_range, index.reshape(-1))  # step 3a, segment by segment
        used += n_inner * k
        tests += n_inner
        alice += n_inner * p1_bits
        bob += n_inner  # Bob's verdicts
        if as_printed:  # step 4 as printed ("≥ 0"): every test says "different"
            different = np.ones(n_inner, np.bool_)
            n_different = n_inner
        else:
            parity = inner_products(
                maps,
                database,
                use_database,
                k0,
                k1,
                domain,
                words_per_string,
                last_mask,
                index,
                inner_lo,
                inner_hi,
                _FROM_BIT,
                _TO_BIT,
            )
            n_different = 0
            different = np.zeros(n_inner, np.bool_)
            for s in range(n_inner):
                for r in range(k):
                    if parity[0, s, r] != parity[1, s, r]:  # step 4 (fixed): any differing round means different
                        different[s] = True
                        break
                if different[s]:
                    n_different += 1
                elif differs[inner_hi[s] + 1] - differs[inner_lo[s]] > 0:
                    missed += 1
        if detected < 0:
            detected = 1 if different[0] else 0
        messages[rounds, 0] = alice - alice_before
        messages[rounds, 1] = bob - bob_before
        rounds += 1
        lo = np.empty(2 * n_different, np.int64)  # line 1 and lines 10–11: both halves, in order of position
        hi = np.empty(2 * n_different, np.int64)
        j = 0
        for s in range(n_inner):
            if different[s]:
                mid = (inner_lo[s] + inner_hi[s]) // 2
                lo[j], hi[j] = inner_lo[s], mid
                lo[j + 1], hi[j + 1] = mid + 1, inner_hi[s]
                j += 2
    stats[0], stats[1], stats[2], stats[3] = alice, bob, rounds, tests
    stats[4], stats[5], stats[6], stats[7] = compared, detected, missed, used
    return np.sort(found[:n_found]), stats, messages[:rounds]


@numba.njit(cache=True)
def walk_and_sense(walk, keys, pos, neighbours, truth, sensed, distinct, maps, stamps, known, new_cells, stamp):
    """The walk (when ``walk``) followed by the sensing, robot by robot (``WorldDynamics._move_and_sense``; numpy
    oracles: ``random_walk`` and ``reference_sense`` of ``tests/helpers/mapsync_reference.py``).

    ``keys`` are the walk's uniform keys (``rng.random((N, 4))``, drawn by the caller as the oracle draws
    them). Updates ``maps``, ``stamps``, ``known`` and ``new_cells`` in place and returns ``(positions, flags)``:
    flag 1 = a robot observed a cell for the first time, 2 = a robot's sensing changed a bit of its map.
    """
    n_robots = pos.size
    out = pos.copy()
    if walk:
        for i in range(n_robots):
            here = pos[i]
            best, best_key = here, -1.0
            for d in range(4):
                cell = neighbours[here, d]
                if cell >= 0 and keys[i, d] > best_key and not truth[cell]:
                    best, best_key = cell, keys[i, d]
            out[i] = best
    flags = 0
    width = sensed.shape[1]
    for i in range(n_robots):
        here = out[i]
        unseen = 0
        changed = 0
        for c in range(width):  # off-grid entries repeat the own cell and are not distinct: skipped
            if distinct[here, c]:
                cell = sensed[here, c]
                if stamps[i, cell] < 0:
                    unseen += 1
                if maps[i, cell] != truth[cell]:
                    changed += 1
        for c in range(width):
            if distinct[here, c]:
                cell = sensed[here, c]
                maps[i, cell] = truth[cell]
                stamps[i, cell] = stamp
        if unseen:
            flags |= 1
            known[i] += unseen
        if changed:  # new since the last sync with every peer
            flags |= 2
            for j in range(n_robots):
                if j != i:
                    new_cells[i, j] += changed
    return out, flags


@numba.njit(cache=True, inline="always")
def _popcount64(v):
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (v * np.uint64(0x0101010101010101)) >> np.uint64(56)


@numba.njit(cache=True)
def change_world(truth, pos, draws, appear_rate, vanish_rate):
    """``WorldDynamics._change_world`` after its draws: ``draws`` holds the appearance keys of every cell, then the
    vanishing keys (``rng.random(2n)``, the numpy oracle's two ``rng.random(n)`` in one call: one stream).
    A free cell no robot occupies becomes an obstacle when its key is below ``appear_rate``; an obstacle vanishes
    when its key is below ``vanish_rate``. Both read the world as it was (a cell cannot do both). Updates
    ``truth`` in place and returns whether any cell changed."""
    n = truth.size
    occupied = np.zeros(n, dtype=np.bool_)
    for i in range(pos.size):
        occupied[pos[i]] = True
    changed = False
    for c in range(n):
        if truth[c]:
            if draws[n + c] < vanish_rate:
                truth[c] = False
                changed = True
        elif not occupied[c] and draws[c] < appear_rate:
            truth[c] = True
            changed = True
    return changed


@numba.njit(cache=True)
def disagreement(maps, truth, pair_rows, pair_cols):
    """``WorldDynamics._update_disagreement``: ``(column, mean, errors, error_mean)``.

    The reference's Hamming distances ``(|x| + |y| − 2 x·y) / n`` are whole numbers of cells before the division
    (float64 holds them exactly), so counting the differing cells gives the same quotients; its sums (each row of
    the (N, N) distances, the N(N − 1)/2 pairs ``pair_rows``, ``pair_cols`` in ``np.triu_indices`` order, the N
    errors) are numpy's pairwise sums (:func:`numpy_sum`) over the same values in the same order. A small team's
    cells are compared one by one (loops the compiler vectorises); a larger team's maps are packed into 64-bit words
    first: its N(N − 1)/2 pairs then cost n/64 popcounts each."""
    n_robots, n = maps.shape
    if n_robots <= _COMPARED_CELL_BY_CELL:
        ham = np.zeros((n_robots, n_robots))
        errors = np.empty(n_robots)
        for i in range(n_robots):
            wrong = 0
            for c in range(n):
                wrong += maps[i, c] != truth[c]
            errors[i] = wrong / n
            for j in range(i + 1, n_robots):
                differ = 0
                for c in range(n):
                    differ += maps[i, c] != maps[j, c]
                ham[i, j] = ham[j, i] = differ / n
        return _disagreement_sums(ham, errors, pair_rows, pair_cols)
    n_words = (n + 63) // 64
    words = np.zeros((n_robots, n_words), dtype=np.uint64)
    truth_words = np.zeros(n_words, dtype=np.uint64)
    for c in range(n):
        bit = np.uint64(1) << np.uint64(c % 64)
        if truth[c]:
            truth_words[c // 64] |= bit
        for i in range(n_robots):
            if maps[i, c]:
                words[i, c // 64] |= bit
    ham = np.zeros((n_robots, n_robots))
    errors = np.empty(n_robots)
    for i in range(n_robots):
        wrong = 0
        for w in range(n_words):
            wrong += np.int64(_popcount64(words[i, w] ^ truth_words[w]))  # int64 + uint64 would be float64
        errors[i] = wrong / n
        for j in range(i + 1, n_robots):
            differ = 0
            for w in range(n_words):
                differ += np.int64(_popcount64(words[i, w] ^ words[j, w]))
            ham[i, j] = ham[j, i] = differ / n
    return _disagreement_sums(ham, errors, pair_rows, pair_cols)


#: teams up to this size compare their maps cell by cell in :func:`disagreement` (larger ones pack them first)
_COMPARED_CELL_BY_CELL = 8


@numba.njit(cache=True)
def _disagreement_sums(ham, errors, pair_rows, pair_cols):
    """:func:`disagreement`'s sums of the (N, N) Hamming distances ``ham`` and the N ``errors``, numpy's own."""
    n_robots = errors.size
    flat = ham.ravel()
    column = np.empty(n_robots)
    for i in range(n_robots):
        column[i] = numpy_sum(flat, i * n_robots, n_robots) / (n_robots - 1)
    picked = np.empty(pair_rows.size)
    for p in range(pair_rows.size):
        picked[p] = ham[pair_rows[p], pair_cols[p]]
    mean = numpy_sum(picked, 0, picked.size) / picked.size
    error_mean = numpy_sum(errors, 0, n_robots) / n_robots
    return column, mean, errors, error_mean


@numba.njit(cache=True)
def observe(out, t, clock, last_sync, new_cells, linked, last_test, session_of, progress, recent, known, n):
    """``MapSyncEnv._observe``, every column computed: writes the (N, 4(N−1) + 5) float32 ``out``.

    Per peer j = i+1, i+2, … (mod N): s/(s+10) for the steps s since the last sync,
    c/(c+10) for the new cells c, the link, the last verdict (none 0, different 1, same ½); then the robot's
    recent bits b/(b+n), coverage, busy, session progress and the clock. Every value is computed in float64 as
    the reference computes it and rounded to float32 on the store, as numpy's assignment rounds it.
    """
    n_robots = out.shape[0]
    own = 4 * (n_robots - 1)
    for i in range(n_robots):
        for o in range(1, n_robots):
            j = (i + o) % n_robots
            col = 4 * (o - 1)
            s = t - last_sync[i, j]
            out[i, col] = s / (s + 10.0)
            c = new_cells[i, j]
            out[i, col + 1] = c / (c + 10.0)
            out[i, col + 2] = 1.0 if linked[i, j] else 0.0
            verdict = last_test[i, j]  # −1 none, 0 different, 1 same
            out[i, col + 3] = 0.0 if verdict < 0 else (1.0 if verdict == 0 else 0.5)
        b = recent[i]
        out[i, own] = b / (b + n)
        out[i, own + 1] = known[i] / n
        out[i, own + 2] = 1.0 if session_of[i] >= 0 else 0.0
        out[i, own + 3] = progress[i]
        out[i, own + 4] = clock


@numba.njit(cache=True, inline="always")
def _gf_mul(a, b, exp, log):
    """a·b in GF(2^m) on ``pinsketch.GF2m``'s tables: 0 with a 0 factor, else exp[log a + log b]."""
    if a == 0 or b == 0:
        return 0
    return exp[log[a] + log[b]]


@numba.njit(cache=True)
def _parities_agree(diff, rho, n_words):
    """Whether a guess whose XOR with Alice's map is ``diff`` (packed) has her parities with every string of ``rho``:
    parity(x·r) = parity(g·r) ⟺ parity((x ⊕ g)·r) = 0."""
    for j in range(rho.shape[0]):
        acc = np.uint64(0)
        for w in range(n_words):
            acc += _popcount32(np.uint64(diff[w]) & np.uint64(rho[j, w]))
        if acc & np.uint64(1):
            return False
    return True


@numba.njit(cache=True)
def sketch(x, y, k0, k1, nonce, verify_bits, domain, exp, log, m, strict_feedback):
    """``protocol.sketch`` after its equal-maps check (``x[1:] ≠ y[1:]``): ``(found, stats)`` with ``stats`` = (Alice's
    bits, Bob's bits, rounds, syndromes sent, outcome), outcome 0 when Bob's map with Alice's cell 0 passed her
    parities, 1 when a decoded difference did, 2 when Alice fell back to her whole map.

    Integer arithmetic only, step for step the oracle's (``reference_sketch`` in ``tests/helpers/mapsync_reference.py``):
    the session's public-coin parity strings (:func:`stream_words`), Bob's guesses checked against Alice's parities, the odd syndromes of the two cell sets
    (cells 1 … n−1; their XOR is the symmetric difference's, as ``syndromes(A) ^ syndromes(B)``), Berlekamp–Massey
    on zero-padded arrays where the reference grows lists (the padding only ever multiplies into 0), and the Chien
    search by Horner's rule over cells 1 … n−1 (``StreamingDecoder.decode``)."""
    n = x.size
    order = (1 << m) - 1
    n_words = (n + 31) // 32
    index = np.empty(verify_bits, dtype=np.uint64)
    for j in range(verify_bits):
        index[j] = np.uint64((nonce * verify_bits + j) % (1 << 32))
    rho = stream_words(k0, k1, index, np.zeros(verify_bits, np.int64), n_words, domain)
    if n % 32:
        last = np.uint32((1 << (n % 32)) - 1)
        for j in range(verify_bits):
            rho[j, n_words - 1] &= last
    diff = np.zeros(n_words, dtype=np.uint32)  # x ⊕ y packed as protocol.pack packs a map
    n_diff = 0
    for c in range(n):
        if x[c] != y[c]:
            diff[c >> 5] |= np.uint32(1) << np.uint32(c & 31)
            n_diff += 1
    base = 1 if x[0] != y[0] else 0
    first_guess = diff.copy()  # x ⊕ (Bob's map with Alice's cell 0)
    if base:
        first_guess[0] ^= np.uint32(1)
    stats = np.zeros(5, dtype=np.int64)
    alice = verify_bits + 1
    if _parities_agree(first_guess, rho, n_words):
        stats[0], stats[1], stats[2] = alice, 1, 1
        found = np.zeros(base, dtype=np.int64)
        return found, stats
    symmetric = np.empty(n_diff, dtype=np.int64)  # cells ≥ 1 in exactly one of the two sets
    n_sym = 0
    for c in range(1, n):
        if x[c] != y[c]:
            symmetric[n_sym] = c
            n_sym += 1
    t_max = max(0, (n - alice - 1) // m)
    cap = 4 * t_max + 8
    S = np.zeros(cap, dtype=np.int64)  # S_1, S_2, … (index 0 holds S_1)
    C = np.zeros(cap, dtype=np.int64)  # the reference's lists C and B, zero beyond their lengths
    B = np.zeros(cap, dtype=np.int64)
    update = np.zeros(cap, dtype=np.int64)
    C[0] = B[0] = 1
    len_c = len_b = 1
    L, shift, b, n_s = 0, 1, 1, 0
    bob, rounds, t = 0, 1, 0
    while t < t_max:
        e = 2 * t + 1  # the next odd syndrome of the difference: ⊕ over its cells of cell^e
        s = 0
        for i in range(n_sym):
            s ^= exp[(log[symmetric[i]] * e) % order]
        t += 1
        rounds += 1
        alice += m
        if strict_feedback:
            bob += 1
        for feed in range(2):  # S_{2t−1}, then S_{2t} = S_t² (StreamingDecoder.add)
            if feed == 1:
                a = S[t - 1]
                s = 0 if a == 0 else exp[(2 * log[a]) % order]
            S[n_s] = s
            r = n_s
            n_s += 1
            d = s
            for i in range(1, L + 1):
                d ^= _gf_mul(C[i], S[r - i], exp, log)
            if d == 0:
                shift += 1
                continue
            coef = exp[(log[d] - log[b]) % order]  # d / b (b ≠ 0: the last nonzero discrepancy)
            len_new = max(len_c, shift + len_b)  # C ⊕ z^shift · coef · B, with B as it was
            if len_new > cap:  # cannot happen (a locator of n_s syndromes has at most n_s + 1 terms)
                raise ValueError("sketch: Berlekamp-Massey locator longer than its buffer")
            span = len_b
            for i in range(span):
                update[i] = _gf_mul(coef, B[i], exp, log)
            if 2 * L <= r:  # B takes the old C (an older C is never longer: B's entries are all overwritten)
                B[:len_c] = C[:len_c]
                len_b = len_c
                b = d
                L = r + 1 - L
                shift_next = 1
            else:
                shift_next = shift + 1
            for i in range(span):
                C[i + shift] ^= update[i]
            len_c = len_new
            shift = shift_next
        if L > t:
            continue
        # decode: the roots x of Λ(x⁻¹) among cells 1 … n−1, exactly L of them, or none found
        if L == 0 or C[L] == 0:  # L = 0 guesses Bob's map with Alice's cell 0 again, which her parities refused
            continue
        if L == 1:
            if not 1 <= C[1] <= n - 1:
                continue
            roots = C[1:2].copy()
        else:
            roots = np.empty(L, dtype=np.int64)
            n_roots = 0
            for cell in range(1, n):
                v = C[0]
                for i in range(1, L + 1):
                    v = _gf_mul(v, cell, exp, log) ^ C[i]
                if v == 0:
                    if n_roots == L:
                        n_roots += 1
                        break
                    roots[n_roots] = cell
                    n_roots += 1
            if n_roots != L:
                continue
        guess = first_guess.copy()  # and the decoded cells flipped
        for i in range(roots.size):
            guess[roots[i] >> 5] ^= np.uint32(1) << np.uint32(roots[i] & 31)
        if _parities_agree(guess, rho, n_words):
            if not strict_feedback:
                bob += 1
            found = np.empty(base + roots.size, dtype=np.int64)
            if base:
                found[0] = 0
            found[base:] = roots
            stats[0], stats[1], stats[2], stats[3], stats[4] = alice, bob, rounds, t, 1
            return found, stats
    alice += n  # no decode within the useful length: Alice sends her map
    found = np.empty(n_diff, dtype=np.int64)
    j = 0
    for c in range(n):
        if x[c] != y[c]:
            found[j] = c
            j += 1
    stats[0], stats[1], stats[2], stats[3], stats[4] = alice, bob, rounds + 1, t, 2
    return found, stats


@numba.njit(cache=True)
def equality_counter(x, y, database, use_database, k0, k1, domain, words_per_string, last_mask, picks):
    """Protocol 1 on whole maps ``x`` and ``y`` (bool, n cells) with Alice's ``picks`` of i: Bob's counter, the rounds
    whose inner products differ (Protocol 1 on the one segment 0 … n−1). x·r ≠ y·r (mod 2) ⟺
    (x ⊕ y)·r = 1 (mod 2), so one packed XOR of the maps is tested against each r_i, as :func:`inner_products`
    forms r_i (from the database, or Philox on demand, masked to the map)."""
    n = x.size
    n_words = (n + 31) >> 5
    diff = np.zeros(n_words, dtype=np.uint32)
    for c in range(n):
        if x[c] != y[c]:
            diff[c >> 5] |= np.uint32(1) << np.uint32(c & 31)
    top = np.uint64(_TO_BIT[(n - 1) & 31])
    counter = 0
    for j in range(picks.size):
        i = picks[j]
        acc = np.uint64(0)
        for w in range(n_words):
            r = _string_word(database, use_database, i, w, domain, k0, k1, words_per_string, last_mask)
            if w == n_words - 1:
                r &= top
            acc += _popcount32(np.uint64(diff[w]) & r)
        counter += int(acc & np.uint64(1))
    return counter


# columns of ``settle_syncs``'s counts: the env's ``_counts`` (in its order), then its merge and latency counters
SYNCS, FALSE_EQUAL, EQUALITY_TESTS, DETECTIONS, ABORTED, CORRECTED, TO_CORRECT, LATENCY_SUM, LATENCY_COUNT = range(9)
N_COUNTS = 9


@numba.njit(cache=True)
def _settle_sync(
    m, a, b, kind, equal, found, maps, stamps, known, last_sync, new_cells, last_test, counts, dirty, lww, t
):
    """``SyncSessions._finish`` of one sync of copy ``m`` that opened and completes at step ``t`` (its verdict, its
    merge, its counts). The merge reads what each robot sent as its map and stamps now: both robots' rows are
    as the protocol found them, since a robot is in one sync at a time and no merge of another touches them."""
    counts[m, SYNCS] += 1
    counts[m, LATENCY_SUM] += 1  # t − t + 1: the sync ended in the step it began
    counts[m, LATENCY_COUNT] += 1
    x, y = maps[m, a], maps[m, b]
    differ = 0
    for c in range(x.size):
        if x[c] != y[c]:
            differ += 1
    synced = True
    if kind == EQUALITY or kind == BISECTION:  # SyncSessions._verdict: Protocol 1's answer, both ends learn it
        counts[m, EQUALITY_TESTS] += 1
        if equal and differ > 0:
            counts[m, FALSE_EQUAL] += 1
        if not equal:
            counts[m, DETECTIONS] += 1
        last_test[m, a, b] = last_test[m, b, a] = 1 if equal else 0  # TEST_SAME, TEST_DIFFERENT
        if kind == EQUALITY:
            synced = equal
    if kind != EQUALITY:
        size = found.size
        right = 0
        if size:  # SyncSessions._merge: last-writer-wins (OR when nothing vanishes), Alice's row first
            xs, ys = np.empty(size, dtype=np.bool_), np.empty(size, dtype=np.bool_)
            sa, sb = np.empty(size, dtype=np.int64), np.empty(size, dtype=np.int64)
            for q in range(size):
                cell = found[q]
                xs[q], ys[q] = x[cell], y[cell]
                sa[q], sb[q] = stamps[m, a, cell], stamps[m, b, cell]
                if xs[q] != ys[q]:
                    right += 1
            for side in range(2):
                me = a if side == 0 else b
                mine, other = (xs, sb) if side == 0 else (ys, sa)
                for q in range(size):
                    cell = found[q]
                    other_bit = not mine[q]  # each believes the other holds the opposite bit
                    if lww:
                        adopt = other[q] > stamps[m, me, cell]
                    else:
                        adopt = other_bit and not maps[m, me, cell]
                    if adopt:
                        if stamps[m, me, cell] < 0:
                            known[m, me] += 1
                        maps[m, me, cell] = other_bit
                        if other[q] > stamps[m, me, cell]:
                            stamps[m, me, cell] = other[q]
            dirty[m] = True
        counts[m, TO_CORRECT] += differ
        counts[m, CORRECTED] += right
    if synced:
        last_sync[m, a, b] = last_sync[m, b, a] = t + 1
        new_cells[m, a, b] = new_cells[m, b, a] = 0


@numba.njit(cache=True)
def open_syncs(
    actions, n_actions, peer_order, last_sync, next_session, sync_copy, sync_a, sync_b, sync_kind, sync_nonce
):
    """``SyncSessions._sync_within_step``'s openings of M copies whose links are always up: robot by robot, one that
    asks for a sync (action ≠ 0) and is not yet in one opens it with the free peer it synced with least recently (the
    first in ``peer_order`` on ties, ``choose_peer``), whose own request it serves; each takes the copy's next
    session number (``next_session``, the sketch's nonce). Writes the syncs in the order they open and returns how
    many; −1 − (flat index of the first action outside [0, ``n_actions``)) before opening any, when there is one."""
    n_copies, n_robots = actions.shape
    for m in range(n_copies):
        for i in range(n_robots):
            if actions[m, i] < 0 or actions[m, i] >= n_actions:
                return -1 - (m * n_robots + i)
    busy = np.empty(n_robots, np.int64)
    count = 0
    for m in range(n_copies):
        busy[:] = -1
        for i in range(n_robots):
            if actions[m, i] == 0 or busy[i] >= 0:
                continue
            best, best_age = -1, -(2**62)
            for o in range(n_robots - 1):
                j = peer_order[i, o]
                if busy[j] < 0 and -last_sync[m, i, j] > best_age:
                    best, best_age = j, -last_sync[m, i, j]
            if best < 0:
                continue
            nonce = next_session[m]
            next_session[m] = nonce + 1
            busy[i] = busy[best] = nonce
            sync_copy[count], sync_a[count], sync_b[count] = m, i, best
            sync_kind[count], sync_nonce[count] = actions[m, i], nonce
            count += 1
    return count


@numba.njit(cache=True)
def _protocol(kind, x, y, state, pick_range, protocol1, nonce, sketch_key, sketch_consts, exp, log, return_table):
    """``SyncSessions._transcript`` of one sync, with the copy's PCG64 ``state`` drawing what the protocol draws:
    ``(found, equal, sent, candidates)``, ``equal`` Protocol 1's answer (equality, or Algorithm 1's first test),
    ``sent`` = (Alice's bits, her messages, Bob's bits, his messages) of the transcript's non-empty messages but the
    found cells' stamps. Bob's way back is in ``sent`` but for Algorithm 1, whose candidates (the cells it compared,
    returned; −1 for the others) vary: ⌈log2 C(C, d)⌉ needs big integers, so the caller adds it
    (``protocol.return_bits``); for the others it is ``return_table[d]`` (C = n). ``protocol1`` = (database,
    use_database, key0, key1, domain, words_per_string, last_mask, Protocol 1's bits, k, res); ``sketch_consts`` =
    (verify_bits, domain, m)."""
    n = x.size
    database, use_database, key0, key1, domain, words, last_mask, p1_bits, k, res = protocol1
    sent = np.zeros(4, dtype=np.int64)
    if kind == EQUALITY:  # protocol.equality: its equal-maps shortcut gives the counter the kernel gives them, 0
        picks = np.empty(k, dtype=np.int64)
        integers_fill(state, 0, pick_range, picks)  # Alice's picks (protocol._alice_picks)
        counter = equality_counter(x, y, database, use_database, key0, key1, domain, words, last_mask, picks)
        sent[0], sent[1], sent[2], sent[3] = p1_bits, 1, 1, 1  # Proposition 1's bits, then the verdict bit
        return np.zeros(0, dtype=np.int64), counter == 0, sent, -1
    candidates, back, equal = n, np.int64(0), False
    if kind == BISECTION:  # protocol.bisection with step 4 fixed (its equal-maps shortcut computes the same)
        found, stats, rounds = bisection(
            x,
            y,
            database,
            use_database,
            key0,
            key1,
            domain,
            words,
            last_mask,
            state,
            k,
            res,
            p1_bits,
            pick_range,
            False,
        )
        for r in range(rounds.shape[0]):
            if rounds[r, 0] > 0:
                sent[0] += rounds[r, 0]
                sent[1] += 1
            if rounds[r, 1] > 0:
                sent[2] += rounds[r, 1]
                sent[3] += 1
        equal, candidates = stats[5] == 0, stats[4]
    else:
        if kind == FULL:  # protocol.full
            found = np.nonzero(x != y)[0].astype(np.int64)
            alice, bob = n, 0
        else:  # protocol.sketch
            verify_bits, sketch_domain, m = sketch_consts
            same_rest = True
            for c in range(1, n):
                if x[c] != y[c]:
                    same_rest = False
                    break
            if same_rest:  # Bob's map with Alice's cell 0 is her map: it passes her parities
                found = np.zeros(1 if x[0] != y[0] else 0, dtype=np.int64)
                alice, bob = verify_bits + 1, 1
            else:
                found, stats = sketch(
                    x, y, sketch_key[0], sketch_key[1], nonce, verify_bits, sketch_domain, exp, log, m, False
                )
                alice, bob = stats[0], stats[1]
        back = return_table[found.size]
        for bits, side in ((alice, 0), (bob, 2), (back, 2)):
            if bits > 0:
                sent[side] += bits
                sent[side + 1] += 1
        candidates = -1
    return found, equal, sent, candidates


@numba.njit(cache=True)
def settle_syncs(
    sync_copy,
    sync_a,
    sync_b,
    sync_kind,
    sync_nonce,
    sync_equal,
    sync_candidates,
    sync_found,
    rng_state,
    pick_range,
    protocol1,
    sketch_keys,
    sketch_consts,
    exp,
    log,
    return_table,
    stamp_bits,
    lww,
    maps,
    stamps,
    known,
    last_sync,
    new_cells,
    last_test,
    robot_syncs,
    step_bits,
    total_bits,
    messages,
    counts,
    dirty,
    charged,
    step_count,
):
    """``SyncSessions._sync_within_step`` of M copies after their syncs opened (:func:`open_syncs`): each sync, in
    the order they opened, runs its protocol (:func:`_protocol`, its draws from its copy's generator state
    ``rng_state[m]``, :mod:`~mrcomm_env.core.pcg64_numba`), charges its transcript to its senders and finishes
    (:func:`_settle_sync`). Every array with a leading copy axis is the env's state of the same name (``counts``:
    the columns above; ``step_bits``, ``total_bits``, ``messages``: the ledger's, ``charged``: whether a copy's
    robots sent bits this step). Writes each sync's answer ``sync_equal`` (detections are listed by the caller),
    and for Algorithm 1 its candidates and found cells, whose way back the caller charges to Bob
    (``sync_candidates``, ``sync_found``; −1 for the others). Returns how many syncs the caller has to look at (an
    Algorithm 1 sync, or a test that found a difference)."""
    step_bits[:] = 0.0  # BitLedger.begin_step
    charged[:] = False
    for_caller = 0
    for s in range(sync_copy.size):
        m, a, b = sync_copy[s], sync_a[s], sync_b[s]
        # a robot is in one sync at a time: no other sync's merge has touched these rows this step
        cells, sync_equal[s], sent, sync_candidates[s] = _protocol(
            sync_kind[s],
            maps[m, a],
            maps[m, b],
            rng_state[m],
            pick_range,
            protocol1,
            sync_nonce[s],
            sketch_keys[m],
            sketch_consts,
            exp,
            log,
            return_table,
        )
        d = cells.size
        sync_found[s] = d
        if lww and d:  # the found cells' stamps, both ways
            sent[2] += d * stamp_bits
            sent[3] += 1
            sent[0] += d * stamp_bits
            sent[1] += 1
        for side in range(2):  # one ledger entry per sender, of the sum of its messages (whole bits: exact)
            who = a if side == 0 else b
            if sent[2 * side + 1]:
                step_bits[m, who] += sent[2 * side]
                total_bits[m, who] += sent[2 * side]
                messages[m] += sent[2 * side + 1]
                charged[m] = True
        robot_syncs[m, a] += 1
        robot_syncs[m, b] += 1
        _settle_sync(
            m,
            a,
            b,
            sync_kind[s],
            sync_equal[s],
            cells,
            maps,
            stamps,
            known,
            last_sync,
            new_cells,
            last_test,
            counts,
            dirty,
            lww,
            step_count[m],
        )
        if sync_kind[s] == BISECTION or (sync_kind[s] == EQUALITY and not sync_equal[s]):
            for_caller += 1
    return for_caller


@numba.njit(cache=True)
def advance_copies(
    rng_state,
    charged,
    maps,
    stamps,
    truth,
    pos,
    known,
    new_cells,
    last_sync,
    last_test,
    step_bits,
    recent,
    recent_max,
    recent_any,
    dirty,
    column,
    mean,
    errors,
    error_mean,
    sums,
    step_count,
    changing,
    appear_rate,
    vanish_rate,
    neighbours,
    sensed,
    distinct,
    pair_rows,
    pair_cols,
    linked,
    no_sessions,
    no_progress,
    lam,
    bit_scale,
    horizon,
    obs,
    rewards,
):
    """The rest of ``MapSyncEnv._step_world`` and ``_observe`` of M copies after their syncs (:func:`settle_syncs`):
    the changing world and the walk, on the keys each copy draws from its generator state ``rng_state[m]`` in the
    env's order (the world's 2n, when ``changing``, then the walk's N × 4), the sensing, the disagreement, the recent
    bits' average, the reward and the observation. Every array with a leading copy axis is the env's state of the
    same name (``sums``: the summed disagreement and error). Writes the observations ``obs`` and the team rewards
    ``rewards`` (M, N); the same operations in the same order as the env, so the same numbers."""
    n_copies, n_robots, n = maps.shape
    world_draws = np.empty(2 * n)
    keys = np.empty((n_robots, 4))
    for m in range(n_copies):
        t = step_count[m]
        if changing:  # WorldDynamics._change_world
            random_fill(rng_state[m], world_draws)
            if change_world(truth[m], pos[m], world_draws, appear_rate, vanish_rate):
                dirty[m] = True
        random_fill(rng_state[m], keys.reshape(-1))
        moved, flags = walk_and_sense(
            True,
            keys,
            pos[m],
            neighbours,
            truth[m],
            sensed,
            distinct,
            maps[m],
            stamps[m],
            known[m],
            new_cells[m],
            t + 1,
        )
        pos[m] = moved
        if flags & 2:
            dirty[m] = True
        if dirty[m]:  # WorldDynamics._update_disagreement
            dirty[m] = False
            col, mean_m, err, err_mean = disagreement(maps[m], truth[m], pair_rows, pair_cols)
            column[m] = col
            mean[m] = mean_m
            errors[m] = err
            error_mean[m] = err_mean
        team_bits = 0.0
        if charged[m] or recent_any[m]:  # the recent bits' moving average, as MapSyncEnv._step_world keeps it
            for i in range(n_robots):
                recent[m, i] *= 0.9
            if charged[m]:
                for i in range(n_robots):
                    team_bits += step_bits[m, i]  # whole numbers of bits: exact in any summation order
                    recent[m, i] += 0.1 * step_bits[m, i]
                recent_max[m] = recent[m].max()
            else:
                recent_max[m] *= 0.9
            recent_any[m] = recent_max[m] > 1e-6 * n
            if not recent_any[m]:
                recent[m] = 0.0
                recent_max[m] = 0.0
        sums[m, 0] += mean[m]
        sums[m, 1] += error_mean[m]
        rewards[m] = -mean[m] - lam * team_bits / bit_scale  # the team reward, every robot's
        t += 1
        step_count[m] = t
        observe(
            obs[m],
            t,
            min(t / horizon, 1.0),
            last_sync[m],
            new_cells[m],
            linked,
            last_test[m],
            no_sessions,
            no_progress,
            recent[m],
            known[m],
            n,
        )
