"""EKF for cooperative localization (the estimator of §IV), batched over several filters at once.

State: all N poses stacked, ``X = [x_1, y_1, φ_1, …, x_N, y_N, φ_N]``, covariance P (3N × 3N). One
*column step* k takes x̂_{k-1|k-1} to x̂_{k|k}: propagation with the odometry u_{k-1} of every robot
(eq. (1), unicycle, Q = diag((σ_v·|v_m|)², σ_ω²)), then **one** batch update with every range/bearing
measurement z_k (eq. (2), R = diag((σ_d·d_m)², σ_θ²)), stacked in (observer, target) order. A
centralized EKF running these column steps on all measurements gives x̂_{k|k}; the robots' delayed
centralized estimates run exactly the same column steps on the same packets, so they are identical.

The functions take ``G`` filters at once (shape ``(G, 3N)`` and ``(G, 3N, 3N)``) so that the causal
estimates of several robots, each with its own subset of measurements, cost one set of numpy calls.
The update is written in information form (Y = P⁻⁻¹ + Hᵀ W H, algebraically the Kalman update):
a measurement a filter does not hold gets weight W = 0, so it has exactly no effect, and filters that
share a prior share its linearisation. A filter holds a measurement exactly when it holds its
observer's packet, so Hᵀ W H and Hᵀ W r are sums of per-observer terms (``info_terms``), computed once
per linearisation; each filter's update is then a small product with its (N,) observer mask (``update``).

Every call on these small arrays costs about a microsecond whatever its size, so the functions are
written for few calls: index tables are cached per sensing graph (``Geometry``) and batch size
(``_prop_index``), and propagation is a single product with an augmented Jacobian.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from numpy.linalg import _umath_linalg

# which of [u_x, u_y, Δx/d², Δy/d², 1] fills each of the 9 Jacobian entries of a measurement, and its sign
# (order of ``jacobian_index``: range row at a, at b, then bearing row at a, at b)
JAC_PICK = np.array([0, 1, 0, 1, 3, 2, 4, 3, 2])
JAC_SIGN = np.array([-1.0, -1.0, 1.0, 1.0, 1.0, -1.0, -1.0, -1.0, 1.0])


@cache
def _prop_index(n: int, dt: float, G: int):
    """Templates of the augmented propagation for G filters: [F | Γ] (G, 3N, 5N) with its constant entries, the
    flat positions of its state-dependent entries and of Q in diag(P, Q) (G, 5N, 5N)."""
    n3, n5 = 3 * n, 5 * n
    v = np.arange(n)
    fa = np.zeros((n3, n5))
    fa[:, :n3] = np.eye(n3)
    fa[3 * v + 2, n3 + 2 * v + 1] = dt  # ∂φ/∂ω
    # per robot: ∂x/∂φ, ∂y/∂φ (F), ∂x/∂v, ∂y/∂v (Γ)
    fidx = np.stack([3 * v * n5 + 3 * v + 2, (3 * v + 1) * n5 + 3 * v + 2,
                     3 * v * n5 + n3 + 2 * v, (3 * v + 1) * n5 + n3 + 2 * v], axis=1).ravel()
    qidx = np.stack([(n3 + 2 * v) * (n5 + 1), (n3 + 2 * v + 1) * (n5 + 1)], axis=1).ravel()  # σ_v², σ_ω²
    g = np.arange(G)[:, None]
    return np.repeat(fa[None], G, axis=0), (g * n3 * n5 + fidx).ravel(), (g * n5 * n5 + qidx).ravel()


def propagate(X, P, uq, dt):
    """Batched unicycle propagation, eq. (1). uq: (G, N, 4) odometry [v, ω] and its variances [σ_v², σ_ω²].

    P⁺ = F P Fᵀ + Γ Q Γᵀ is computed as one product [F | Γ] diag(P, Q) [F | Γ]ᵀ, with the per-robot
    Jacobians F = ∂f/∂x (∂x/∂φ = −v dt sin φ, ∂y/∂φ = v dt cos φ) and Γ = ∂f/∂(v, ω) = [[c dt, 0], [s dt, 0], [0, dt]].
    """
    G, n3 = X.shape
    n = n3 // 3
    fa, fidx, qidx = _prop_index(n, float(dt), G)
    Xr = X.reshape(G, n, 3)
    phi = Xr[:, :, 2]
    e = np.empty((G, n, 4))  # per robot: −v s dt, v c dt, c dt, s dt
    np.multiply(np.cos(phi), dt, out=e[:, :, 2])
    np.multiply(np.sin(phi), dt, out=e[:, :, 3])
    np.multiply(e[:, :, 2:], uq[:, :, :1], out=e[:, :, 1::-1])
    e[:, :, 0] *= -1.0
    Xn = X.copy()
    Xnr = Xn.reshape(G, n, 3)
    Xnr[:, :, 0] += e[:, :, 1]
    Xnr[:, :, 1] -= e[:, :, 0]
    th = phi + uq[:, :, 1] * dt
    th += np.pi  # wrap into (-π, π] (``world.wrap``)
    np.remainder(th, 2.0 * np.pi, out=th)
    np.subtract(th, np.pi, out=Xnr[:, :, 2])
    Fa = fa.copy()
    Fa.reshape(-1)[fidx] = e.reshape(-1)
    Pa = np.zeros((G, 5 * n, 5 * n))
    Pa[:, :n3, :n3] = P
    Pa.reshape(-1)[qidx] = uq[:, :, 2:].reshape(-1)
    return Xn, Fa @ Pa @ Fa.transpose(0, 2, 1)


def jacobian_index(a, b, n3):
    """Flat positions of the 9 non-zero Jacobian entries of every measurement (range row, bearing row).

    Measurement-major: entries e of measurement j sit at 9 j + e, in the order of ``JAC_PICK``.
    """
    rr = np.arange(len(a)) * (2 * n3)
    ia, ib = 3 * a, 3 * b
    return np.stack([rr + ia, rr + ia + 1, rr + ib, rr + ib + 1,
                     rr + n3 + ia, rr + n3 + ia + 1, rr + n3 + ia + 2, rr + n3 + ib, rr + n3 + ib + 1], axis=1).ravel()


class Geometry:
    """Index tables of one sensing graph (observer ids ``a``, target ids ``b``), which recurs over many steps."""

    def __init__(self, a, b, n):
        m = len(a)
        self.a, self.b, self.n, self.m = a, b, n, m
        # S @ poses: rows < m give x_b − x_a (relative positions), rows ≥ m give x_a (the observer's heading)
        self.S = np.zeros((2 * m, n))
        self.S[np.arange(m), b] = 1.0
        self.S[np.arange(m), a] -= 1.0
        self.S[m + np.arange(m), a] = 1.0
        self.idx = jacobian_index(a, b, 3 * n)
        self.full = m == n * (n - 1)  # every robot sees every other: rows come in n equal blocks per observer
        self._flat: dict = {}

    def flat(self, G):
        """Flat Jacobian positions for G filters at once."""
        f = self._flat.get(G)
        if f is None:
            f = self._flat[G] = (np.arange(G)[:, None] * (6 * self.m * self.n) + self.idx[None]).ravel()
        return f

    def weights(self, z, sd_frac, s_theta):
        """w = 1/R of eq. (2) per measurement row (R = diag((σ_d d)², σ_θ²)) and, unless every robot sees every
        other, the (N, 2m) matrix A with A[v, row] = w_row for the rows robot v measured."""
        m = self.m
        w = np.empty(2 * m)
        w[0::2] = 1.0 / (sd_frac * z[:, 0]) ** 2
        w[1::2] = 1.0 / s_theta**2
        if self.full:
            return w, None
        A = np.zeros((self.n, 2 * m))
        A[np.repeat(self.a, 2), np.arange(2 * m)] = w
        return w, A


def linearize(X, geo, z):
    """Range/bearing Jacobians H (G, 2m, 3N) and residuals r (G, 2m) at X (eq. (2))."""
    G, n3 = X.shape
    m = geo.m
    V = geo.S @ X.reshape(G, n3 // 3, 3)
    D = V[:, :m, :2]  # (G, m, [Δx, Δy])
    d2 = np.einsum("gmk,gmk->gm", D, D)
    np.maximum(d2, 1e-12, out=d2)
    d = np.sqrt(d2)
    r = np.empty((G, m, 2))
    np.subtract(z[:, 0], d, out=r[:, :, 0])
    br = np.arctan2(D[:, :, 1], D[:, :, 0])
    br -= V[:, m:, 2]
    np.subtract(z[:, 1], br, out=br)
    # wrap into (-π, π] in place (``world.wrap``)
    br += np.pi
    np.remainder(br, 2.0 * np.pi, out=br)
    np.subtract(br, np.pi, out=r[:, :, 1])
    # range row: ∓(Δx, Δy)/d at a / b; bearing row: (Δy, −Δx)/d², −1 at a and (−Δy, Δx)/d² at b
    q = np.empty((G, m, 5))
    q[:, :, 4] = 1.0
    np.divide(D, d[:, :, None], out=q[:, :, :2])
    np.divide(D, d2[:, :, None], out=q[:, :, 2:4])
    H = np.zeros((G, 2 * m, n3))
    H.reshape(-1)[geo.flat(G)] = (q[:, :, JAC_PICK] * JAC_SIGN).reshape(-1)
    return H, r.reshape(G, 2 * m)


def info_terms(H, r, w, A):
    """Per-observer information of G linearisations: J_v = Σ_rows(v) w h hᵀ (G, N, 9N²), β_v = Σ_rows(v) w h r (G, N, 3N).

    With these, the update of eq. (2) for a filter holding the packets of the robots in mask M is
    Y = Y⁻ + Σ_v M_v J_v and b = Σ_v M_v β_v (the information form of the batch EKF update). A filter holds a
    measurement exactly when it holds its observer's packet, so the sums run over observers; ``A`` (or, when
    every robot sees every other, the equal blocks of rows) groups the rows by observer.
    """
    G, m2, n3 = H.shape
    if A is None:
        n = n3 // 3
        HW = (H * w[:, None]).reshape(G, n, m2 // n, n3).transpose(0, 1, 3, 2)
        return (HW @ H.reshape(G, n, m2 // n, n3)).reshape(G, n, n3 * n3), (HW @ r.reshape(G, n, m2 // n, 1))[..., 0]
    HH = (H[:, :, :, None] * H[:, :, None, :]).reshape(G, m2, n3 * n3)
    return A @ HH, A @ (H * r[:, :, None])


def inv(A):
    """Batched inverse without numpy.linalg.inv's per-call checks (its overhead dominates at 15 × 15)."""
    return _umath_linalg.inv(A, signature="d->d")


