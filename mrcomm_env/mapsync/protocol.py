"""The synchronisation protocols, executed between two robots with every bit counted (paper 002, §IV).

Maps are bit vectors of ``n`` cells. Alice is the robot that runs the protocol as client; Bob answers. Each
protocol here is *one-way reconciliation*: it ends when Bob knows (or believes he knows) the set of cells
where the two maps differ. Its result carries Alice's and Bob's bits separately.

* :func:`equality` — Protocol 1. k rounds: Alice draws ``i`` uniformly from the 100n strings, sends ``i`` and
  ``b = X·r_i mod 2``; Bob counts the rounds with ``Y·r_i ≠ b``. Step 4 as printed ("if the counter is
  greater or equal than zero return *different*") would answer "different" always; the fix, used unless
  ``step4="as_printed"``, is "greater than zero", which makes the error one-sided (Proposition 2). Bob's
  verdict is one more bit back to Alice (§IV-A: "sending one more bit will ensure that both parties have the
  result"), reported apart from Proposition 1's ``k(⌈log2 100n⌉ + 1)``.
* :func:`bisection` — Algorithm 1 as request/response rounds, one round per recursion level: Alice sends a
  Protocol 1 (on the segment, strings restricted to it) for every open segment longer than ``res`` and her
  bits of every open segment of length ≤ ``res`` (EQUALLINEAR); Bob answers one verdict bit per Protocol 1.
  Segments that tested different are split at ``⌊(l+u)/2⌋`` for the next round.
* :func:`full` — Alice sends all n bits.
* :func:`sketch` — beyond the paper: a streaming PinSketch (:mod:`pinsketch`). Alice first sends ``v``
  public-coin parity bits of her map (fresh random strings from the shared seed and a session nonce both
  robots know, so no index is sent; v = :func:`sketch_verify_bits`) and her bit of cell 0 (cells 1 … n−1 are the field elements). Then she
  streams odd syndromes of GF(2^m), m = ⌈log2 n⌉, one at a time; after each, Bob decodes the XOR with his own
  and checks the candidate map against the parities; when it passes he sends one *stop* bit. The number of
  differences is never sent or guessed: the stream is rateless and stops at the first syndrome that decodes,
  so the estimation cost is the stop bit and the parities. A wrong candidate passes the parities with
  probability 2^−v; Bob then keeps a wrong map (one-sided, like Protocol 1; at most about e·2^−v per run). If ``v + 1 + t·m`` would reach ``n``, Alice sends her map
  instead. Bits to agreement stay within 2 log2 C(n, d) for n ≥ 1024 and d ≤ 64 except just above a power of
  two (n ∈ [1025, 1204] at d near 64: up to 2.09×), where the field gains a bit while log2 C(n, d)/d does
  not. *Timing assumption*: Alice waits for a possible stop after each syndrome, so a link's round trip
  is short against a step; ``strict_feedback=True`` instead charges Bob one continue/stop bit per syndrome.

:func:`return_bits` is the cost of the way back (Bob tells Alice the differing cells) that two-way
merging in the env adds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np

from mrcomm_env.core import pcg64_numba
from mrcomm_env.mapsync import kernels_numba, pinsketch, theory
from mrcomm_env.mapsync.philox import DOMAIN_DATABASE, DOMAIN_PARITY, SharedStrings, seed_key

PROTOCOLS = ("equality", "bisection", "full", "sketch")
STEP4_RULES = ("fixed", "as_printed")

#: parity bits a sketch candidate is verified against below n = 1024 (a wrong candidate passes w.p. 2^−v)
SKETCH_VERIFY_SMALL = 8


def sketch_verify_bits(n: int) -> int:
    """Parity bits v of the sketch: from n = 1024 on, as many as keep one difference within 2 log2 n bits.

    One difference costs m (one syndrome) + 1 (cell 0) + v + 1 (stop) bits, so v = ⌊2 log2 n⌋ − m − 2: 8 at
    n = 1024, 10 at 4096, 14 at 65536 (7 just above a power of two, where m jumps); 8 below n = 1024. With d ≥ 2 the
    decoder meets wrong candidates before the right one: "no difference" before the first syndrome, the one root
    of the first, and after t syndromes a wrong locator splits into valid roots with probability about 1/t!, so
    one passes with probability about (1 + 1 + 1/2 + 1/6 + …)·2^−v ≤ e·2^−v per reconciliation (2·2^−v at
    d = 2) — a one-sided error like Protocol 1's 2^−k.
    """
    if n < 1024:
        return SKETCH_VERIFY_SMALL
    return math.floor(2 * math.log2(n)) - pinsketch.field_bits(n) - 2


def check_protocol(name: str) -> str:
    if name not in PROTOCOLS:
        raise ValueError(f"argument 'protocol' must be one of {', '.join(PROTOCOLS)}; got {name!r}")
    return name


def check_n(n: int) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"argument 'n' (bits per map) must be an integer ≥ 2, got {n!r}")
    return int(n)


def pack(bits: np.ndarray) -> np.ndarray:
    """A bit vector as little-endian uint32 words (bit b → word b // 32, bit b % 32); zero padded."""
    bits = np.asarray(bits, dtype=bool).reshape(-1)
    pad = (-bits.size) % 32
    if pad:
        bits = np.concatenate([bits, np.zeros(pad, dtype=bool)])
    return np.packbits(bits, bitorder="little").view(np.uint32)


_FROM_BIT = np.array([(0xFFFFFFFF << b) & 0xFFFFFFFF for b in range(32)], dtype=np.uint32)  # bits ≥ b
_TO_BIT = np.array([0xFFFFFFFF >> (31 - b) for b in range(32)], dtype=np.uint32)  # bits ≤ b


def kernel_strings(strings) -> tuple[np.ndarray, bool, Any, Any, int, int, int]:
    """The shared strings as the compiled kernels take them: (database, use_database, key0, key1, domain,
    words_per_string, last_mask); a 1×1 dummy database when r_i are generated on demand."""
    use_db = strings.database is not None
    database = strings.database if use_db else np.zeros((1, 1), np.uint32)
    return (
        database,
        use_db,
        strings.key[0],
        strings.key[1],
        DOMAIN_DATABASE,
        strings.words_per_string,
        int(strings.last_mask),
    )


@dataclass
class EqualityResult:
    equal: bool  #: Bob's verdict (Protocol 1's return value 1 = "same")
    counter: int  #: rounds in which Bob's inner product differed from Alice's
    alice_bits: int  #: Proposition 1: k (⌈log2 100n⌉ + 1)
    bob_bits: int  #: the verdict sent back (1)


def _alice_picks(strings: SharedStrings, segments: int, k: int, rng: np.random.Generator) -> np.ndarray:
    """Protocol 1's step 3a for ``segments`` tests at once: Alice's k picks of i among the 100n strings each."""
    return rng.integers(0, strings.size, size=(segments, k))


def equality(
    x: np.ndarray, y: np.ndarray, strings: SharedStrings, k: int, rng: np.random.Generator, step4: str = "fixed"
) -> EqualityResult:
    """Protocol 1 on whole maps ``x`` and ``y`` (bool vectors of n cells), in one compiled call
    (``kernels_numba.equality_counter``; its numpy rounds are ``protocol1_batch`` in ``tests/helpers/mapsync_reference.py``)."""
    n = check_n(len(x))
    if k < 1:
        raise ValueError(f"argument 'k' must be an integer ≥ 1, got {k!r}")
    if step4 not in STEP4_RULES:
        raise ValueError(f"argument 'step4' must be one of {', '.join(STEP4_RULES)}; got {step4!r}")
    if not np.shape(x) == np.shape(y) == (n,):
        raise ValueError(
            f"arguments 'x' and 'y' must be maps of the same n cells, got shapes {np.shape(x)}, {np.shape(y)}"
        )
    if step4 == "fixed" and np.array_equal(x, y):
        # equal maps have equal inner products with every r_i: Bob's counter is 0 whatever Alice picks (step 3e),
        # so only her picks are drawn (step 3a), which keeps the generator where the full run leaves it
        _alice_picks(strings, 1, k, rng)
        return EqualityResult(True, 0, theory.protocol1_bits(n, k), 1)
    picks = _alice_picks(strings, 1, k, rng)[0]  # step 3a
    database, use_database, key0, key1, domain, words, last_mask = kernel_strings(strings)
    x_plain, y_plain = np.ascontiguousarray(x, dtype=bool), np.ascontiguousarray(y, dtype=bool)
    counter = kernels_numba.equality_counter(
        x_plain, y_plain, database, use_database, key0, key1, domain, words, last_mask, picks
    )
    # step 4: "greater than zero" means different; as printed ("≥ 0") it can never answer "same"
    return EqualityResult(step4 == "fixed" and counter == 0, counter, theory.protocol1_bits(n, k), 1)


@dataclass
class Reconciliation:
    """What one-way reconciliation achieved and cost: Bob's belief of the differing cells, and bits."""

    protocol: str
    found: np.ndarray  #: cells Bob believes differ (sorted)
    alice_bits: int
    bob_bits: int
    rounds: int  #: request/response rounds
    candidates: int  #: cells both robots know ``found`` lies within (the way back codes a subset of these)
    detected: bool  #: did the first test (Protocol 1 on the whole map, or any step) find a difference
    extra: dict = field(default_factory=dict)

    @property
    def bits(self) -> int:
        return self.alice_bits + self.bob_bits


def full(x: np.ndarray, y: np.ndarray) -> Reconciliation:
    n = check_n(len(x))
    diff = np.flatnonzero(np.asarray(x, bool) != np.asarray(y, bool))
    return Reconciliation("full", diff, n, 0, 1, n, diff.size > 0)


def bisection(
    x: np.ndarray,
    y: np.ndarray,
    strings: SharedStrings,
    k: int,
    res: int,
    rng: np.random.Generator,
    step4: str = "fixed",
) -> Reconciliation:
    """Algorithm 1, ERRORCORRECTION(X, Y, 1, n, res), as one request/response round per recursion level, in one
    compiled call (``kernels_numba.bisection``; its numpy rounds are ``reference_bisection`` in
    ``tests/helpers/mapsync_reference.py``). Alice's picks come from ``rng`` round by round, as
    ``rng.integers(0, 100n, (segments, k))`` draws them, whatever its bit generator."""
    n = check_n(len(x))
    if k < 1:
        raise ValueError(f"argument 'k' must be an integer ≥ 1, got {k!r}")
    if res < 1:
        raise ValueError(f"argument 'res' must be an integer ≥ 1, got {res!r}")
    if step4 not in STEP4_RULES:
        raise ValueError(f"argument 'step4' must be one of {', '.join(STEP4_RULES)}; got {step4!r}")
    x = np.ascontiguousarray(x, dtype=bool)
    y = np.ascontiguousarray(y, dtype=bool)
    if step4 == "fixed" and np.array_equal(x, y):
        return _bisection_of_equal_maps(n, strings, k, res, rng)
    # numba draws from any numpy Generator handed to it, but through the bit generator's function pointers, at 1.6×
    # the run's time (282 against 182 µs, n = 4,096, 3 differences, k = 7): a PCG64's state is handed over instead
    state = np.empty(pcg64_numba.STATE_WORDS, dtype=np.uint64)
    pcg64 = isinstance(rng.bit_generator, np.random.PCG64)
    if pcg64:
        pcg64_numba.state_of(rng, state)
    found, stats, rounds = kernels_numba.bisection(
        x,
        y,
        *kernel_strings(strings),
        state if pcg64 else rng,
        k,
        res,
        theory.protocol1_bits(n, k),
        strings.size,
        step4 == "as_printed",
    )
    if pcg64:
        pcg64_numba.set_state(rng, state)
    alice, bob, n_rounds, tests, compared, detected, missed, _ = stats.tolist()
    messages: list[tuple[str, int]] = []
    for alice_round, bob_round in rounds.tolist():
        messages.append(("alice", alice_round))
        if bob_round >= 0:
            messages.append(("bob", bob_round))
    return Reconciliation(
        "bisection",
        found,
        alice,
        bob,
        n_rounds,
        compared,
        bool(detected),
        {"protocol1_calls": tests, "false_equal_tests": missed, "messages": messages},
    )


def _bisection_of_equal_maps(n: int, strings: SharedStrings, k: int, res: int, rng: np.random.Generator):
    """:func:`bisection` of two equal maps with step 4 fixed, without computing what is known to come out.

    The first round is the whole map. If it is no longer than ``res`` Alice sends it (lines 2–6) and Bob finds
    nothing; otherwise Protocol 1 on it says "same" (equal maps agree on every inner product, and step 4 fixed
    errs one way only), Bob sends that verdict and no segment is left to open (line 7). Either way one round, and
    the generator advances by the k picks of that one test, as in the full run.
    """
    if n <= res:
        return Reconciliation(
            "bisection",
            np.empty(0, dtype=np.int64),
            n,
            0,
            1,
            n,
            False,
            {"protocol1_calls": 0, "false_equal_tests": 0, "messages": [("alice", n)]},
        )
    _alice_picks(strings, 1, k, rng)
    p1_bits = theory.protocol1_bits(n, k)
    return Reconciliation(
        "bisection",
        np.empty(0, dtype=np.int64),
        p1_bits,
        1,
        1,
        0,
        False,
        {"protocol1_calls": 1, "false_equal_tests": 0, "messages": [("alice", p1_bits), ("bob", 1)]},
    )


def sketch(
    x: np.ndarray,
    y: np.ndarray,
    seed: int,
    nonce: int,
    verify_bits: int | None = None,
    strict_feedback: bool = False,
) -> Reconciliation:
    """Streaming PinSketch with parity verification (see the module docstring); Bob learns the difference."""
    n = check_n(len(x))
    if verify_bits is None:
        verify_bits = sketch_verify_bits(n)
    if verify_bits < 1:
        raise ValueError(f"argument 'verify_bits' must be an integer ≥ 1, got {verify_bits!r}")
    x = np.asarray(x, dtype=bool)
    y = np.asarray(y, dtype=bool)
    if np.array_equal(x[1:], y[1:]):
        # Bob's first candidate, his map with Alice's cell 0, *is* her map: it passes her parities (sent with cell
        # 0) whatever the strings, so they need not be generated (they are the seed's and the nonce's: nothing
        # random is drawn)
        base = np.array([0]) if x[0] != y[0] else np.empty(0, dtype=np.int64)
        return Reconciliation(
            "sketch", base, verify_bits + 1, 1, 1, n, base.size > 0, {"syndromes": 0, "fallback": False}
        )
    m = pinsketch.field_bits(n)
    gf = pinsketch.field(m)
    k0, k1 = seed_key(seed)
    # the steps of the module docstring in one call, integer for integer (their Python oracle is under tests/)
    found, stats = kernels_numba.sketch(
        np.ascontiguousarray(x),
        np.ascontiguousarray(y),
        k0,
        k1,
        int(nonce),
        int(verify_bits),
        DOMAIN_PARITY,
        gf.exp,
        gf.log,
        m,
        bool(strict_feedback),
    )
    alice, bob, rounds, t, outcome = stats.tolist()
    if outcome == 0:  # Bob's map with Alice's cell 0 passed her parities
        return Reconciliation(
            "sketch", found, alice, bob, rounds, n, found.size > 0, {"syndromes": 0, "fallback": False}
        )
    extra = {"syndromes": t, "fallback": outcome == 2, "m": m}
    return Reconciliation("sketch", found, alice, bob, rounds, n, True, extra)


def return_bits(candidates: int, found: int) -> int:
    """Bob → Alice: how many cells differ (⌈log2(C+1)⌉ bits) and which (⌈log2 C(C, d)⌉, enumerative code)."""
    if candidates <= 0:
        return 0
    return theory.count_bits(candidates) + theory.ceil_log2_binomial(candidates, found)


@lru_cache(maxsize=8)
def return_bits_table(candidates: int) -> np.ndarray:
    """:func:`return_bits` of ``candidates`` cells for every count of found cells 0 … ``candidates`` (read-only int64),
    for compiled code, which has no big integers: C(C, d) is carried from d to d + 1 exactly (0.6 s at C = 65,536)."""
    table = np.zeros(candidates + 1, dtype=np.int64)
    if candidates > 0:
        count, binomial = theory.count_bits(candidates), 1
        for d in range(candidates + 1):
            table[d] = count + (binomial - 1).bit_length()  # theory.ceil_log2_binomial(candidates, d)
            binomial = binomial * (candidates - d) // (d + 1)
    table.flags.writeable = False
    return table
