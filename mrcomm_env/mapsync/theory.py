"""The paper's formulas (Alsayegh et al., paper 002) and the bounds we check them against."""

from __future__ import annotations

import math


def index_bits(n: int, size_factor: int = 100) -> int:
    """Bits of the index ``i ∈ {1, …, 100n}`` of Protocol 1 step 3c: ⌈log2(100 n)⌉."""
    return math.ceil(math.log2(size_factor * n))


def protocol1_bits(n: int, k: int) -> int:
    """Proposition 1: k (⌈log2 100n⌉ + 1) bits from Alice to Bob (k indices and k inner-product bits)."""
    return k * (index_bits(n) + 1)


def protocol1_error_bound(k: int) -> float:
    """Proposition 2: when X ≠ Y, Protocol 1 (with step 4 fixed to "> 0") says "equal" w.p. at most 2^−k."""
    return 2.0 ** (-k)


def recursion_depth(n: int, res: int) -> int:
    """Levels of Algorithm 1 at which Protocol 1 runs: segments longer than ``res`` (root = level 0)."""
    depth, length = 0, n
    while length > res:
        depth += 1
        length = (length + 1) // 2  # the longer half, ⌈L/2⌉ (Algorithm 1, line 1: midpoint = ⌊(l+u)/2⌋)
    return depth


def algorithm1_paper_worst_case(n: int, k: int, res: int, differing: int) -> int:
    """§IV-B as printed: log(n/res) · k (log 100n + 1) + i, with ⌈·⌉ on the logarithms.

    The argument charges one Protocol 1 per recursion level ("in the worst case, Protocol 1 is called with the
    whole array"). But every call costs k (⌈log2 100n⌉ + 1) bits whatever the segment's length, and a level
    can hold up to 2·min(2^(ℓ−1), i) calls, so this is *not* an upper bound once a segment splits into two
    tested halves, which happens on every level even for i = 1 (see :func:`algorithm1_worst_case`).
    """
    return math.ceil(math.log2(n / res)) * protocol1_bits(n, k) + differing


def segment_levels(n: int, res: int) -> list[dict[int, int]]:
    """The segment tree of Algorithm 1 on [1, n]: per level, {segment length: how many segments}."""
    levels = [{n: 1}]
    while True:
        nxt: dict[int, int] = {}
        for length, count in levels[-1].items():
            if length <= res:
                continue
            for half in ((length + 1) // 2, length // 2):
                if half > 0:
                    nxt[half] = nxt.get(half, 0) + count
        if not nxt:
            return levels
        levels.append(nxt)


def algorithm1_worst_case(n: int, k: int, res: int, differing: int) -> dict[str, int]:
    """A true worst case of Algorithm 1 executed as request/response rounds, for ``differing`` ≥ 1 cells.

    Level 0 tests the whole map. On level ℓ ≥ 1 only the two halves of a segment that tested *different* are
    visited, and at most ``min(#internal segments at ℓ−1, i)`` segments can hold a difference, so at most
    ``v_ℓ = min(#segments at ℓ, 2·min(#internal at ℓ−1, i))`` segments are visited. A visited segment longer
    than ``res`` costs one Protocol 1 (Alice) and a one-bit verdict (Bob); one of length ≤ ``res`` costs its
    length in bits (EQUALLINEAR: Alice sends her bits). Returns Alice's, Bob's and the total bits.
    """
    p1 = protocol1_bits(n, k)
    levels = segment_levels(n, res)
    alice = bob = 0
    prev_internal = 0
    for depth, lengths in enumerate(levels):
        internal = sum(c for length, c in lengths.items() if length > res)
        leaves = sorted(((length, c) for length, c in lengths.items() if length <= res), reverse=True)
        total = internal + sum(c for _, c in leaves)
        visited = 1 if depth == 0 else min(total, 2 * min(prev_internal, differing))
        tests = min(internal, visited)
        alice += tests * p1
        bob += tests
        room = visited  # the remaining visits may be leaves: charge the longest ones
        for length, c in leaves:
            take = min(c, room)
            alice += take * length
            room -= take
        prev_internal = internal
    return {"alice": alice, "bob": bob, "total": alice + bob}


def log2_binomial(n: int, d: int) -> float:
    """log2 C(n, d): the bits Bob needs to learn Alice's map when he knows his own and that d cells differ."""
    if d < 0 or d > n:
        return math.nan
    return math.log2(math.comb(n, d))  # exact big integer first: lgamma loses the last bits (log2 4096 ≠ 12)


def ceil_log2_binomial(n: int, d: int) -> int:
    """⌈log2 C(n, d)⌉ exactly (big integers): the length of an enumerative code of a d-subset of n cells."""
    return (math.comb(n, d) - 1).bit_length()


def count_bits(n: int) -> int:
    """Bits of a number in [0, n]: ⌈log2 (n + 1)⌉."""
    return max(1, n.bit_length())
