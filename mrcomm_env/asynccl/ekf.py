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
observer's packet, so its rows are masked by observer (``Geometry.obs_of_row``).

Every call on these small arrays costs about a microsecond whatever its size, so the functions are
written for few calls:

* the whitened rows [√W H | √W r] of a column are ten numbers per measurement scattered into a
  constant template (``Geometry``, per sensing graph), and one Gram product over the rows a filter
  holds, ``[[Hᵀ W H, Hᵀ W r], [·, ·]]``, gives its information matrix *and* vector (``update``);
* propagation is one product with an augmented Jacobian [F | Γ √Q] (``_prop_templates``);
* headings are wrapped into (-π, π] once per column, after the update: the prior's heading only
  enters through cos, sin and the wrapped bearing residual, so leaving it unwrapped changes nothing.
"""

from __future__ import annotations

import sys
import types
from functools import cache

import numpy as np
from numpy.linalg import _umath_linalg

from mrcomm_env.asynccl import ekf_numba
from mrcomm_env.core.backend import name as backend_name

TWO_PI = 2.0 * np.pi
MIN_DISTANCE = 1e-6  # guards the Jacobian of two estimates at the same place (the sensor gives d ≥ 5 cm)


@cache
def _prop_templates(n: int, G: int):
    """Templates of the augmented propagation for G filters, and where the state-dependent entries go.

    Fa = [F | Γ√Q | 0] is (3N, 5N+1) and Pa = diag(P, I_2N, 0), so Fa Pa Faᵀ = F P Fᵀ + Γ Q Γᵀ. Per robot,
    ``propagate`` forms the 12 products (v dt, σ_v dt, σ_ω dt) ⊗ (cos φ, −sin φ, sin φ, 1) in one call and
    scatters them in one call; the 7 products the Jacobian does not use all land on the spare last column
    of row 0, which meets a zero row and column of Pa and so contributes exactly nothing.
    """
    n3, na = 3 * n, 5 * n + 1
    v = np.arange(n)
    fa = np.zeros((n3, na))
    fa[:, :n3] = np.eye(n3)
    pa = np.zeros((na, na))
    pa[n3 : 5 * n, n3 : 5 * n] = np.eye(2 * n)
    tgt = np.full((n, 3, 4), 5 * n)  # (row 0, spare column)
    tgt[:, 0, 0] = (3 * v + 1) * na + 3 * v + 2  # ∂y/∂φ = v dt cos φ
    tgt[:, 0, 1] = 3 * v * na + 3 * v + 2  # ∂x/∂φ = −v dt sin φ
    tgt[:, 1, 0] = 3 * v * na + n3 + 2 * v  # Γ√Q, velocity noise: σ_v dt (cos φ, sin φ, 0)
    tgt[:, 1, 2] = (3 * v + 1) * na + n3 + 2 * v
    tgt[:, 2, 3] = (3 * v + 2) * na + n3 + 2 * v + 1  # Γ√Q, turn-rate noise: σ_ω dt on φ
    idx = (np.arange(G)[:, None] * (n3 * na) + tgt.reshape(1, -1)).ravel()
    return np.repeat(fa[None], G, axis=0), np.repeat(pa[None], G, axis=0), idx


def propagate(X, P, ud):
    """Batched unicycle propagation, eq. (1). ud: (G, N, 4) odometry per robot as [v dt, σ_v dt, σ_ω dt, ω dt].

    x⁺ = x + v dt cos φ, y⁺ = y + v dt sin φ, φ⁺ = φ + ω dt (left unwrapped, see the module doc), and
    P⁺ = F P Fᵀ + Γ Q Γᵀ with F = ∂f/∂x (∂x/∂φ = −v dt sin φ, ∂y/∂φ = v dt cos φ) and
    Γ = ∂f/∂(v, ω) = [[c dt, 0], [s dt, 0], [0, dt]], computed as one product Fa Pa Faᵀ (``_prop_templates``).
    """
    G, n3 = X.shape
    n = n3 // 3
    fa, pa, idx = _prop_templates(n, G)
    k = np.empty((G, n, 4))
    phi = X[:, 2::3]
    np.cos(phi, out=k[:, :, 0])
    np.sin(phi, out=k[:, :, 2])
    np.negative(k[:, :, 2], out=k[:, :, 1])
    k[:, :, 3] = 1.0
    prod = k[:, :, None, :] * ud[:, :, :3, None]  # (G, N, 3, 4)
    Xn = X.copy()
    Xr = Xn.reshape(G, n, 3)
    Xr[:, :, :2] += prod[:, :, 0, ::2]  # v dt (cos φ, sin φ)
    Xr[:, :, 2] += ud[:, :, 3]
    Fa = fa.copy()
    Fa.reshape(-1)[idx] = prod.reshape(-1)
    Pa = pa.copy()
    Pa[:, :n3, :n3] = P
    return Xn, Fa @ Pa @ Fa.transpose(0, 2, 1)


class Geometry:
    """Constant tables of one sensing graph (observer ids ``a``, target ids ``b``), which recurs over many steps.

    Rows 2j and 2j+1 of the whitened measurement matrix are the range and bearing rows of measurement j
    (eq. (2)): range ∓(Δx, Δy)/d at a / b; bearing (Δy, −Δx)/d², −1 at a and (−Δy, Δx)/d² at b, each times
    √w (√w = 1/(σ_d z_d) for a range row, 1/σ_θ for a bearing row), with the whitened residual in column 3N.
    """

    def __init__(self, a, b, n, inv_sth):
        a, b = np.ascontiguousarray(a, dtype=np.int64), np.ascontiguousarray(b, dtype=np.int64)
        m = len(a)
        self.a, self.b, self.n, self.m = a, b, n, m
        rows = np.arange(m)
        # S @ poses: rows < m give x_b − x_a (relative positions), rows ≥ m give x_a (the observer's heading)
        self.S = np.zeros((2 * m, n))
        self.S[rows, b] = 1.0
        self.S[rows, a] -= 1.0
        self.S[m + rows, a] = 1.0
        self.obs_of_row = np.repeat(a, 2)  # a filter holds a row iff it holds its observer's packet
        K = 3 * n + 1
        self.template = np.zeros((2 * m, K))
        self.template[2 * rows + 1, 3 * a + 2] = -inv_sth  # bearing row: −1 on the observer's heading
        rng_row, brg_row = 2 * rows * K, (2 * rows + 1) * K
        # where ``information``'s ten numbers per measurement go (its buffer ``B``, shape (m, 2, 5))
        self._pos = np.stack(
            [
                rng_row + 3 * b,
                rng_row + 3 * b + 1,
                brg_row + 3 * a,
                brg_row + 3 * a + 1,
                rng_row + 3 * n,
                rng_row + 3 * a,
                rng_row + 3 * a + 1,
                brg_row + 3 * b,
                brg_row + 3 * b + 1,
                brg_row + 3 * n,
            ],
            axis=1,
        ).ravel()
        self._flat: dict = {}

    def positions(self, G):
        """Flat positions of ``information``'s numbers for G filters at once."""
        f = self._flat.get(G)
        if f is None:
            f = self._flat[G] = (np.arange(G)[:, None] * self.template.size + self._pos[None]).ravel()
        return f