def update(Xp, Yp, J, beta, M):
    """EKF update in information form for G filters with priors (Xp, Yp = P⁻⁻¹) and observer masks M (G, N).

    Y = Yp + Σ_v M_v J_v, P = Y⁻¹, x = x⁻ + P Σ_v M_v β_v — algebraically the Kalman update of eq. (2) with
    W = diag(1/R) on the filter's own measurements and 0 on the ones it does not hold (they have exactly
    no effect). ``J`` and ``beta`` are ``info_terms`` of each filter's prior, so filters sharing a prior
    may pass the same arrays (broadcast): one small matrix product per update.
    """
    G = len(M)
    n3 = Xp.shape[-1]
    Mr = M[:, None, :]
    Y = (Mr @ J).reshape(G, n3, n3)
    Y += Yp
    Pn = inv(Y)
    Pn += Pn.transpose(0, 2, 1)  # symmetrise: 0.5 (P + Pᵀ) (numpy buffers the overlapping operand)
    Pn *= 0.5
    Xn = (Pn @ (Mr @ beta).reshape(G, n3, 1)).reshape(G, n3)
    Xn += Xp
    th = Xn[:, 2::3]  # wrap the headings into (-π, π] in place (``world.wrap``)
    th += np.pi
    np.remainder(th, 2.0 * np.pi, out=th)
    th -= np.pi
    return Xn, Pn
