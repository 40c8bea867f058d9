"""MapSync's walk, sensing, changing world, disagreement, observation, Protocol 1's inner products, Algorithm 1 and
the streaming PinSketch written in numpy and Python: the oracles of their compiled kernels.

The env computes each in one compiled call (``WorldDynamics._move_and_sense``, ``_change_world``,
``_update_disagreement``, ``MapSyncEnv._observe``, ``kernels_numba.inner_products``, ``protocol.bisection``,
``protocol.sketch``:
``kernels_numba``); these are the same steps (§I, §III, §V-C, the module's observation table, and
``protocol``'s and ``pinsketch``'s docstrings for the sketch: GF(2^m) arithmetic on log tables, odd syndromes,
Berlekamp–Massey, a Chien search), kept here and not in the package (#44: one implementation in the package, the
reference under tests/). ``ReferenceMapSync`` steps whole episodes with them, and ``tests/mapsync/test_mapsync.py``
compares those, and each kernel, with the env's byte for byte."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from mrcomm_env.mapsync import kernels_numba, theory
from mrcomm_env.mapsync.env import MapSyncEnv
from mrcomm_env.mapsync.philox import DOMAIN_PARITY, seed_key, stream_words
from mrcomm_env.mapsync.pinsketch import GF2m, field_bits
from mrcomm_env.mapsync.protocol import (
    _FROM_BIT,
    _TO_BIT,
    Reconciliation,
    check_n,
    kernel_strings,
    pack,
    sketch_verify_bits,
)

#: the observation of last_test + 1: no test yet 0, different 1, same ½
TEST_CODE = np.array([0.0, 1.0, 0.5])


def random_walk(rng: np.random.Generator, pos: np.ndarray, neighbours: np.ndarray, blocked: np.ndarray) -> np.ndarray:
    """One step of every robot to a uniformly drawn free neighbour (stays when boxed in): one uniform key per
    (robot, direction), and the free neighbour with the largest key is taken, a uniform choice among the free ones.
    ``neighbours``: ``world.neighbour_table``."""
    keys = rng.random((pos.size, 4)).tolist()
    out = pos.copy()
    for i, here in enumerate(pos.tolist()):
        best, best_key = here, -1.0
        for cell, key in zip(neighbours[here].tolist(), keys[i]):
            if cell >= 0 and key > best_key and not blocked[cell]:
                best, best_key = cell, key
        out[i] = best
    return out


def reference_sense(env: MapSyncEnv, stamp: int) -> int:
    """Every robot senses its cell and its 4-neighbours (§V-C) into its map, stamps, coverage and new-cell counts, in
    place. Returns the kernel's flags: 1 = a cell observed for the first time, 2 = a bit of a map changed."""
    n_robots, n = env.maps.shape
    cells = env._sensed.take(env.pos, axis=0)  # (N, 5): off-grid neighbours repeat the own cell
    distinct = env._sensed_distinct.take(env.pos, axis=0)
    flat = cells + np.arange(n_robots)[:, None] * n  # into the flattened (N, n) maps and stamps
    seen = env.truth.take(cells)
    maps, stamps = env.maps.reshape(-1), env.stamps.reshape(-1)
    changed = maps.take(flat) != seen
    before = stamps.take(flat)
    flags = 0
    if before.min() < 0:  # a cell never observed before
        env.known += np.count_nonzero((before < 0) & distinct, axis=1)
        flags |= 1
    if changed.any():
        # own sensing changed these cells: new since the last sync with every peer
        env.new_cells += np.count_nonzero(changed & distinct, axis=1)[:, None]
        np.fill_diagonal(env.new_cells, 0)
        maps.put(flat, seen)
        flags |= 2
    stamps.put(flat, stamp)
    return flags


def reference_change_world(env: MapSyncEnv) -> bool:
    """Obstacles appear on free, unoccupied cells and vanish, each cell independently (§I): n appearance keys, then
    n vanishing keys from the env's generator. Returns whether any cell changed."""
    c, rng, truth = env.cfg, env.np_random, env.truth
    occupied = np.zeros(env.n, dtype=bool)
    occupied[env.pos] = True
    appear = (~truth) & (~occupied) & (rng.random(env.n) < c.appear_rate)
    vanish = truth & (rng.random(env.n) < c.vanish_rate)
    truth[appear] = True
    truth[vanish] = False
    return bool(appear.any() or vanish.any())


