"""AsyncCL's EKF kernels, the estimator's common step, its observation and team errors, written in numpy: the oracles
of their compiled kernels (``ekf_numba``, ``env_numba``).

The env runs each in compiled calls (``ekf.KERNELS``, ``AsyncCLEnv._observe``, ``_errors``); these are the same
formulas as §IV and the module's table state them, in numpy's own calls and reduction order, kept here and not in
the package (#44: one implementation in the package, the reference under tests/).

* ``NUMPY_KERNELS``: the column step (eq. (1) propagation, the whitened rows of eq. (2), the information-form update)
  as dense numpy products, with an LU inverse where the kernels use a Cholesky factor; so they agree with the
  kernels within the forward-error bound of the matrices they invert (``tests/asynccl/test_asynccl_backends.py``).
* ``ReferenceEstimators``: ``Estimators`` whose common step (every robot exact) groups the robots in Python and runs
  the restarting filters' columns as a loop of batched kernel calls, with whichever kernels it is given
  (``use_reference``); with the compiled ones it gives the env's bytes (``tests/asynccl/test_asynccl_fastpath.py``).
* The observation and team errors, compared with the env's byte for byte at every step of whole episodes
  (``tests/asynccl/test_asynccl.py``)."""

from __future__ import annotations

import types
import weakref
from functools import cache

import numpy as np
from numpy.linalg import _umath_linalg

from mrcomm_env.asynccl.env import AGE_SCALE, BITS_SCALE, OTHER_FEATURES, OWN_FEATURES
from mrcomm_env.asynccl.estimator import Estimators

TWO_PI = 2.0 * np.pi
MIN_DISTANCE = 1e-6  # as ``ekf_numba.MIN_DISTANCE``: the Jacobian of two estimates at the same place


