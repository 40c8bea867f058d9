"""Shared public randomness for Protocol 1 without storing the paper's database (§IV-A, step 1).

Protocol 1 gives both robots a database ``R`` of ``100 n`` random ``n``-bit strings before deployment.
At the paper's own motivating size (n = 10^6) that is 10^14 bits, 12.5 TB. A *counter-based* generator
makes the database virtual: bit block ``w`` of string ``r_i`` is ``Philox4x32-10(key = seed, counter =
(w // 4, i, domain, 0))[w % 4]``, so either robot computes any word of any ``r_i`` on demand, in any
order, with nothing stored but the 64-bit seed. Philox4x32-10 (Salmon et al., SC'11, the generator behind
Random123 and numpy's ``Philox`` family) is implemented here vectorised in numpy so that many words of
many strings come out of one call; the known-answer vectors of Random123 are checked by the tests.

:class:`SharedStrings` serves the words of ``r_i`` either on demand (default) or from an explicit,
materialised database (``explicit=True``, small n only) built row by row from the same stream, so that
the two can be compared.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

_MASK = np.uint64(0xFFFFFFFF)
_M0, _M1 = np.uint64(0xD2511F53), np.uint64(0xCD9E8D57)
_SHIFT = np.uint64(32)

#: counter word 2 separates independent uses of one seed: Protocol 1's database, the sketch's parities
DOMAIN_DATABASE = 0
DOMAIN_PARITY = 1

#: largest explicit database materialised (bits); 100 n · n bits is 13 MB at n = 1024
MAX_EXPLICIT_BITS = 100 * 1024 * 1024
#: largest database kept as a per-process cache of the on-demand strings (1 MB: n ≤ 289, a 17×17 grid)
CACHE_BITS = 8 * 1024 * 1024


@lru_cache(maxsize=64)
def _round_keys(k0: int, k1: int, rounds: int) -> np.ndarray:
    """The key of every round, ``(rounds, 2)``: Weyl-sequence bumps by (0x9E3779B9, 0xBB67AE85) mod 2^32."""
    keys = [((k0 + r * 0x9E3779B9) & 0xFFFFFFFF, (k1 + r * 0xBB67AE85) & 0xFFFFFFFF) for r in range(rounds)]
    return np.array(keys, dtype=np.uint64)


def philox4x32(counter: np.ndarray, key: tuple[int, int], rounds: int = 10) -> np.ndarray:
    """Philox4x32 of every row of ``counter`` (``(..., 4)`` integers < 2^32): ``(..., 4)`` uint32 words.

    One round maps (c0, c1, c2, c3) to (hi(M1·c2) ⊕ c1 ⊕ k0, lo(M1·c2), hi(M0·c0) ⊕ c3 ⊕ k1, lo(M0·c0)).
    The pairs (c0, c2) and (c1, c3) are kept stacked so that a round is five numpy operations.
    """
    ctr = np.asarray(counter, dtype=np.uint64)
    lead = (2,) + (1,) * (ctr.ndim - 1)
    a = np.stack([ctr[..., 0], ctr[..., 2]])  # (c0, c2)
    b = np.stack([ctr[..., 1], ctr[..., 3]])  # (c1, c3)
    mult = np.array([_M0, _M1], dtype=np.uint64).reshape(lead)
    keys = _round_keys(int(key[0]) & 0xFFFFFFFF, int(key[1]) & 0xFFFFFFFF, rounds)
    for r in range(rounds):
        prod = mult * a  # 32 × 32 → 64 bits: exact in uint64
        a = (prod >> _SHIFT)[::-1] ^ b ^ keys[r].reshape(lead)
        b = (prod & _MASK)[::-1]
    out = np.empty((*ctr.shape[:-1], 4), dtype=np.uint32)
    out[..., 0], out[..., 1], out[..., 2], out[..., 3] = a[0], b[0], a[1], b[1]
    return out


def seed_key(seed: int) -> tuple[int, int]:
    seed = int(seed) & 0xFFFFFFFFFFFFFFFF
    return seed & 0xFFFFFFFF, seed >> 32


def stream_words(
    key: tuple[int, int], index: np.ndarray, first_word: np.ndarray, n_words: int, domain: int
) -> np.ndarray:
    """Words ``first_word … first_word + n_words − 1`` of stream ``index`` (one row per index): ``(S, n_words)``."""
    index = np.asarray(index, dtype=np.uint64).reshape(-1)
    first_word = np.asarray(first_word, dtype=np.int64).reshape(-1)
    if first_word.size == 1 and index.size != 1:
        first_word = np.full(index.size, first_word[0])
    offset = first_word % 4
    aligned = not offset.any()
    n_blocks = (n_words + 3) // 4 if aligned else (int(offset.max()) + n_words + 3) // 4
    counter = np.empty((index.size, n_blocks, 4), dtype=np.uint64)
    counter[..., 0] = (first_word // 4)[:, None] + np.arange(n_blocks)[None, :]
    counter[..., 1] = index[:, None]
    counter[..., 2] = domain
    counter[..., 3] = 0
    words = philox4x32(counter, key).reshape(index.size, n_blocks * 4)
    if aligned:
        return words[:, :n_words]
    cols = offset[:, None] + np.arange(n_words)[None, :]
    return np.take_along_axis(words, cols, axis=1)


class SharedStrings:
    """The database ``R = {r_0, …, r_{size−1}}`` of ``n``-bit strings shared by two robots (Protocol 1, step 1).

    Strings are stored/served as little-endian uint32 words: bit ``b`` of ``r_i`` is bit ``b % 32`` of word
    ``b // 32``. Bits past ``n`` in the last word are zero.
    """

    def __init__(self, n: int, seed: int, size: int | None = None, explicit: bool = False, cache: bool = False):
        if n < 2:
            raise ValueError(f"argument 'n' must be an integer ≥ 2 (bits per map), got {n!r}")
        self.n = int(n)
        self.size = 100 * self.n if size is None else int(size)
        if self.size < 1:
            raise ValueError(f"argument 'size' must be ≥ 1, got {size!r}")
        self.key = seed_key(seed)
        self.words_per_string = (self.n + 31) // 32
        self.last_mask = np.uint32(
            (1 << (self.n - 32 * (self.words_per_string - 1))) - 1 if self.n % 32 else 0xFFFFFFFF
        )
        self.explicit = bool(explicit)
        self.database: np.ndarray | None = None
        if self.explicit:
            if self.size * self.n > MAX_EXPLICIT_BITS:
                raise ValueError(
                    f"argument 'explicit' needs {self.size * self.n / 8e6:.0f} MB for 100n strings of n = {self.n} bits; "
                    f"allowed up to {MAX_EXPLICIT_BITS / 8e6:.0f} MB (use the on-demand generator)"
                )
            # materialised once per process and (n, seed): an env resets without regenerating 100n strings
            self.database = _cached_database(self.n, int(seed), self.size)
        elif cache and self.size * self.n <= CACHE_BITS:
            # the same strings, generated once per process and (n, seed): a speed-up for small maps only
            self.database = _cached_database(self.n, int(seed), self.size)

    def _generate(self, index, first_word, n_words) -> np.ndarray:
        words = stream_words(self.key, index, first_word, n_words, DOMAIN_DATABASE)
        # zero the bits past n so that a string is exactly n bits long whichever way it is produced
        col = np.asarray(first_word).reshape(-1, 1) + np.arange(n_words)[None, :]
        if (col >= self.words_per_string - 1).any():
            words = np.where(col == self.words_per_string - 1, words & self.last_mask, words)
            words = np.where(col < self.words_per_string, words, np.uint32(0)).astype(np.uint32)
        return words

    def words(self, index: np.ndarray, first_word: np.ndarray, n_words: int) -> np.ndarray:
        """``(S, n_words)`` words of ``r_index`` starting at word ``first_word`` (zero past the string's end)."""
        index = np.asarray(index, dtype=np.int64).reshape(-1)
        first_word = np.asarray(first_word, dtype=np.int64).reshape(-1)
        if first_word.size == 1 and index.size != 1:
            first_word = np.full(index.size, first_word[0])
        if self.database is None:
            return self._generate(index, first_word, n_words)
        cols = first_word[:, None] + np.arange(n_words)[None, :]
        inside = cols < self.words_per_string
        out = self.database[index[:, None], np.minimum(cols, self.words_per_string - 1)]
        return out if inside.all() else np.where(inside, out, np.uint32(0))

    def bits(self, index: int) -> np.ndarray:
        """String ``r_index`` as ``n`` bools (for checks; the protocols work on words)."""
        words = self.words(np.array([index]), np.array([0]), self.words_per_string)[0]
        return np.unpackbits(words.view(np.uint8), bitorder="little")[: self.n].astype(bool)


@lru_cache(maxsize=8)
def _cached_database(n: int, seed: int, size: int) -> np.ndarray:
    words = SharedStrings(n, seed, size)._generate(np.arange(size), np.zeros(size, np.int64), (n + 31) // 32)
    words.flags.writeable = False
    return words
