"""Tolerances for comparing two floating-point computations of one quantity, derived from the problem.

Two implementations of the same mathematics — numpy and its numba twin, an LU and a Cholesky inverse, the
information-form filter and a textbook Kalman-form one, a closed form and a recursion — round in different
places and do not return the same bits. How far apart they may legitimately be is a property of the problem,
not a constant: ``atol=1e-9`` failed on one CPU for a well-posed information matrix (κ ≈ 2·10⁵, difference
1.6·10⁻⁹ in a 27 m correction) and is meaningless for the κ ≈ 10¹³ of near-noiseless sensing. Every test that
compares floating-point results of two algorithms or backends takes its tolerance from here; integer and
bookkeeping quantities (tables, bits, indices) are compared exactly.

**One computation.** Both implementations are backward stable: each returns the exact answer of a problem whose
data are perturbed by a relative ``γ_ops ≈ ops·ε`` (ε = 2⁻⁵² ≈ 2.2·10⁻¹⁶, the float64 machine epsilon; ``ops``
the number of roundings along the longest chain that forms one entry: n for a solve with or an inverse of an
n × n matrix, plus the length of the sums that formed that matrix and right-hand side; k for a sum or product
of k terms). By perturbation theory the result then moves by at most ``cond · ops · ε · scale``, with ``cond``
the condition number of the problem and ``scale`` the size of the result:

* solve ``A x = b`` or inverse ``A⁻¹``: ``‖x̂ − x‖ ≤ c·n·ε·κ₂(A)·‖x‖`` (Higham, *Accuracy and Stability of
  Numerical Algorithms*, 2nd ed.: perturbation theory, ch. 7, with the backward errors of LU with partial
  pivoting and a small growth factor, ch. 9, and of Cholesky, ch. 10; inverses, ch. 14), κ₂(A) = σ_max/σ_min
  computed in the test from the matrix actually inverted or solved;
* a formula without cancellation (sums of same-sign terms, products, quotients): cond = 1.

Two implementations each within the bound differ by at most twice it::

    tol = 2 · C · ops · ε · cond · scale,        C = 3

C = 3 covers the constants of the classical bounds (γ_{3n} for LU and for the Cholesky-based inverse) and the
rounding of adding a correction to a state. Norms are 2-norms (``scale``) and a maximum entry is bounded by the
2-norm, so ``max |a − b| ≤ tol`` is what is asserted. These are worst-case bounds; measured differences stay
below 2 % of them (most below 0.1 %; ``docs/architecture.md``, "Compiled twins"), so the tests hold on every
CPU, while a real defect — a dropped noise term, a lost Jacobian entry, a wrong odometry slot — exceeds them
10⁵- to 10¹²-fold, and even a relative 10⁻⁹ change of one formula 10³-fold: the bound's relative size
``2·C·ops·ε·κ`` is 10⁻¹² to 10⁻⁴ in these tests.

**Whole episodes.** Over an episode of an EKF, step k maps the previous estimate to the next; the difference of
two implementations obeys ``e_k ≤ g_k·e_{k−1} + δ_k`` with δ_k the one-step bound above and g_k the step's
error gain. A filter whose linearisation points are near the truth does not amplify a perturbation of its
state: (I − K H) F is a contraction in the metric of P⁻¹, and in the unobservable directions of cooperative
localization (the team's rigid translation and rotation, which only the prior fixes) it is neutral (g = 1).
With g_k ≤ 1 the errors add up::

    tol_T = 2 · C · ops · ε · Σ_{k ≤ T} κ_k · scale,    κ_k = Σ κ₂ of the matrices inverted in step k

(``episode_tolerance``; its relative size β = 2·C·ops·ε·Σκ_k is reported by ``episode_budget``). The bound is
informative while β ≪ 1. When the linearisation is far from the truth (a metres-wide prior with near-noiseless
range/bearing), g_k reaches 10–50 per step and κ 10¹³–10¹⁴: β then exceeds 1, the bound says nothing, and
estimates of one backend with its prior mean moved by one ulp separate by metres just as the two backends do
(``tests/asynccl/test_asynccl_backends.py::test_backends_agree_where_the_filter_is_well_conditioned``).
"""

from __future__ import annotations

import types
from collections.abc import Sequence

import numpy as np

EPS = float(np.finfo(np.float64).eps)
C = 3.0  # constant of the classical forward-error bounds (γ_{3n}: LU and Cholesky inverses, see the module doc)


def condition(matrix, symmetric: bool = False) -> float:
    """κ₂ of a matrix, the largest over a batch (..., n, n); ∞ for a numerically singular one.

    ``symmetric``: the matrix is symmetric up to rounding (a covariance or information matrix), so its singular
    values are the moduli of the eigenvalues of its symmetric part (half the cost of the SVD)."""
    m = np.asarray(matrix, dtype=np.float64)
    m = m.reshape((-1,) + m.shape[-2:])
    if symmetric:
        s = np.abs(np.linalg.eigvalsh(0.5 * (m + m.swapaxes(-1, -2))))
        smin, smax = s.min(axis=1), s.max(axis=1)
    else:
        s = np.linalg.svd(m, compute_uv=False)
        smin, smax = s[:, -1], s[:, 0]
    with np.errstate(divide="ignore"):
        return float(np.max(np.where(smin > 0, smax / smin, np.inf)))


def tolerance(scale: float, ops: int, cond: float = 1.0) -> float:
    """Largest difference of two backward-stable computations: 2·C·ops·ε·cond·scale (module doc)."""
    return 2.0 * C * ops * EPS * cond * float(scale)