_TABLES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _tables(geo, inv_sth):
    """The constant tables ``information`` scatters into, per sensing graph (``ekf.Geometry``) and σ_θ: ``S`` with
    S @ poses giving x_b − x_a (rows < m) and x_a (rows ≥ m), the rows' ``template`` (−1/σ_θ on the observer's
    heading in each bearing row) and where its ten numbers per measurement go (``pos``)."""
    per_graph = _TABLES.setdefault(geo, {})
    if inv_sth not in per_graph:
        a, b, n, m = geo.a, geo.b, geo.n, geo.m
        rows = np.arange(m)
        S = np.zeros((2 * m, n))
        S[rows, b] = 1.0
        S[rows, a] -= 1.0
        S[m + rows, a] = 1.0
        K = 3 * n + 1
        template = np.zeros((2 * m, K))
        template[2 * rows + 1, 3 * a + 2] = -inv_sth
        rng_row, brg_row = 2 * rows * K, (2 * rows + 1) * K
        pos = np.stack(
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
        per_graph[inv_sth] = S, template, pos
    return per_graph[inv_sth]


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


def information(X, geo, z, inv_sd, inv_sth):
    """Whitened measurement rows [√W H | √W r] of column k linearised at the priors X (eq. (2)): (G, 2m, 3N+1).

    ``z`` holds the column's measurements [d, θ] (m, 2). With these rows ā, a filter's information matrix
    and vector are the Gram matrix Σ ā āᵀ over the rows it holds (``update``).
    """
    G, n3 = X.shape
    n, m = n3 // 3, geo.m
    sr = inv_sd / z[:, 0]  # √w of the range rows, 1/(σ_d z_d)
    z1pi = z[:, 1] + np.pi
    S, template, pos = _tables(geo, inv_sth)
    V = S @ X.reshape(G, n, 3)
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
    A = np.repeat(template[None], G, axis=0)
    A.reshape(-1)[(np.arange(G)[:, None] * template.size + pos[None]).ravel()] = B.reshape(-1)
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
    prior among several. (``geo``, the column's ``Geometry``, is used by the compiled kernel only.)
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


NUMPY_KERNELS = types.SimpleNamespace(
    propagate=propagate, information=information, inv=inv, update=update, column=column
)


class ReferenceEstimators(Estimators):
    """``Estimators`` whose common step runs in Python over the kernels ``self.k``: the robots grouped by ``_groups``,
    the restarting filters' columns c+1 … t-1 as a loop of batched ``update``/``column`` calls (or, when ``self.k``
    has ``recent_column``, that one call after the Python grouping)."""

    def _step_recent(self, t, c, L, cache_ok):
        return self._python_recent(t, L, *self._groups(t, c.tolist(), L, cache_ok, True))

    def _slots(self, src):
        """Ring slots of the odometry of steps ``src``; step -1 (none of that robot yet) is the standstill slot."""
        return src % self.W if self._sources_known else np.where(src < 0, self.W, src % self.W)

    def _python_recent(self, t, L, valid, groups):
        """Every robot exact: the same column steps as ``_advance``, in a fixed short sequence of batched calls.

        Each group's causal estimate is one of: x̂_{t|t} itself (c ≥ t); one column from x̂_{t-1|t-1} (c = t-1:
        it shares the central prior of column t, as it holds everyone's odometry of t-1); its previous causal
        estimate extended by one column (valid: nothing about steps ≤ t-1 arrived); or a restart from x̂_{c|c}
        (c ≤ t-2): column c+1 updates the central chain's prior of c+1 (kept, ``lin``) with the rows it holds,
        later columns propagate with its last available odometry (§IV). All filters of a column share its calls.
        Returns ``None`` when the central prior a restart needs is no longer kept (``_step_general`` then).
        """
        n, W, lin = self.n, self.W, self.lin
        res_of = [0] * n
        rows_a, rows_r, rows_e, src_e, c_r = [], [], [], [], []
        held = {}  # a group's row of L (its key), shared by its robots
        for (_, ci, Lrow), robots in groups.items():
            if ci >= t:
                continue
            held[robots[0]] = Lrow
            rb = None
            if ci < t - 1:  # the first of its robots whose previous estimate is still valid
                for r in robots:
                    if valid[r]:
                        rb = r
                        break
            if rb is not None:
                rows_e.append(robots)
                src_e.append(rb)
            elif ci == t - 1:
                rows_a.append(robots)
            elif (ci + 1, ("C", ci), b"") in lin:
                rows_r.append(robots)
                c_r.append(ci)
            else:
                return None
        # filters: 0 the central chain, then those with a prior of column t of their own: the groups restarting
        # at t-2 or earlier (R) and the extended ones (E); last the groups restarting at t-1 (A)
        order = rows_r + rows_e + rows_a
        nr, nown = len(rows_r), len(rows_r) + len(rows_e)
        for g, robots in enumerate(order, start=1):
            for r in robots:
                res_of[r] = g
        Lx = np.array([(t,) * n] + [held[r[0]] for r in order], dtype=np.int64)  # holdings of each filter
        if getattr(self.k, "recent_column", None) is not None:  # compiled: the calls below in one
            Xn, Pn = self._fused_column(t, Lx, c_r, src_e)
            return Xn, Pn, res_of
        ar = np.arange(n)[None, :]
        cX, cP = self.central[t - 1]
        Xs, Ps = [cX[None]], [cP[None]]
        if rows_r:  # columns c+1 … t-1 of the restarting groups
            Xc, Pc = self._restart_chains(t, Lx[1 : 1 + nr], c_r)
            Xs.append(Xc)
            Ps.append(Pc)
        if rows_e:
            Xs.append(self.X[src_e])
            Ps.append(self.P[src_e])
        if nown:  # the central row of Lx gives the odometry of t-1 of everyone
            ud = self.ud_ring[self._slots(np.minimum(Lx[: 1 + nown], t - 1)), ar]
            Xp, Pp = np.concatenate(Xs), np.concatenate(Ps)
        else:
            ud = self.ud_ring[(t - 1) % W][None]
            Xp, Pp = Xs[0], Ps[0]
        pk = self.packets[t]
        geo = self._geometry(pk)
        hold = Lx[:, geo.obs_of_row] >= t  # a filter holds the rows of column t of the packets it holds
        pr = np.array(list(range(1 + nown)) + [0] * len(rows_a))  # the restarts at t-1 share the central prior
        Xp, Yp, JA, Xn, Pn = self.k.column(Xp, Pp, ud, geo, pk.z, self._inv_sd, self._inv_sth, hold, pr)
        lin[(t, ("C", t - 1), b"")] = (Xp[0], Yp[0], JA[0])
        return Xn, Pn, res_of

    def _restart_chains(self, t, Lr, c_r):
        """Columns c+1 … t-1 of the groups restarting from x̂_{c|c} (c ≤ t-2) with holdings ``Lr``: their (X, P) at
        column t-1, in the order of ``c_r``. Column c+1 updates the central chain's kept prior of c+1 (``lin``) with
        the rows a group holds; later columns propagate with its last available odometry (§IV). The loop batches the
        groups of a column into one call; the compiled ``recent_column`` runs each group alone through the same
        kernel calls: a filter's numbers do not depend on its batch, so both give the same."""
        lin = self.lin
        ar, nr = np.arange(self.n)[None, :], len(c_r)
        running, Xc, Pc = [], None, None  # the groups whose chain has begun, in the order they began
        for k in range(min(c_r) + 1, t):
            parts = []
            if running:  # their prior of column k: last available odometry of step k-1
                Lk = Lr[running]
                pk = self.packets[k]
                geo = self._geometry(pk)
                parts.append(
                    self.k.column(
                        Xc,
                        Pc,
                        self.ud_ring[self._slots(np.minimum(Lk, k - 1)), ar],
                        geo,
                        pk.z,
                        self._inv_sd,
                        self._inv_sth,
                        Lk[:, geo.obs_of_row] >= k,
                        np.arange(len(running)),
                    )[3:]
                )
            start = [g for g, ci in enumerate(c_r) if ci + 1 == k]
            if start:  # first column: the central prior of column k with the rows they hold
                Ls = Lr if len(start) == nr else Lr[start]
                geo = self._geometry(self.packets[k])
                parts.append(self.k.update(*lin[(k, ("C", k - 1), b"")], Ls[:, geo.obs_of_row] >= k, geo=geo))
                running = running + start
            if len(parts) == 1:
                Xc, Pc = parts[0]
            elif parts:
                Xc, Pc = np.concatenate([parts[0][0], parts[1][0]]), np.concatenate([parts[0][1], parts[1][1]])
        if running != sorted(running):  # back in the order of c_r
            pos = np.argsort(running)
            Xc, Pc = Xc[pos], Pc[pos]
        return Xc, Pc


def reference_observation(env) -> np.ndarray:
    """``AsyncCLEnv._observe`` in numpy: per other robot (i+1, i+2, … mod N) linked, my row lag, what it lacks; then
    my delay, the clock, my own-pose trace on a log scale, my neighbours and my recent bits."""
    tab, n = env.tables, env.n_agents
    t = tab.t
    k = OTHER_FEATURES * (n - 1)
    out = np.empty((n, k + OWN_FEATURES), dtype=np.float32)
    blocks = out[:, :k].reshape(n, n - 1, OTHER_FEATURES)
    others = (np.arange(n)[:, None] + np.arange(1, n)[None, :]) % n  # robot i sees robot (i + k) mod N in block k-1
    flat = (others + np.arange(n)[:, None] * n).ravel()
    behind = (t - tab.latest).reshape(-1)[flat]  # steps my copy of each other row lags
    lacks = (t - tab.known).reshape(-1)[flat]  # how far each other robot's frontier lags, as far as I know
    blocks[:, :, 0] = env.adj.reshape(-1)[flat].reshape(n, n - 1)
    blocks[:, :, 1] = (behind / (behind + AGE_SCALE)).reshape(n, n - 1)
    blocks[:, :, 2] = (lacks / (lacks + AGE_SCALE)).reshape(n, n - 1)
    delay = t - 1 - tab.c  # age of the oldest incomplete column
    out[:, k] = delay / (delay + AGE_SCALE)
    out[:, k + 1] = min(t / env.cfg["max_cycles"], 1.0)
    if env.cfg["estimation"]:
        out[:, k + 2] = np.clip((np.log10(np.maximum(own_pose_traces(env), 1e-12)) + 6.0) / 8.0, 0.0, 1.0)
    else:
        out[:, k + 2] = 0.0
    out[:, k + 3] = env.neighbours / (n - 1)
    out[:, k + 4] = env._ema / (env._ema + BITS_SCALE)
    return out


def own_pose_traces(env) -> np.ndarray:
    """(N,) trace of each robot's own-pose block P_i[3i:3i+3, 3i:3i+3] of its covariance, summed as numpy sums."""
    n = env.n_agents
    rows = np.arange(n)[:, None]
    diagonal = (np.arange(n)[:, None] * 3 + np.arange(3)[None, :]) * (3 * n + 1)  # flat index of P_i[3i+d, 3i+d]
    return np.add.reduce(env.est.P.reshape(n, -1)[rows, diagonal], axis=1)


def reference_errors(env) -> tuple[np.ndarray, np.ndarray, float, float]:
    """``AsyncCLEnv._errors`` in numpy: each robot's RMS position and orientation errors over the team (headings
    wrapped into (-π, π] as ``wrap`` does), and their means over the robots."""
    n = env.n_agents
    E = env.est.X.reshape(n, n, 3) - env.world.x
    th = E[:, :, 2]
    th += np.pi
    np.remainder(th, 2.0 * np.pi, out=th)
    th -= np.pi
    E *= E
    S = np.add.reduce(E, axis=1)  # (robot, [Σx², Σy², Σφ²]) over the team
    S[:, 0] += S[:, 1]
    S *= 1.0 / n
    R = np.sqrt(S, out=S)  # (robot, [RMS position, ·, RMS orientation])
    mean_pos, _, mean_ori = (np.add.reduce(R, axis=0) * (1.0 / n)).tolist()
    return R[:, 0], R[:, 2], mean_pos, mean_ori


def use_reference(env, kernels=NUMPY_KERNELS) -> None:
    """Make ``env``'s estimators a ``ReferenceEstimators`` running ``kernels`` (the numpy oracle by default) from its
    next reset on; the estimators keep their state, so call it before ``reset``."""
    est = env.unwrapped.est
    est.__class__ = ReferenceEstimators
    est.k = kernels