def information(X, geo, z, inv_sd, inv_sth):
    """Whitened measurement rows [√W H | √W r] of column k linearised at the priors X (eq. (2)): (G, 2m, 3N+1).

    ``z`` holds the column's measurements [d, θ] (m, 2). With these rows ā, a filter's information matrix
    and vector are the Gram matrix Σ ā āᵀ over the rows it holds (``update``).
    """
    G, n3 = X.shape
    n, m = n3 // 3, geo.m
    sr = inv_sd / z[:, 0]  # √w of the range rows, 1/(σ_d z_d)
    z1pi = z[:, 1] + np.pi
    V = geo.S @ X.reshape(G, n, 3)
    D = V[:, :m, :2]  # (G, m, [Δx, Δy])
    d = np.hypot(D[:, :, 0], D[:, :, 1])
    np.maximum(d, MIN_DISTANCE, out=d)
    B = np.empty((G, m, 2, 5))  # per measurement [u, (p_0, −p_1), r_range], then [−u, (−p_0, p_1), r_bearing]
    np.multiply(D, (sr / d)[:, :, None], out=B[:, :, 0, :2])  # u = √w (Δx, Δy)/d
    np.multiply(D[:, :, ::-1], (inv_sth / (d * d))[:, :, None], out=B[:, :, 0, 2:4])  # p = √w (Δy, Δx)/d²
    B[:, :, 0, 3] *= -1.0
    np.negative(B[:, :, 0, :4], out=B[:, :, 1, :4])
    rr = B[:, :, 0, 4]  # whitened range residual (z_d − d)/(σ_d z_d)
    np.multiply(d, sr, out=rr)
    np.subtract(inv_sd, rr, out=rr)
    br = np.arctan2(D[:, :, 1], D[:, :, 0])  # bearing residual z_θ − (atan2(Δy, Δx) − φ_a), wrapped, whitened
    np.subtract(V[:, m:, 2], br, out=br)
    br += z1pi
    np.remainder(br, TWO_PI, out=br)
    br -= np.pi
    np.multiply(br, inv_sth, out=B[:, :, 1, 4])
    A = np.repeat(geo.template[None], G, axis=0)
    A.reshape(-1)[geo.positions(G)] = B.reshape(-1)
    return A