def reference_disagreement(env: MapSyncEnv) -> tuple[np.ndarray, float, np.ndarray, float]:
    """Each robot's mean Hamming distance to the others, the mean over pairs, each robot's error against the world
    and their mean: ``(column, mean, errors, error_mean)``."""
    maps = env.maps.astype(np.float64)
    ones = maps.sum(axis=1)
    ham = (ones[:, None] + ones[None, :] - 2.0 * (maps @ maps.T)) / env.n
    column = ham.sum(axis=1) / (env.n_agents - 1)
    pairs = ham[env._pairs]
    errors = (env.maps != env.truth).sum(axis=1) / env.n
    return column, float(pairs.sum()) / pairs.size, errors, float(errors.sum()) / env.n_agents


def reference_observation(env: MapSyncEnv) -> np.ndarray:
    """The module's observation table, every column: per peer j = i+1, i+2, … (mod N) the age of the last sync
    s/(s+10), new cells c/(c+10), the link and the last verdict; then recent bits b/(b+n), coverage, busy, the session's
    progress and the clock."""
    N, t = env.n_agents, env.step_count
    peers = env._peer_order
    rows = np.arange(N)[:, None]
    ages = t - env.last_sync[rows, peers]
    new = env.new_cells[rows, peers]
    per_peer = np.stack(
        [ages / (ages + 10.0), new / (new + 10.0), env.linked[rows, peers], TEST_CODE[env.last_test[rows, peers] + 1]],
        axis=-1,
    )
    progress = np.zeros(N)
    for s in env.sessions.values():
        progress[[s.alice, s.bob]] = s.sent / max(s.total, 1)
    own = np.column_stack(
        [
            env.recent_bits / (env.recent_bits + env.n),
            env.known / env.n,
            env.session_of >= 0,
            progress,
            np.full(N, min(t / env._horizon, 1.0)),
        ]
    )
    return np.concatenate([per_peer.reshape(N, -1), own], axis=1).astype(np.float32)


class ReferenceMapSync(MapSyncEnv):
    """MapSync whose walk, sensing, changing world, disagreement and observation are the numpy oracles above."""

    def _change_world(self) -> bool:
        return reference_change_world(self)

    def _move_and_sense(self, stamp: int, walk: bool) -> None:
        if walk:
            self.pos = random_walk(self.np_random, self.pos, self._neighbour_table, self.truth)
        flags = reference_sense(self, stamp)
        if flags & 1:
            self._events += 1
        if flags & 2:
            self._dirty = True
            self._events += 1

    def _update_disagreement(self) -> None:
        if not self._dirty:
            return
        self._dirty = False
        self._map_version += 1
        column, mean, errors, error_mean = reference_disagreement(self)
        self._disagreement_column, self._disagreement_mean = column, mean
        self._errors, self._error_mean = errors, error_mean

    def _observe(self) -> np.ndarray:
        return reference_observation(self)


def reference_inner_products(maps, strings, index, lo, hi) -> list[np.ndarray]:
    """``kernels_numba.inner_products`` in numpy: ``X[lo..hi] · r_i[lo..hi] mod 2`` for every packed map X, every
    segment s and each of its indices ``index[s, :]``, from the strings' words (``SharedStrings.words``)."""
    first, last = lo >> 5, hi >> 5
    span = last - first
    n_words = int(span.max()) + 1
    S, k = index.shape
    stacked = np.stack(maps)  # (M, W)
    if S == 1 and lo[0] == 0 and hi[0] == 32 * stacked.shape[1] - 1:
        seg = stacked[:, None, :]  # the whole map, a whole number of words: nothing to mask
    else:
        cols = first[:, None] + np.arange(n_words)[None, :]
        mask = np.where(cols <= last[:, None], np.uint32(0xFFFFFFFF), np.uint32(0))
        mask[:, 0] &= _FROM_BIT[lo & 31]
        mask[np.arange(S), span] &= _TO_BIT[hi & 31]
        seg = stacked[:, np.minimum(cols, stacked.shape[1] - 1)] & mask  # (M, S, n_words)
    r = strings.words(index.reshape(-1), np.repeat(first, k), n_words).reshape(S, k, n_words)
    counts = np.bitwise_count(r[None, :, :, :] & seg[:, :, None, :]).sum(axis=-1, dtype=np.int64)
    return list((counts & 1).astype(np.uint8))


# ------------------------------------------------------------------------------------------------ Algorithm 1
def segment_inner_products(maps, strings, index, lo, hi) -> list[np.ndarray]:
    """The compiled inner products (``kernels_numba.inner_products``) called as :func:`reference_inner_products` is."""
    lo = np.asarray(lo, dtype=np.int64)
    hi = np.asarray(hi, dtype=np.int64)
    index = np.asarray(index, dtype=np.int64)
    out = kernels_numba.inner_products(np.stack(maps), *kernel_strings(strings), index, lo, hi, _FROM_BIT, _TO_BIT)
    return list(out)