def solve_tolerance(matrix, scale: float, ops: int | None = None) -> float:
    """Bound for two solves with / inverses of ``matrix`` (a batch: its worst member): 2·C·ops·ε·κ₂(matrix)·scale.

    ``ops`` defaults to the dimension n; add the length of the sums that formed the matrix and right-hand side
    when the two implementations form them differently (an information matrix summed over m rows: n + m)."""
    m = np.asarray(matrix)
    return tolerance(scale, m.shape[-1] if ops is None else ops, condition(m))


def episode_budget(conds: Sequence[float], ops: int) -> np.ndarray:
    """β_T = 2·C·ops·ε·Σ_{k ≤ T} κ_k for every step T: the relative size of ``episode_tolerance``."""
    return 2.0 * C * ops * EPS * np.cumsum(np.asarray(conds, dtype=np.float64))


def episode_tolerance(conds: Sequence[float], scale: float, ops: int) -> np.ndarray:
    """Bound after every step of an episode (module doc): 2·C·ops·ε·Σ_{k ≤ T} κ_k·scale, κ_k per step."""
    return episode_budget(conds, ops) * float(scale)


def assert_close_conditioned(actual, desired, tol: float, angles=None, err_msg: str = "") -> None:
    """max |actual − desired| ≤ tol, entries at ``angles`` (an index into the last axis) compared modulo 2π.

    ``tol`` is a bound from this module; on failure the message gives the difference in units of it."""
    a, d = np.asarray(actual, dtype=np.float64), np.asarray(desired, dtype=np.float64)
    assert a.shape == d.shape, f"shapes differ: {a.shape} vs {d.shape} {err_msg}"
    diff = a - d
    if angles is not None:
        diff[..., angles] = (diff[..., angles] + np.pi) % (2.0 * np.pi) - np.pi
    worst = float(np.max(np.abs(diff), initial=0.0))
    if not worst <= tol:  # also fails on NaN
        raise AssertionError(
            f"max |difference| {worst:.3e} exceeds the derived bound {tol:.3e} "
            f"({worst / tol if tol > 0 else np.inf:.1f}× it) {err_msg}"
        )


# --------------------------------------------------------------------------- AsyncCL's EKF kernels
HEADINGS = slice(2, None, 3)  # the headings in AsyncCL's stacked poses [x_1, y_1, φ_1, …]: compared modulo 2π


def information_matrices(Xp, Yp, A, hold, prior=None):
    """The matrices ``update`` inverts, Y_g = Y⁻_p + Σ_held ā ā (ā the whitened rows of ``ekf.information``)."""
    Xp, Yp, A = np.asarray(Xp), np.asarray(Yp), np.asarray(A)
    if Xp.ndim == 1:
        Xp, Yp, A = Xp[None], Yp[None], A[None]
        prior = np.zeros(len(hold), dtype=np.int64) if prior is None else prior
    elif prior is None:
        prior = np.arange(len(hold))
    prior = np.asarray(prior)
    n3 = Xp.shape[-1]
    Ap = A[prior]
    return (Ap.swapaxes(-1, -2) @ (Ap * hold[:, :, None]))[:, :n3, :n3] + Yp[prior]


class ConditionLog:
    """Wraps an EKF kernel namespace (``ekf.KERNELS``, or its numpy oracle ``asynccl_reference.NUMPY_KERNELS``) and
    records κ_k per step k: the sum over the step's kernel calls of the largest κ₂ among the matrices the call
    inverts — prior covariances P⁻ (``inv``, ``column``) and information matrices Y (``update``, ``column``). Calls
    of one step chain (P⁻ → Y⁻ → Y → P, one column after another when a filter restarts), so their bounds add; the
    filters of one batched call run side by side, so their worst one counts. Set ``step`` before a step's calls;
    ``conds(T)`` gives κ_0 … κ_{T−1}."""

    def __init__(self, kernels=None):
        self.kernels, self.step, self.kappa = kernels, 0, {}

    def _note(self, matrices):
        self.kappa[self.step] = self.kappa.get(self.step, 0.0) + condition(matrices, symmetric=True)

    def namespace(self) -> types.SimpleNamespace:
        k = self.kernels

        def inv(P):
            self._note(P)
            return k.inv(P)

        def update(Xp, Yp, A, hold, prior=None, geo=None):
            self._note(information_matrices(Xp, Yp, A, hold, prior))
            return k.update(Xp, Yp, A, hold, prior, geo)

        def column(Xs, Ps, ud, geo, z, inv_sd, inv_sth, hold, prior):
            out = k.column(Xs, Ps, ud, geo, z, inv_sd, inv_sth, hold, prior)
            Xp, Yp, A = out[:3]
            self._note(Yp)  # κ(Y⁻) = κ(P⁻), the propagated covariance ``column`` inverted
            self._note(information_matrices(Xp, Yp, A, hold, prior))
            return out

        # the others pass through unrecorded (``group_filters``, and ``recent_column``, whose inversions are opaque)
        return types.SimpleNamespace(**{**vars(k), "inv": inv, "update": update, "column": column})

    def conds(self, steps: int) -> np.ndarray:
        return np.array([self.kappa.get(t, 1.0) for t in range(steps)])


def bit_identical(a, b) -> bool:
    """The exact twins' comparison: arrays (and numbers) by dtype and bytes, dicts (per agent) key by key."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(bit_identical(a[key], b[key]) for key in a)
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
