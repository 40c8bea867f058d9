"""PinSketch set reconciliation (Dodis, Ostrovsky, Reyzin & Smith 2004): the syndrome of a binary BCH code.

Written here from scratch (no ``galois``): the GF(2^m) log/antilog tables the compiled sketch
(``kernels_numba.sketch``) computes with, for the syndromes ``s_j = Σ_{x∈S} x^j`` for odd ``j`` (the even ones
follow, ``s_2j = s_j²``), Berlekamp–Massey for the error-locator polynomial and a Chien search over the valid
elements for its roots. The same steps in Python and numpy are the kernel's oracle
(``tests/helpers/mapsync_reference.py``, #44: one implementation in the package).

The sketch is linear: ``sketch(A) ⊕ sketch(B) = sketch(A △ B)``. A robot's map is the set of its cells
holding a 1, so the XOR of two robots' sketches is the sketch of the cells where their maps differ. With
``t`` odd syndromes, ``t·m`` bits, up to ``t`` differences are decoded. Syndromes are *incremental*:
sending one more extends the capacity by one, so the decoder here is streaming (one syndrome at a time,
Berlekamp–Massey state kept between them).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

#: conventional primitive polynomials (bit i = coefficient of x^i); verified when the tables are built
_PRIMITIVE = {
    1: 0b11,
    2: 0x7,
    3: 0xB,
    4: 0x13,
    5: 0x25,
    6: 0x43,
    7: 0x89,
    8: 0x11D,
    9: 0x211,
    10: 0x409,
    11: 0x805,
    12: 0x1053,
    13: 0x201B,
    14: 0x4443,
    15: 0x8003,
    16: 0x1100B,
    17: 0x20009,
    18: 0x40081,
    19: 0x80027,
    20: 0x100009,
}


class GF2m:
    """GF(2^m) with log/antilog tables; elements are ints in [0, 2^m)."""

    def __init__(self, m: int):
        if not 1 <= m <= 20:
            raise ValueError(f"argument 'm' must be an integer in [1, 20], got {m!r}")
        self.m = m
        self.q = 1 << m
        self.order = self.q - 1
        self.poly = _PRIMITIVE[m]
        exp = np.zeros(2 * self.order + 1, dtype=np.int64)
        log = np.full(self.q, -1, dtype=np.int64)
        x = 1
        for i in range(self.order):
            exp[i] = x
            if log[x] != -1:
                raise ValueError(f"polynomial {self.poly:#x} is not primitive for m = {m}")
            log[x] = i
            x <<= 1
            if x & self.q:
                x ^= self.poly
        exp[self.order : 2 * self.order] = exp[: self.order]
        self.exp, self.log = exp, log


@lru_cache(maxsize=32)
def field(m: int) -> GF2m:
    return GF2m(m)


def field_bits(n: int) -> int:
    """m such that the n − 1 cells 1 … n − 1 are distinct nonzero elements of GF(2^m) (cell 0 is sent apart)."""
    return max(1, (n - 1).bit_length())