def protocol1_batch(x_words, y_words, strings, k: int, lo, hi, rng: np.random.Generator, step4: str = "fixed"):
    """Protocol 1 on many segments at once in numpy: (verdict "equal" per segment, counter per segment)."""
    lo = np.atleast_1d(np.asarray(lo, dtype=np.int64))
    hi = np.atleast_1d(np.asarray(hi, dtype=np.int64))
    index = rng.integers(0, strings.size, size=(lo.size, k))  # step 3a
    b, b_bob = reference_inner_products([x_words, y_words], strings, index, lo, hi)  # steps 3b (Alice), 3d (Bob)
    counter = (b != b_bob).sum(axis=1)  # step 3e
    # step 4: "greater than zero" means different; as printed ("≥ 0") it can never answer "same"
    equal = counter == 0 if step4 == "fixed" else np.zeros(lo.size, dtype=bool)
    return equal, counter


def reference_bisection(x, y, strings, k: int, res: int, rng: np.random.Generator, step4: str = "fixed"):
    """``protocol.bisection`` computed in full (no shortcut for equal maps), round by round in numpy: Alice's picks
    are ``rng.integers(0, 100n, (segments, k))`` per round, the inner products :func:`reference_inner_products`."""
    x = np.asarray(x, dtype=bool)
    y = np.asarray(y, dtype=bool)
    n = check_n(x.size)
    xw, yw = pack(x), pack(y)
    differs = np.concatenate([[0], np.cumsum(x != y)])  # prefix counts: which segments truly differ (metrics)
    p1_bits = theory.protocol1_bits(n, k)
    lo, hi = np.array([0]), np.array([n - 1])
    alice = bob = rounds = tests = compared = 0
    found: list[np.ndarray] = []
    detected = None
    missed_tests = 0
    messages: list[tuple[str, int]] = []  # one request (Alice) and one reply (Bob) per round
    while lo.size:
        rounds += 1
        alice_before, bob_before = alice, bob
        length = hi - lo + 1
        leaf = length <= res
        if leaf.any():  # lines 2–6, EQUALLINEAR: Alice sends her bits of the segment, Bob compares
            leaf_lo, leaf_hi = lo[leaf], hi[leaf]
            holding = differs[leaf_hi + 1] - differs[leaf_lo] > 0  # Bob's comparison finds these
            for a, b in zip(leaf_lo[holding].tolist(), leaf_hi[holding].tolist()):
                found.append(np.flatnonzero(x[a : b + 1] != y[a : b + 1]) + a)
            leaf_bits = int(length[leaf].sum())
            compared += leaf_bits
            alice += leaf_bits
            if detected is None:
                detected = bool(found)
        inner_lo, inner_hi = lo[~leaf], hi[~leaf]
        if inner_lo.size == 0:
            messages.append(("alice", alice - alice_before))
            break
        equal, _ = protocol1_batch(xw, yw, strings, k, inner_lo, inner_hi, rng, step4)  # line 7
        tests += inner_lo.size
        alice += inner_lo.size * p1_bits
        bob += inner_lo.size  # Bob's verdicts, so that Alice knows which halves to open next
        if detected is None:
            detected = not bool(equal[0])
        different = ~equal
        if step4 == "fixed":
            truly = differs[inner_hi + 1] - differs[inner_lo] > 0
            missed_tests += int((equal & truly).sum())
        messages += [("alice", alice - alice_before), ("bob", bob - bob_before)]
        mid = (inner_lo[different] + inner_hi[different]) // 2  # line 1
        lo = np.concatenate([inner_lo[different], mid + 1])  # lines 10–11
        hi = np.concatenate([mid, inner_hi[different]])
        order = np.argsort(lo, kind="stable")
        lo, hi = lo[order], hi[order]
    cells = np.sort(np.concatenate(found)) if found else np.empty(0, dtype=np.int64)
    return Reconciliation(
        "bisection",
        cells,
        alice,
        bob,
        rounds,
        compared,
        bool(detected),
        {"protocol1_calls": tests, "false_equal_tests": missed_tests, "messages": messages},
    )


