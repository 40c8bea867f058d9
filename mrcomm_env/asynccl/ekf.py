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
share a prior share its linearisation (``update_shared``).
"""

from __future__ import annotations

from functools import cache

import numpy as np
from numpy.linalg import _umath_linalg

from mrcomm_env.asynccl.world import wrap


@cache
def _prop_index(n: int):
    n3 = 3 * n
    v = np.arange(n) * 3
    fidx = np.concatenate([v * n3 + v + 2, (v + 1) * n3 + v + 2])  # ∂x/∂φ, ∂y/∂φ entries of F
    qidx = np.concatenate([v * n3 + v, (v + 1) * n3 + v + 1, v * n3 + v + 1, (v + 1) * n3 + v, (v + 2) * n3 + v + 2])
    return np.eye(n3), fidx, qidx


def propagate(X, P, u, qv, qw, dt):
    """Batched unicycle propagation, eq. (1). u: (G, N, 2) velocities; qv, qw: (G, N) variances of v, ω."""
    G, n3 = X.shape
    n = n3 // 3
    eye, fidx, qidx = _prop_index(n)
    phi = X[:, 2::3]
    c, s = np.cos(phi), np.sin(phi)
    vdt = u[:, :, 0] * dt
    Xn = X.copy()
    Xn[:, 0::3] += vdt * c
    Xn[:, 1::3] += vdt * s
    Xn[:, 2::3] = wrap(phi + u[:, :, 1] * dt)
    F = np.repeat(eye[None], G, axis=0)
    F.reshape(G, -1)[:, fidx] = np.concatenate([-vdt * s, vdt * c], axis=1)
    out = F @ P @ F.transpose(0, 2, 1)
    # + G Q Gᵀ with G = [[c dt, 0], [s dt, 0], [0, dt]] per robot
    qvv = qv * (dt * dt)
    cs = qvv * c * s
    out.reshape(G, -1)[:, qidx] += np.concatenate([qvv * c * c, qvv * s * s, cs, cs, qw * (dt * dt)], axis=1)
    return Xn, out


def jacobian_index(a, b, n3):
    """Flat positions of the 9 non-zero Jacobian entries of every measurement (range row, bearing row)."""
    rr = np.arange(len(a)) * (2 * n3)
    ia, ib = 3 * a, 3 * b
    return np.concatenate([rr + ia, rr + ia + 1, rr + ib, rr + ib + 1,
                           rr + n3 + ia, rr + n3 + ia + 1, rr + n3 + ia + 2, rr + n3 + ib, rr + n3 + ib + 1])


def linearize(X, a, b, z, sd_frac, s_theta, idx=None):
    """Range/bearing Jacobians H (G, 2m, 3N), residuals r (G, 2m) at X, and weights w = 1/R (2m,)."""
    G, n3 = X.shape
    m = len(a)
    Xr = X.reshape(G, n3 // 3, 3)
    dx = Xr[:, b, 0] - Xr[:, a, 0]
    dy = Xr[:, b, 1] - Xr[:, a, 1]
    d2 = np.maximum(dx * dx + dy * dy, 1e-12)
    d = np.sqrt(d2)
    r = np.empty((G, 2 * m))
    r[:, 0::2] = z[:, 0] - d
    r[:, 1::2] = wrap(z[:, 1] - (np.arctan2(dy, dx) - Xr[:, a, 2]))
    ux, uy, vx, vy = dx / d, dy / d, dy / d2, dx / d2
    H = np.zeros((G, 2 * m * n3))
    if idx is None:
        idx = jacobian_index(a, b, n3)
    H[:, idx] = np.concatenate([-ux, -uy, ux, uy, vx, -vy, -np.ones((G, m)), -vx, vy], axis=1)
    w = np.empty(2 * m)
    w[0::2] = 1.0 / (sd_frac * z[:, 0]) ** 2
    w[1::2] = 1.0 / s_theta**2
    return H.reshape(G, 2 * m, n3), r, w


def inv(A):
    """Batched inverse without numpy.linalg.inv's per-call checks (its overhead dominates at 15 × 15)."""
    return _umath_linalg.inv(A, signature="d->d")


def shared_terms(H, r, w):
    """Per-measurement-row information terms of one prior: outer products h hᵀ (2m, 9N²) and h·r (2m, 3N)."""
    n3 = H.shape[1]
    return (H[:, :, None] * H[:, None, :]).reshape(len(H), n3 * n3), H * r[:, None]


def update_shared(Xp, Yp, HH, Hr, w, masks):
    """``update_info`` for G filters that share one prior (one linearisation): two matrix products.

    Y_g = Yp + Σ_rows m_g w hhᵀ and b_g = Σ_rows m_g w h r, with the per-row terms precomputed once.
    """
    n3 = Xp.shape[0]
    wm = np.repeat(masks, 2, axis=1) * w
    G = len(wm)
    Y = (wm @ HH).reshape(G, n3, n3) + Yp
    Pn = inv(Y)
    Pn = 0.5 * (Pn + Pn.transpose(0, 2, 1))
    Xn = Xp + (Pn @ (wm @ Hr)[:, :, None])[:, :, 0]
    Xn[:, 2::3] = wrap(Xn[:, 2::3])
    return Xn, Pn


def update_info(Xp, Yp, H, r, w, prior, masks):
    """EKF update in information form for G filters, each from prior ``prior[g]`` with measurement mask.

    Y = Yp + Hᵀ W H with Yp = P⁻⁻¹, P = Y⁻¹, x = x⁻ + P Hᵀ W r — algebraically the Kalman update; W = diag(1/R) on the
    filter's own measurements and 0 on the ones it does not hold, so masked rows have exactly no effect.
    """
    n3 = Xp.shape[1]
    wm = w[None, :] if masks is None else np.repeat(masks, 2, axis=1) * w[None, :]
    Hp = H[prior]
    HtW = Hp.transpose(0, 2, 1) * wm[:, None, :]
    Y = Yp[prior] + HtW @ Hp
    Pn = inv(Y)
    Pn = 0.5 * (Pn + Pn.transpose(0, 2, 1))
    Xn = Xp[prior] + np.einsum("gij,gj->gi", Pn, np.einsum("gij,gj->gi", HtW, r[prior]))
    Xn.reshape(len(prior), n3 // 3, 3)[:, :, 2] = wrap(Xn.reshape(len(prior), n3 // 3, 3)[:, :, 2])
    return Xn, Pn