def column(Xs, Ps, ud, geo, z, inv_sd, inv_sth, hold, prior):
    """One column step for several filters: propagate the priors (Xs, Ps) with odometry ``ud`` (eq. (1)),
    linearise the column's measurements ``z`` at them (eq. (2)), and update filter g from prior ``prior[g]``
    with the rows ``hold[g]``. Returns the priors' (X⁻, Y⁻ = P⁻⁻¹, rows A) and the filters' (X, P)."""
    Xp, Pp = propagate(Xs, Ps, ud)
    A = information(Xp, geo, z, inv_sd, inv_sth)
    Yp = inv(Pp)
    Xn, Pn = update(Xp, Yp, A, hold, prior)
    return Xp, Yp, A, Xn, Pn


def inv(A):
    """Batched inverse without numpy.linalg.inv's per-call checks (its overhead dominates at 15 × 15)."""
    return _umath_linalg.inv(A, signature="d->d")


def update(Xp, Yp, A, hold, prior=None, geo=None):
    """EKF update in information form for G filters with priors (Xp, Yp = P⁻⁻¹, rows A) and row masks ``hold`` (G, 2m).

    Y = Yp + Hᵀ W_f H, P = Y⁻¹, x = x⁻ + P Hᵀ W_f r — algebraically the Kalman update of eq. (2) with
    W_f = diag(1/R) on the rows the filter holds and 0 on the others (they have exactly no effect). Both
    terms come from one Gram product of the whitened rows ``A`` (``information``) of the filter's prior;
    filters sharing a prior may pass the same (Xp, Yp, A) (broadcast), or ``prior[g]``, the index of filter g's
    prior among several. (``geo``, the column's ``Geometry``, is used by the compiled twin only.)
    """
    if prior is not None:
        Xp, Yp, A = Xp[prior], Yp[prior], A[prior]
    G, m2 = hold.shape
    n3 = Xp.shape[-1]
    YA = A.swapaxes(-1, -2) @ (A * hold[:, :, None])  # (G, 3N+1, 3N+1): [[Hᵀ W H, Hᵀ W r], [·, ·]]
    Pn = inv(YA[:, :n3, :n3] + Yp)
    Pn += Pn.transpose(0, 2, 1)  # symmetrise: 0.5 (P + Pᵀ) (numpy buffers the overlapping operand)
    Pn *= 0.5
    Xn = (Pn @ YA[:, :n3, n3:]).reshape(G, n3)
    Xn += Xp
    th = Xn[:, 2::3]  # wrap the headings into (-π, π] in place (``world.wrap``)
    th += np.pi
    np.remainder(th, TWO_PI, out=th)
    th -= np.pi
    return Xn, Pn


@cache
def backend(name: str | None = None) -> types.SimpleNamespace:
    """The EKF kernels (``propagate``, ``information``, ``inv``, ``update``, ``column``): the numba twins of ``ekf_numba.py``
    when ``core.backend`` says compiled code runs (or ``name="numba"``), this module's otherwise."""
    name = name or backend_name()
    module = ekf_numba if name == "numba" else sys.modules[__name__]
    return types.SimpleNamespace(
        name=name,
        propagate=module.propagate,
        information=module.information,
        inv=module.inv,
        update=module.update,
        column=module.column,
        # the restart loop of ``Estimators._step_recent`` in one call (compiled only: numpy runs the loop)
        restart_chains=getattr(module, "restart_chains", None),
        # the rest of that step too: restarts, extended estimates and column t in one call (compiled only)
        recent_column=getattr(module, "recent_column", None),
        # and how the robots of such a step share their filters (compiled only)
        group_filters=getattr(module, "group_filters", None),
    )