# ------------------------------------------------------------------------------------------------ the sketch
class ArithmeticField(GF2m):
    """GF(2^m) with scalar arithmetic for Berlekamp–Massey (on short Python lists) and zero-absorbing tables for a
    vectorised Chien search, on ``pinsketch.GF2m``'s log/antilog tables."""

    def __init__(self, m: int):
        super().__init__(m)
        exp, log = self.exp, self.log
        # zero-absorbing tables for the vectorised Chien search: log(0) points into a block of zeros, so a
        # product with 0 needs no mask (exp_z[log_z[a] + log[b]] = a·b for every a and nonzero b)
        self.exp_z = np.concatenate([exp[: 2 * self.order], np.zeros(self.order + 1, np.int64)]).astype(np.int32)
        self.log_z = np.where(log < 0, 2 * self.order, log).astype(np.int32)
        self.exp_list = exp.tolist()
        self.log_list = log.tolist()

    # scalar arithmetic (Berlekamp–Massey works on short Python lists)
    def mul(self, a: int, b: int) -> int:
        if a == 0 or b == 0:
            return 0
        return self.exp_list[self.log_list[a] + self.log_list[b]]

    def div(self, a: int, b: int) -> int:
        if b == 0:
            raise ZeroDivisionError("division by zero in GF(2^m)")
        if a == 0:
            return 0
        return self.exp_list[(self.log_list[a] - self.log_list[b]) % self.order]

    def square(self, a: int) -> int:
        return 0 if a == 0 else self.exp_list[(2 * self.log_list[a]) % self.order]

    def powers_sum(self, elements: np.ndarray, exponents: np.ndarray) -> np.ndarray:
        """``s_j = ⊕_{x∈elements} x^j`` for each ``j`` in ``exponents`` (elements nonzero)."""
        elements = np.asarray(elements, dtype=np.int64)
        exponents = np.asarray(exponents, dtype=np.int64)
        if elements.size == 0:
            return np.zeros(exponents.size, dtype=np.int64)
        logs = self.log[elements]
        terms = self.exp[(logs[None, :] * exponents[:, None]) % self.order]
        return np.bitwise_xor.reduce(terms, axis=1)


@lru_cache(maxsize=32)
def arithmetic_field(m: int) -> ArithmeticField:
    return ArithmeticField(m)


def syndromes(gf: ArithmeticField, elements: np.ndarray, count: int, first: int = 0) -> np.ndarray:
    """Odd syndromes number ``first … first + count − 1``: ``s_{2j+1}`` for j in that range."""
    return gf.powers_sum(elements, 2 * np.arange(first, first + count) + 1)


class StreamingDecoder:
    """Bob's side: feed the XOR of Alice's and his own odd syndromes one at a time; try to decode after each.

    Berlekamp–Massey (Massey 1969) runs incrementally over ``S_1, S_2, …`` (each odd syndrome brings its even
    successor ``S_2j = S_j²``); after ``t`` odd syndromes the locator ``Λ`` is the shortest LFSR generating
    ``S_1 … S_2t``. When ``deg Λ ≤ t`` a Chien search looks for its roots among the valid elements
    (``x ∈ [1, n_elements]``: ``Λ(x⁻¹) = 0``); decoding succeeds when it finds exactly ``deg Λ`` of them.
    """

    def __init__(self, gf: ArithmeticField, n_elements: int):
        self.gf = gf
        self.valid = np.arange(1, n_elements + 1, dtype=np.int64)
        self._valid_log = gf.log[self.valid].astype(np.int32)
        self.S: list[int] = []  # S_1, S_2, … (index 0 holds S_1)
        self.C = [1]
        self.B = [1]
        self.L = 0
        self.shift = 1
        self.b = 1
        self.t = 0

    def _feed(self, s: int) -> None:
        gf = self.gf
        self.S.append(s)
        r = len(self.S) - 1
        d = s
        for i in range(1, self.L + 1):
            if i < len(self.C):
                d ^= gf.mul(self.C[i], self.S[r - i])
        if d == 0:
            self.shift += 1
            return
        coef = gf.div(d, self.b)
        update = [0] * self.shift + [gf.mul(coef, c) for c in self.B]
        newC = self.C + [0] * max(0, len(update) - len(self.C))
        for i, u in enumerate(update):
            newC[i] ^= u
        if 2 * self.L <= r:
            self.B, self.b = self.C, d
            self.L = r + 1 - self.L
            self.shift = 1
        else:
            self.shift += 1
        self.C = newC

    def add(self, odd_syndrome: int) -> None:
        """Append ``S_{2t+1}`` (the next odd syndrome of the difference); ``S_{2t+2} = S_{t+1}²`` follows."""
        self.t += 1
        self._feed(int(odd_syndrome))
        self._feed(self.gf.square(self.S[self.t - 1]))

    def locator_degree(self) -> int:
        return self.L

    def decode(self) -> np.ndarray | None:
        """The difference set if the current locator splits into ``deg Λ`` distinct valid roots, else ``None``."""
        L = self.L
        coeffs = (self.C + [0] * (L + 1))[: L + 1]
        if L == 0:
            return np.empty(0, dtype=np.int64)
        if L > self.t or coeffs[L] == 0:
            return None
        gf = self.gf
        if L == 1:  # Λ = 1 + C_1 z: the one root is x = C_1
            root = coeffs[1]
            return np.array([root], dtype=np.int64) if 1 <= root <= self.valid.size else None
        # Λ(x⁻¹) = 0  ⟺  x^L Λ(x⁻¹) = Σ_i C_i x^{L−i} = 0: Horner over C_0 … C_L at every valid x at once
        exp_z, log_z, logx = gf.exp_z, gf.log_z, self._valid_log
        acc = np.full(self.valid.size, coeffs[0], dtype=np.int32)
        for c in coeffs[1:]:
            acc = exp_z[log_z[acc] + logx]
            acc ^= c
        roots = self.valid[acc == 0]
        return roots if roots.size == L else None


