"""EKF for cooperative localization (the estimator of §IV), batched over several filters at once.

State: all N poses stacked, ``X = [x_1, y_1, φ_1, …, x_N, y_N, φ_N]``, covariance P (3N × 3N). One
*column step* k takes x̂_{k-1|k-1} to x̂_{k|k}: propagation with the odometry u_{k-1} of every robot
(eq. (1), unicycle, Q = diag((σ_v·|v_m|)², σ_ω²)), then **one** batch update with every range/bearing
measurement z_k (eq. (2), R = diag((σ_d·d_m)², σ_θ²)), stacked in (observer, target) order. A
centralized EKF running these column steps on all measurements gives x̂_{k|k}; the robots' delayed
centralized estimates run exactly the same column steps on the same packets, so they are identical.

The kernels (``KERNELS``: ``propagate``, ``information``, ``inv``, ``update``, ``column``, and the estimator's
``group_filters`` and ``recent_column``) are compiled (``ekf_numba.py``) and take ``G`` filters at once (shape
``(G, 3N)`` and ``(G, 3N, 3N)``), so that the causal estimates of several robots, each with its own subset of
measurements, cost one call. The update is written in information form (Y = P⁻⁻¹ + Hᵀ W H, algebraically the
Kalman update): a measurement a filter does not hold gets weight W = 0, so it has exactly no effect, and filters
that share a prior share its linearisation. A filter holds a measurement exactly when it holds its observer's
packet, so its rows are masked by observer (``Geometry.obs_of_row``). Headings are wrapped into (-π, π] once per
column, after the update: the prior's heading only enters through cos, sin and the wrapped bearing residual, so
leaving it unwrapped changes nothing. The same kernels written in numpy are their oracle
(``tests/helpers/asynccl_reference.py``, #44: one implementation in the package).
"""

from __future__ import annotations

import types

import numpy as np

from mrcomm_env.asynccl import ekf_numba

KERNELS = types.SimpleNamespace(
    propagate=ekf_numba.propagate,
    information=ekf_numba.information,
    inv=ekf_numba.inv,
    update=ekf_numba.update,
    column=ekf_numba.column,
    group_filters=ekf_numba.group_filters,
    recent_column=ekf_numba.recent_column,
)


class Geometry:
    """One sensing graph (observer ids ``a``, target ids ``b``, ``m`` measurements), which recurs over many steps.

    Rows 2j and 2j+1 of the whitened measurement matrix are the range and bearing rows of measurement j
    (eq. (2)): range ∓(Δx, Δy)/d at a / b; bearing (Δy, −Δx)/d², −1 at a and (−Δy, Δx)/d² at b, each times
    √w (√w = 1/(σ_d z_d) for a range row, 1/σ_θ for a bearing row), with the whitened residual in column 3N.
    """

    def __init__(self, a, b, n):
        a, b = np.ascontiguousarray(a, dtype=np.int64), np.ascontiguousarray(b, dtype=np.int64)
        self.a, self.b, self.n, self.m = a, b, n, len(a)
        self.obs_of_row = np.repeat(a, 2)  # a filter holds a row iff it holds its observer's packet
