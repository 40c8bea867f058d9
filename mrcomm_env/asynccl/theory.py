"""The paper's analytic delay results (§III-A.4, §III-B.4, §IV) as code.

* :func:`scheme1_expected_delay` — eq. (9)–(11): with Scheme 1, robot i can compute x̂_{k|k} once every
  other robot has talked to it directly at some step in k … k+t, so
  ``P(delay ≤ t) = Π_{j≠i} (1 − (1 − p)^{t+1})`` and E(delay) = Σ_t t·P(delay = t).
* :func:`scheme2_qinf_n3_expected_delay` — eq. (15)–(16): N = 3, Scheme 2 with q = ∞,
  ``I_t = I_{t-1} (1-p)^2 + 2p (1-p)^{2t+1}`` with ``I_0 = 1 − p²``.
* :func:`p_delay_gt1_as_printed`, :func:`p_delay_eq1_as_printed` — eq. (17)–(18) evaluated exactly
  as printed (Table II claims to tabulate eq. (18)).
* :func:`p_delay_eq1_exact` — P(delay = 1) for q = ∞ by exact enumeration over the link graphs of two
  consecutive steps (small N only), the reference against which eq. (17)–(18) and Table II are judged.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

#: Table I of the paper: N -> (Scheme 1 theory, Scheme 1 sim, Scheme 2 q=∞, Scheme 2 q=1); None: not given
PAPER_TABLE1 = {
    3: (1.6667, 1.6488, 1.2222, 66.0237),
    5: (2.5048, 2.4867, 1.2876, 66.7684),
    10: (3.5813, 3.5495, 1.1673, 69.9089),
    20: (4.6183, 4.5356, 1.0231, 70.6912),
    50: (5.9621, 5.8811, 1.0, 72.5475),
    100: (6.9694, 7.0152, 1.0, 74.2389),
}
#: the N = 3, q = ∞ theory value printed in Table I (eq. (15)–(16))
PAPER_QINF_N3_THEORY = 1.2333
#: Table II of the paper: N -> p(delay = 1) for Scheme 2, q = ∞
PAPER_TABLE2 = {3: 0.5625, 5: 0.8789, 10: 0.9961, 20: 0.9999, 50: 1.0, 100: 1.0}


def scheme1_cdf(t: int, n: int, p: float) -> float:
    """eq. (9): P(delay ≤ t) = Π_{j≠i} (1 − (1 − p)^{t+1}) (t < 0 gives 0)."""
    if t < 0:
        return 0.0
    return (1.0 - (1.0 - p) ** (t + 1)) ** (n - 1)


def scheme1_expected_delay(n: int, p: float, tol: float = 1e-13) -> float:
    """eq. (11): Σ_t t (P(delay ≤ t) − P(delay ≤ t−1)), summed until the tail is below ``tol``."""
    if p <= 0.0:
        return math.inf
    total, t = 0.0, 0
    while True:
        t += 1
        pt = scheme1_cdf(t, n, p) - scheme1_cdf(t - 1, n, p)
        total += t * pt
        if 1.0 - scheme1_cdf(t, n, p) < tol and t > 2:
            return total


def scheme2_qinf_n3_tails(p: float, tmax: int = 2000):
    """eq. (15): I_0, I_1, … with I_t = P(delay > t) for N = 3, q = ∞; I_0 = 1 − p²."""
    it = 1.0 - p * p
    yield it
    for s in range(1, tmax):
        it = it * (1.0 - p) ** 2 + 2.0 * p * (1.0 - p) ** (2 * s + 1)
        yield it
        if it < 1e-15:
            return


def scheme2_qinf_n3_expected_delay(p: float, tmax: int = 2000) -> float:
    """eq. (16): E(delay) = Σ_{t≥1} t (I_{t-1} − I_t)."""
    tails = list(scheme2_qinf_n3_tails(p, tmax))
    return sum(t * (tails[t - 1] - tails[t]) for t in range(1, len(tails)))


def p_delay_gt1_as_printed(n: int, p: float) -> float:
    """eq. (17) exactly as printed."""
    return sum(
        math.comb(n - 1, r) * (1 - p) ** r * p ** (n - 1 - r) * (1 - (1 - (1 - p) ** (n - r)) ** r) for r in range(1, n)
    )


def p_delay_eq1_as_printed(n: int, p: float) -> float:
    """eq. (18) exactly as printed: 1 − P(delay > 1) − p^{N−1}."""
    return 1.0 - p_delay_gt1_as_printed(n, p) - p ** (n - 1)


def p_delay_eq1_exact(n: int, p: float) -> float:
    """P(delay = 1) for q = ∞ by enumerating both steps' link graphs (exact; n ≤ 5).

    Robot 0 computes x̂_{k|k} at k+1 iff for every j: j talked to 0 at k, or some robot that held
    M_k^j after step k (j itself or a robot j talked to at k) talks to 0 at k+1 — and not all at k.
    """
    if n > 5:
        raise ValueError("argument 'n' must be ≤ 5 for exact enumeration")
    pairs = list(itertools.combinations(range(n), 2))
    total = 0.0
    for bits_k in itertools.product((0, 1), repeat=len(pairs)):
        pk = math.prod(p if b else 1 - p for b in bits_k)
        adj = np.zeros((n, n), dtype=bool)
        for (a, b), on in zip(pairs, bits_k, strict=True):
            adj[a, b] = adj[b, a] = bool(on)
        if adj[0, 1:].all():
            continue  # delay 0
        # holders of M_k^j after step k (besides robot 0), for each j robot 0 still lacks
        needs = [({j} | set(np.nonzero(adj[j])[0].tolist())) - {0} for j in range(1, n) if not adj[0, j]]
        # at step k+1 robot 0 needs a link to one holder of every missing row
        others = list(range(1, n))
        prob = 0.0
        for linked in itertools.product((0, 1), repeat=n - 1):
            s = {o for o, on in zip(others, linked, strict=True) if on}
            if all(h & s for h in needs):
                prob += math.prod(p if on else 1 - p for on in linked)
        total += pk * prob
    return total