def parity_strings(seed: int, nonce: int, n: int, count: int) -> np.ndarray:
    """``count`` public-coin random n-bit strings for one session (``(count, words)`` uint32), from numpy's Philox."""
    index = np.array([(nonce * count + j) % (1 << 32) for j in range(count)], dtype=np.uint64)
    words = stream_words(seed_key(seed), index, np.zeros(count, np.int64), (n + 31) // 32, DOMAIN_PARITY)
    if n % 32:
        words[:, -1] &= np.uint32((1 << (n % 32)) - 1)
    return words


def parities(words: np.ndarray, strings: np.ndarray) -> np.ndarray:
    return (np.bitwise_count(strings & words[None, :]).sum(axis=1) & 1).astype(np.uint8)


def reference_sketch(x, y, seed, nonce, verify_bits=None, strict_feedback=False, block=8) -> Reconciliation:
    """``protocol.sketch`` step by step: Alice's parities and cell 0, then odd syndromes (``block`` computed at a
    time) fed to Bob's streaming decoder, each decoded candidate checked against her parities; her whole map when
    no syndrome the channel can afford decodes."""
    n = check_n(len(x))
    if verify_bits is None:
        verify_bits = sketch_verify_bits(n)
    x = np.asarray(x, dtype=bool)
    y = np.asarray(y, dtype=bool)
    alice, bob = verify_bits + 1, 0  # the parities and cell 0
    base = np.array([0]) if x[0] != y[0] else np.empty(0, dtype=np.int64)
    m = field_bits(n)
    gf = arithmetic_field(m)
    rho = parity_strings(seed, nonce, n, verify_bits)
    alice_parity = parities(pack(x), rho)

    def accepted(candidate: np.ndarray) -> bool:
        guess = y.copy()
        guess[candidate] ^= True
        return bool(np.array_equal(parities(pack(guess), rho), alice_parity))

    if accepted(base):
        return Reconciliation("sketch", base, alice, 1, 1, n, base.size > 0, {"syndromes": 0, "fallback": False})
    alice_set = np.flatnonzero(x[1:]) + 1
    bob_set = np.flatnonzero(y[1:]) + 1
    decoder = StreamingDecoder(gf, n - 1)
    t_max = max(0, (n - alice - 1) // m)  # beyond this the raw map is cheaper than more syndromes
    t = 0
    rounds = 1
    while t < t_max:
        count = min(block, t_max - t)
        for s in (syndromes(gf, alice_set, count, first=t) ^ syndromes(gf, bob_set, count, first=t)).tolist():
            t += 1
            rounds += 1
            alice += m
            if strict_feedback:
                bob += 1
            decoder.add(s)
            if decoder.locator_degree() > t:
                continue
            roots = decoder.decode()
            if roots is not None:
                candidate = np.sort(np.concatenate([base, roots]))
                if accepted(candidate):
                    bob += 0 if strict_feedback else 1
                    return Reconciliation(
                        "sketch", candidate, alice, bob, rounds, n, True, {"syndromes": t, "fallback": False, "m": m}
                    )
    # no decode within the useful length: Alice sends her map (both know t_max, so no request is needed)
    alice += n
    diff = np.flatnonzero(x != y)
    return Reconciliation("sketch", diff, alice, bob, rounds + 1, n, True, {"syndromes": t, "fallback": True, "m": m})
