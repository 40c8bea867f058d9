"""PinSketch set reconciliation (Dodis, Ostrovsky, Reyzin & Smith 2004): the syndrome of a binary BCH code.

Written here from scratch (no ``galois``): table-based GF(2^m) arithmetic, the syndromes
``s_j = Σ_{x∈S} x^j`` for odd ``j`` (the even ones follow, ``s_2j = s_j²``), Berlekamp–Massey for the
error-locator polynomial and a vectorised Chien search over the valid elements for its roots.

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
        # zero-absorbing tables for the vectorised Chien search: log(0) points into a block of zeros, so a
        # product with 0 needs no mask (exp_z[log_z[a] + log[b]] = a·b for every a and nonzero b)
        self.exp_z = np.concatenate([exp[: 2 * self.order], np.zeros(self.order + 1, np.int64)]).astype(np.int32)
        self.log_z = np.where(log < 0, 2 * self.order, log).astype(np.int32)
        self._exp_list = exp.tolist()
        self._log_list = log.tolist()

    # scalar arithmetic (Berlekamp–Massey works on short Python lists)
    def mul(self, a: int, b: int) -> int:
        if a == 0 or b == 0:
            return 0
        return self._exp_list[self._log_list[a] + self._log_list[b]]

    def div(self, a: int, b: int) -> int:
        if b == 0:
            raise ZeroDivisionError("division by zero in GF(2^m)")
        if a == 0:
            return 0
        return self._exp_list[(self._log_list[a] - self._log_list[b]) % self.order]

    def square(self, a: int) -> int:
        return 0 if a == 0 else self._exp_list[(2 * self._log_list[a]) % self.order]

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
def field(m: int) -> GF2m:
    return GF2m(m)


def field_bits(n: int) -> int:
    """m such that the n − 1 cells 1 … n − 1 are distinct nonzero elements of GF(2^m) (cell 0 is sent apart)."""
    return max(1, (n - 1).bit_length())


def syndromes(gf: GF2m, elements: np.ndarray, count: int, first: int = 0) -> np.ndarray:
    """Odd syndromes number ``first … first + count − 1``: ``s_{2j+1}`` for j in that range."""
    return gf.powers_sum(elements, 2 * np.arange(first, first + count) + 1)


class StreamingDecoder:
    """Bob's side: feed the XOR of Alice's and his own odd syndromes one at a time; try to decode after each.

    Berlekamp–Massey (Massey 1969) runs incrementally over ``S_1, S_2, …`` (each odd syndrome brings its even
    successor ``S_2j = S_j²``); after ``t`` odd syndromes the locator ``Λ`` is the shortest LFSR generating
    ``S_1 … S_2t``. When ``deg Λ ≤ t`` a Chien search looks for its roots among the valid elements
    (``x ∈ [1, n_elements]``: ``Λ(x⁻¹) = 0``); decoding succeeds when it finds exactly ``deg Λ`` of them.
    """

    def __init__(self, gf: GF2m, n_elements: int):
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
