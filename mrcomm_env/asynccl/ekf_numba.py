"""The EKF kernels of ``ekf.py`` (``ekf.KERNELS``), compiled with numba.

The column step of §IV: eq. (1) propagation, one batch update with the range/bearing rows of eq. (2) in information
form. Their numpy oracle is ``tests/helpers/asynccl_reference.py`` (dense products, an LU inverse);
``tests/asynccl/test_asynccl_backends.py`` checks that both agree, kernel by kernel and over whole episodes, within
the forward-error bound of the matrices they invert (``tests/helpers/numerics.py``; when that bound means round-off:
docs/architecture.md, "Compiled twins of hot loops"). At these sizes (3N = 15) the cost of numpy is its per-call overhead, not
the arithmetic, so the arithmetic is organised for one pass over few numbers:

* propagation applies F = I + E (E has two entries per robot, ∂(x, y)/∂φ) as row and column operations
  instead of dense products;
* the update adds each held row's outer product on the row's ≤ 5 non-zero columns only, to the symmetric
  part of the prior information (what a dense update sees to first order through its symmetrised result);
* the inverse of the (symmetric positive definite) information matrix goes through its Cholesky factor,
  P = L⁻ᵀ L⁻¹, which is about four times cheaper than the LU inverse and exactly symmetric. A matrix that
  is not numerically positive definite falls back to the LU inverse;
* independent sums (of the inverse, and of x = x⁻ + P b) run four at a time, each with its own terms in its own
  order, so each keeps its bits: at 3N = 15 a running sum's wait for its previous term set the pace, not the
  arithmetic (``tests/asynccl/test_asynccl_backends.py`` pins both to a one-sum-at-a-time loop in Python floats).

``group_filters`` and ``recent_column`` are the estimator's common step (``Estimators._step_recent``): the robots
grouped into filters, then the restarting filters' columns, the extended estimates, each prior's odometry and held
rows and column t in one call, each filter through the same kernel calls as a loop of batched calls would make
(``tests/asynccl/test_asynccl_fastpath.py`` compares the bytes of both with that loop's).
"""

from __future__ import annotations

import math
from itertools import accumulate

import numpy as np
from numba import njit

from mrcomm_env.core.backend import configure_numba_cache, kernel_array

configure_numba_cache()  # before the @njit(cache=True) below: never cache into the package

TWO_PI = 2.0 * math.pi
MIN_DISTANCE = 1e-6  # guards the Jacobian of two estimates at the same place (the sensor gives d ≥ 5 cm)


@njit(cache=True)
def _inv_spd_into(Y, out, L):
    """out = Y⁻¹ for a symmetric positive definite Y, through its Cholesky factor: Y = L Lᵀ, Y⁻¹ = L⁻ᵀ L⁻¹.

    ``L`` (n, n) is scratch: its lower triangle receives L, its upper triangle U = (L⁻¹)ᵀ, so that every inner
    loop runs along a row.

    Each entry is one running sum, and a sum waits for its previous term: at 3N = 15 the three phases were bound
    by that latency, not by the arithmetic. So each phase runs four independent sums at once (four rows of L, four
    entries of a row of L⁻¹, four entries of Y⁻¹), each with its own terms in its own order (k ascending), which
    gives every entry the bits of the one-sum-at-a-time loop (``tests/asynccl/test_asynccl_backends.py`` compares them)
    in about two thirds of its time at 3N = 15 and half of it at 3N = 60 (a throwaway timing).
    """
    if not _cholesky_into(Y, L):  # not numerically positive definite: LU inverse, symmetrised
        n = Y.shape[0]
        P = np.linalg.inv(Y)
        for r in range(n):
            for c in range(n):
                out[r, c] = 0.5 * (P[r, c] + P[c, r])
        return
    _invert_factor(L)
    _gram_into(L, out)


@njit(cache=True)
def _cholesky_into(Y, L):
    """The lower triangle of ``L`` = the Cholesky factor of ``Y``; False (``L`` unfinished) when a pivot is not
    positive."""
    n = Y.shape[0]
    for j in range(n):
        s = Y[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        L[j, j] = d
        # L[i, j] = (Y[i, j] − Σ_{k<j} L[i, k] L[j, k]) / L[j, j], rows i > j four at a time
        i = j + 1
        while i + 3 < n:
            s0, s1, s2, s3 = Y[i, j], Y[i + 1, j], Y[i + 2, j], Y[i + 3, j]
            for k in range(j):
                ljk = L[j, k]
                s0 -= L[i, k] * ljk
                s1 -= L[i + 1, k] * ljk
                s2 -= L[i + 2, k] * ljk
                s3 -= L[i + 3, k] * ljk
            L[i, j] = s0 / d
            L[i + 1, j] = s1 / d
            L[i + 2, j] = s2 / d
            L[i + 3, j] = s3 / d
            i += 4
        while i < n:
            s = Y[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
            i += 1
    return True


@njit(cache=True)
def _invert_factor(L):
    """U[j, i] = (L⁻¹)[i, j] for i ≥ j into the upper triangle of ``L`` (its diagonal: 1 / L[i, i]), row by row of
    L⁻¹: (L⁻¹)[i, j] = −Σ_{j≤k<i} L[i, k] (L⁻¹)[k, j] / L[i, i]. The sums of entries j … j+3 start at k = j … j+3,
    so their first terms come one by one, then the terms k ≥ j+3 of all four together."""
    n = L.shape[0]
    for i in range(n):
        inv_d = 1.0 / L[i, i]
        j = 0
        while j + 3 < i:
            lik = L[i, j]
            s0 = 0.0 - lik * L[j, j]
            lik = L[i, j + 1]
            s0 -= lik * L[j, j + 1]
            s1 = 0.0 - lik * L[j + 1, j + 1]
            lik = L[i, j + 2]
            s0 -= lik * L[j, j + 2]
            s1 -= lik * L[j + 1, j + 2]
            s2 = 0.0 - lik * L[j + 2, j + 2]
            s3 = 0.0
            for k in range(j + 3, i):
                lik = L[i, k]
                s0 -= lik * L[j, k]
                s1 -= lik * L[j + 1, k]
                s2 -= lik * L[j + 2, k]
                s3 -= lik * L[j + 3, k]
            L[j, i] = s0 * inv_d
            L[j + 1, i] = s1 * inv_d
            L[j + 2, i] = s2 * inv_d
            L[j + 3, i] = s3 * inv_d
            j += 4
        while j < i:
            s = 0.0
            for k in range(j, i):
                s -= L[i, k] * L[j, k]
            L[j, i] = s * inv_d
            j += 1
        L[i, i] = inv_d


@njit(cache=True)
def _gram_into(L, out):
    """out[i, j] = Σ_{k ≥ max(i, j)} (L⁻¹)[k, i] (L⁻¹)[k, j] = Σ_k U[i, k] U[j, k] (``_invert_factor``'s U), entries
    j ≤ i four at a time."""
    n = L.shape[0]
    for i in range(n):
        j = 0
        while j + 3 <= i:
            s0 = s1 = s2 = s3 = 0.0
            for k in range(i, n):
                uik = L[i, k]
                s0 += uik * L[j, k]
                s1 += uik * L[j + 1, k]
                s2 += uik * L[j + 2, k]
                s3 += uik * L[j + 3, k]
            out[i, j] = out[j, i] = s0
            out[i, j + 1] = out[j + 1, i] = s1
            out[i, j + 2] = out[j + 2, i] = s2
            out[i, j + 3] = out[j + 3, i] = s3
            j += 4
        while j <= i:
            s = 0.0
            for k in range(i, n):
                s += L[i, k] * L[j, k]
            out[i, j] = s
            out[j, i] = s
            j += 1


@njit(cache=True)
def _inv(A):
    """Batched inverse of symmetric positive definite matrices (G, n, n)."""
    G, n, _ = A.shape
    out = np.empty((G, n, n))
    L = np.zeros((n, n))
    for g in range(G):
        _inv_spd_into(A[g], out[g], L)
    return out


@njit(cache=True)
def _propagate(X, P, ud):
    """x⁺ = f(x, u) and P⁺ = F P Fᵀ + Γ Q Γᵀ (eq. (1)); ud = [v dt, σ_v dt, σ_ω dt, ω dt]."""
    G, n3 = X.shape
    Xn = np.empty((G, n3))
    Pn = np.empty((G, n3, n3))
    fx = np.empty(n3 // 3)
    fy = np.empty(n3 // 3)
    for g in range(G):
        _propagate_one(X[g], P[g], ud[g], Xn[g], Pn[g], fx, fy)
    return Xn, Pn


@njit(cache=True)
def _propagate_one(x, P, ud, xn, T, fx, fy):
    """One filter of ``_propagate`` into ``xn`` (3N,) and ``T`` (3N, 3N); ``fx``, ``fy`` (N,) are scratch."""
    n3 = x.shape[0]
    n = n3 // 3
    T[:, :] = P
    xn[:] = x
    for i in range(n):
        phi = x[3 * i + 2]
        c, s = math.cos(phi), math.sin(phi)
        vdt = ud[i, 0]
        fx[i], fy[i] = -vdt * s, vdt * c  # ∂x/∂φ, ∂y/∂φ
        xn[3 * i] += vdt * c
        xn[3 * i + 1] += vdt * s
        xn[3 * i + 2] += ud[i, 3]
    for i in range(n):  # F P: rows x_i, y_i gain ∂/∂φ times row φ_i (which E leaves as it is)
        for j in range(n3):
            T[3 * i, j] += fx[i] * P[3 * i + 2, j]
            T[3 * i + 1, j] += fy[i] * P[3 * i + 2, j]
    for i in range(n):  # (F P) Fᵀ: the same on the columns
        for j in range(n3):
            T[j, 3 * i] += fx[i] * T[j, 3 * i + 2]
            T[j, 3 * i + 1] += fy[i] * T[j, 3 * i + 2]
    for i in range(n):  # Γ Q Γᵀ: σ_v² dt² (c, s)(c, s)ᵀ on (x_i, y_i), σ_ω² dt² on φ_i
        phi = x[3 * i + 2]
        gx, gy = ud[i, 1] * math.cos(phi), ud[i, 1] * math.sin(phi)
        T[3 * i, 3 * i] += gx * gx
        T[3 * i, 3 * i + 1] += gx * gy
        T[3 * i + 1, 3 * i] += gx * gy
        T[3 * i + 1, 3 * i + 1] += gy * gy
        T[3 * i + 2, 3 * i + 2] += ud[i, 2] * ud[i, 2]


@njit(cache=True)
def _information(X, a, b, z, inv_sd, inv_sth):
    G, n3 = X.shape
    A = np.zeros((G, 2 * len(a), n3 + 1))
    for g in range(G):
        _information_one(X[g], a, b, z, inv_sd, inv_sth, A[g])
    return A


@njit(cache=True)
def _information_one(x, a, b, z, inv_sd, inv_sth, A):
    """One filter of ``_information``: its rows' non-zero entries into ``A`` (2m, 3N+1), whose others must be 0."""
    n3 = x.shape[0]
    for j in range(len(a)):
        ia, ib = 3 * a[j], 3 * b[j]
        dx, dy = x[ib] - x[ia], x[ib + 1] - x[ia + 1]
        d = max(math.hypot(dx, dy), MIN_DISTANCE)
        sr = inv_sd / z[j, 0]  # √w of the range row, 1/(σ_d z_d)
        f = sr / d
        u0, u1 = dx * f, dy * f
        f = inv_sth / (d * d)
        p0, p1 = dy * f, dx * f
        r = A[2 * j]  # range row: ∓(Δx, Δy)/d at a / b, times 1/(σ_d z_d)
        r[ia], r[ia + 1], r[ib], r[ib + 1] = -u0, -u1, u0, u1
        r[n3] = inv_sd - d * sr
        r = A[2 * j + 1]  # bearing row: (Δy, −Δx)/d², −1 at a and (−Δy, Δx)/d² at b, times 1/σ_θ
        r[ia], r[ia + 1], r[ia + 2], r[ib], r[ib + 1] = p0, -p1, -inv_sth, -p0, p1
        br = ((x[ia + 2] - math.atan2(dy, dx)) + (z[j, 1] + math.pi)) % TWO_PI - math.pi
        r[n3] = br * inv_sth


def inv(A):
    """batched inverse of symmetric positive definite matrices."""
    return _inv(kernel_array(A))


def propagate(X, P, ud):
    """x⁺ = f(x, u), P⁺ = F P Fᵀ + Γ Q Γᵀ (eq. (1))."""
    return _propagate(kernel_array(X), kernel_array(P), kernel_array(ud))


def information(X, geo, z, inv_sd, inv_sth):
    """Whitened rows [√W H | √W r] of a column at the priors X, (G, 2m, 3N+1)."""
    return _information(kernel_array(X), geo.a, geo.b, kernel_array(z), inv_sd, inv_sth)


@njit(cache=True)
def _update(Xp, Yp, A, hold, prior, a, b):
    G = hold.shape[0]
    n3 = Xp.shape[1]
    Xn = np.empty((G, n3))
    Pn = np.empty((G, n3, n3))
    Y = np.empty((n3, n3))
    L = np.zeros((n3, n3))
    bvec = np.empty(n3)
    cols = np.empty(5, dtype=np.int64)
    for g in range(G):
        p = prior[g]
        _update_one(Xp[p], Yp[p], A[p], hold[g], a, b, Xn[g], Pn[g], Y, L, bvec, cols)
    return Xn, Pn


@njit(cache=True)
def _update_one(xp, Yp, A, hold, a, b, xn, Pn, Y, L, bvec, cols):
    """One filter of ``_update`` into ``xn`` (3N,) and ``Pn`` (3N, 3N): prior ``xp``, ``Yp``, rows ``A`` (2m, 3N+1) of
    which it holds those of ``hold`` (2m,); ``Y``, ``L`` (3N, 3N), ``bvec`` (3N,), ``cols`` (5,) are scratch."""
    n3 = xp.shape[0]
    # Y starts from the symmetric part of Y⁻: the Cholesky factorisation below reads only the lower triangle,
    # while a dense LU inverse (the numpy oracle's) sees the whole matrix and symmetrises its result, which removes
    # the antisymmetric part of Y⁻ to first order. An LU inverse Y⁻ = P⁻⁻¹ is asymmetric by up to
    # ε·κ(P⁻)·‖Y⁻‖; read from one triangle only, that changed P = Y⁻¹ by a relative κ(Y)·ε·κ(P⁻), up to O(1)
    # at the κ of near-noiseless sensing. A Y⁻ of this module (``inv``) is exactly symmetric: nothing changes.
    for i in range(n3):
        for j in range(i + 1):
            s = 0.5 * (Yp[i, j] + Yp[j, i])
            Y[i, j] = s
            Y[j, i] = s
    bvec[:] = 0.0
    for r in range(hold.shape[0]):
        if not hold[r]:
            continue
        # the row's non-zero columns: x, y (and φ for a bearing row) of the observer, x, y of the target
        j = r >> 1
        cols[0], cols[1], cols[2], cols[3], cols[4] = 3 * b[j], 3 * b[j] + 1, 3 * a[j], 3 * a[j] + 1, 3 * a[j] + 2
        k = 5 if r & 1 else 4
        row = A[r]
        res = row[n3]
        for x in range(k):
            cx = cols[x]
            hx = row[cx]
            bvec[cx] += hx * res
            for y in range(k):
                Y[cx, cols[y]] += hx * row[cols[y]]
    _inv_spd_into(Y, Pn, L)
    i = 0
    while i + 3 < n3:  # x = x⁻ + P b, four independent sums at once (each in its own order: ``_inv_spd_into``)
        s0 = s1 = s2 = s3 = 0.0
        for j in range(n3):
            bj = bvec[j]
            s0 += Pn[i, j] * bj
            s1 += Pn[i + 1, j] * bj
            s2 += Pn[i + 2, j] * bj
            s3 += Pn[i + 3, j] * bj
        xn[i] = xp[i] + s0
        xn[i + 1] = xp[i + 1] + s1
        xn[i + 2] = xp[i + 2] + s2
        xn[i + 3] = xp[i + 3] + s3
        i += 4
    while i < n3:
        s = 0.0
        for j in range(n3):
            s += Pn[i, j] * bvec[j]
        xn[i] = xp[i] + s
        i += 1
    for i in range(2, n3, 3):  # wrap the headings into (-π, π]
        xn[i] = (xn[i] + math.pi) % TWO_PI - math.pi


_FIRST = np.zeros(256, dtype=np.int64)  # prior indices "all the first prior" and "each its own", sliced per call
_OWN = np.arange(256, dtype=np.int64)


def update(Xp, Yp, A, hold, prior=None, geo=None):
    """information-form update of G filters; ``prior[g]`` picks filter g's prior (default: its own,
    or the single prior when Xp is one state). ``geo`` (the column's ``ekf.Geometry``) gives the rows' columns."""
    G = len(hold)
    if Xp.ndim == 1:
        Xp, Yp, A = Xp[None], Yp[None], A[None]
        if prior is None:
            prior = _FIRST[:G] if G <= 256 else np.zeros(G, dtype=np.int64)
    elif prior is None:
        prior = _OWN[:G] if G <= 256 else np.arange(G)
    return _update(
        kernel_array(Xp),
        kernel_array(Yp),
        kernel_array(A),
        kernel_array(hold),
        kernel_array(prior, np.int64),
        geo.a,
        geo.b,
    )


@njit(cache=True)
def _column(Xs, Ps, ud, a, b, z, inv_sd, inv_sth, hold, prior):
    Xp, Pp = _propagate(Xs, Ps, ud)
    A = _information(Xp, a, b, z, inv_sd, inv_sth)
    Yp = _inv(Pp)
    Xn, Pn = _update(Xp, Yp, A, hold, prior, a, b)
    return Xp, Yp, A, Xn, Pn


def column(Xs, Ps, ud, geo, z, inv_sd, inv_sth, hold, prior):
    """propagate, linearise, invert and update in one compiled call."""
    return _column(
        kernel_array(Xs),
        kernel_array(Ps),
        kernel_array(ud),
        geo.a,
        geo.b,
        kernel_array(z),
        inv_sd,
        inv_sth,
        kernel_array(hold),
        kernel_array(prior, np.int64),
    )


@njit(cache=True)
def _restart_chains(Lr, c_r, t, k0, ud_ring, W, sources_known, chain, inv_sd, inv_sth):
    a_cat, b_cat, z_cat, off, slot_of_col, lin_X, lin_Y, lin_A, lin_off = chain  # ``_chain_inputs``
    G, n = Lr.shape
    n3 = 3 * n
    X_out = np.empty((G, n3))
    P_out = np.empty((G, n3, n3))
    m_max = 0
    for j in range(len(off) - 1):
        m_max = max(m_max, off[j + 1] - off[j])
    # one filter at a time through the one-filter kernels, on buffers allocated once: its estimate (x, P), its
    # prior of the next column (xp, Pp, Yp) and that column's rows (A), and the kernels' scratch
    x, xp, bvec = np.empty(n3), np.empty(n3), np.empty(n3)
    P, Pp, Yp, Y = np.empty((n3, n3)), np.empty((n3, n3)), np.empty((n3, n3)), np.empty((n3, n3))
    L = np.zeros((n3, n3))
    A = np.empty((2 * m_max, n3 + 1))
    hold = np.empty(2 * m_max, dtype=np.bool_)
    ud = np.empty((n, 4))
    fx, fy = np.empty(n), np.empty(n)
    cols = np.empty(5, dtype=np.int64)
    for g in range(G):
        k = c_r[g] + 1
        j = k - k0
        s = slot_of_col[j]
        lo, hi = off[j], off[j + 1]
        a, b = a_cat[lo:hi], b_cat[lo:hi]
        held = hold[: 2 * (hi - lo)]
        for r in range(2 * (hi - lo)):  # a filter holds a row iff it holds its observer's packet (``obs_of_row``)
            held[r] = Lr[g, a[r >> 1]] >= k
        # column c+1: the central chain's prior, the rows it holds
        _update_one(lin_X[s], lin_Y[s], lin_A[lin_off[s] : lin_off[s + 1]], held, a, b, x, P, Y, L, bvec, cols)
        for k in range(c_r[g] + 2, t):  # columns c+2 … t-1: its own prior, its last available odometry of k-1
            j = k - k0
            lo, hi = off[j], off[j + 1]
            a, b, z = a_cat[lo:hi], b_cat[lo:hi], z_cat[lo:hi]
            for i in range(n):
                src = min(Lr[g, i], k - 1)
                slot = src % W if sources_known or src >= 0 else W  # the standstill slot: no odometry yet
                for q in range(4):
                    ud[i, q] = ud_ring[slot, i, q]
            held = hold[: 2 * (hi - lo)]
            for r in range(2 * (hi - lo)):
                held[r] = Lr[g, a[r >> 1]] >= k
            rows = A[: 2 * (hi - lo)]
            rows[:, :] = 0.0
            # ``_column``'s four kernels, this filter's share of each
            _propagate_one(x, P, ud, xp, Pp, fx, fy)
            _information_one(xp, a, b, z, inv_sd, inv_sth, rows)
            _inv_spd_into(Pp, Yp, L)
            _update_one(xp, Yp, rows, held, a, b, x, P, Y, L, bvec, cols)
        X_out[g] = x
        P_out[g] = P
    return X_out, P_out


def _chain_inputs(geometries, zs, lins, k0, n3):
    """The columns k0, k0+1, … (``geometries``, ``zs``) and the central chain's kept priors ``lins`` (first column →
    (X, Y, A)) as the flat arrays the compiled chains read, one tuple (a_cat, b_cat, z_cat, off, slot_of_col, lin_X,
    lin_Y, lin_A, lin_off): each column's measurements at ``off[k - k0]`` …
    ``off[k - k0 + 1]``, each prior's rows of A at ``lin_off[s]`` … ``lin_off[s + 1]``, ``slot_of_col`` the prior
    slot s of a first column (−1: none). Python lists and ``accumulate``, not numpy calls: at these sizes (a few
    columns of ≤ N(N−1) measurements) numpy's per-call overhead was half of the chains' own time."""
    off = np.array(list(accumulate((geo.m for geo in geometries), initial=0)), dtype=np.int64)
    slot_of_col = [-1] * len(geometries)
    firsts = sorted(lins)
    for s, k in enumerate(firsts):
        slot_of_col[k - k0] = s
    if firsts:
        priors = [lins[k] for k in firsts]
        lin_off = np.array(list(accumulate((len(A) for _, _, A in priors), initial=0)), dtype=np.int64)
        lin_X = np.array([X for X, _, _ in priors])
        lin_Y = np.array([Y for _, Y, _ in priors])
        lin_A = np.concatenate([A for _, _, A in priors])
    else:
        lin_off = np.zeros(1, dtype=np.int64)
        lin_X, lin_Y, lin_A = np.empty((0, n3)), np.empty((0, n3, n3)), np.empty((0, n3 + 1))
    return (
        np.concatenate([geo.a for geo in geometries]),
        np.concatenate([geo.b for geo in geometries]),
        kernel_array(np.concatenate(zs)),
        off,
        np.array(slot_of_col, dtype=np.int64),
        lin_X,
        lin_Y,
        lin_A,
        lin_off,
    )


@njit(cache=True)
def _recent_column(Lx, c_r, src_e, t, k0, X_prev, P_prev, cX, cP, ud_ring, W, sources_known, chain, inv_sd, inv_sth):
    a_cat, b_cat, z_cat, off = chain[0], chain[1], chain[2], chain[3]  # ``_chain_inputs``
    F, n = Lx.shape
    nr, ne = len(c_r), len(src_e)
    G = 1 + nr + ne  # the filters with a prior of column t of their own; the other F - G share the central one
    n3 = 3 * n
    Xs = np.empty((G, n3))
    Ps = np.empty((G, n3, n3))
    Xs[0] = cX
    Ps[0] = cP
    if nr > 0:  # columns c+1 … t-1 of the restarting filters
        Xc, Pc = _restart_chains(Lx[1 : 1 + nr], c_r, t, k0, ud_ring, W, sources_known, chain, inv_sd, inv_sth)
        Xs[1 : 1 + nr] = Xc
        Ps[1 : 1 + nr] = Pc
    for q in range(ne):  # the extended filters: their previous causal estimate
        Xs[1 + nr + q] = X_prev[src_e[q]]
        Ps[1 + nr + q] = P_prev[src_e[q]]
    ud = np.empty((G, n, 4))
    for g in range(G):  # each own prior's last available odometry of step t-1 (the central row: everyone's)
        for i in range(n):
            src = min(Lx[g, i], t - 1)
            slot = src % W if sources_known or src >= 0 else W  # the standstill slot: no odometry yet
            for q in range(4):
                ud[g, i, q] = ud_ring[slot, i, q]
    j = t - k0
    lo, hi = off[j], off[j + 1]
    a, b, z = a_cat[lo:hi].copy(), b_cat[lo:hi].copy(), z_cat[lo:hi].copy()
    hold = np.empty((F, 2 * (hi - lo)), dtype=np.bool_)
    for g in range(F):  # a filter holds the rows of column t of the packets it holds (``obs_of_row``)
        for r in range(2 * (hi - lo)):
            hold[g, r] = Lx[g, a[r >> 1]] >= t
    prior = np.zeros(F, dtype=np.int64)
    for g in range(G):
        prior[g] = g
    return _column(Xs, Ps, ud, a, b, z, inv_sd, inv_sth, hold, prior)


def recent_column(
    Lx, c_r, src_e, t, X_prev, P_prev, central, ud_ring, W, sources_known, geometries, zs, lins, inv_sd, inv_sth
):
    """``Estimators._step_recent``'s column t in one compiled call: ``column``'s (X⁻, Y⁻, A, X, P) of the filters of
    ``Lx`` (F, N): the central chain (row 0, prior ``central`` = x̂_{t-1|t-1}), the filters restarting from
    x̂_{c|c}, c = ``c_r`` ≤ t-2 (their columns c+1 … t-1: ``update`` of the central chain's kept prior on column
    c+1, ``column`` with the last available odometry on each later one), those extending their previous estimate
    ``X_prev[src_e]``, ``P_prev[src_e]``, then those restarting at t-1 (the central prior). ``geometries``/``zs``:
    columns k0 … t (k0 = min(c_r)+1, or t without restarts); ``lins`` maps each first column c+1 to the central
    chain's kept prior there (X, Y = P⁻¹, whitened rows A). Each filter goes through the very kernel calls of a
    loop of batched calls on the same inputs, so it gets the loop's numbers
    (``tests/asynccl/test_asynccl_fastpath.py``)."""
    c_r = np.array(c_r, dtype=np.int64)
    k0 = t - len(geometries) + 1
    cX, cP = central
    return _recent_column(
        Lx,
        c_r,
        np.array(src_e, dtype=np.int64),
        int(t),
        k0,
        X_prev,
        P_prev,
        kernel_array(cX),
        kernel_array(cP),
        ud_ring,
        int(W),
        bool(sources_known),
        _chain_inputs(geometries, zs, lins, k0, Lx.shape[1] * 3),
        float(inv_sd),
        float(inv_sth),
    )


@njit(cache=True)
def _still_valid(t, c, L, cache_ok, cache_c, cache_L):
    """(N,) bool: robots whose causal estimate of step t-1 is still valid (``group_filters``)."""
    n = c.shape[0]
    valid = np.zeros(n, dtype=np.bool_)
    if cache_ok:
        for i in range(n):
            if c[i] < t - 1 and c[i] == cache_c[i]:
                same = True
                for j in range(n):
                    if min(L[i, j], t - 1) != cache_L[i, j]:
                        same = False
                        break
                valid[i] = same
    return valid


@njit(cache=True)
def _shared_filters(c, L):
    """Each robot's group (robots with the same c and row of ``L``), groups numbered by their first robot: the group
    of every robot, each group's first robot, and the number of groups."""
    n = c.shape[0]
    group_of = np.full(n, -1, dtype=np.int64)
    firsts = np.empty(n, dtype=np.int64)
    G = 0
    for i in range(n):
        for g in range(G):
            f = firsts[g]
            if c[f] == c[i]:
                same = True
                for j in range(n):
                    if L[f, j] != L[i, j]:
                        same = False
                        break
                if same:
                    group_of[i] = g
                    break
        if group_of[i] < 0:
            firsts[G] = i
            group_of[i] = G
            G += 1
    return group_of, firsts, G


@njit(cache=True)
def group_filters(t, c, L, cache_ok, cache_c, cache_L):
    """``Estimators.step``'s filters of step t ≥ 1 while every robot is exact, in one compiled call: robots with the
    same frontier c and holdings (a row of ``L`` = min(latest, t)) share one causal filter; groups are numbered by
    their first robot. A group with c ≥ t reads x̂_{t|t} (filter 0, the central chain); one that can extend its
    previous estimate (c < t-1, and a robot whose frontier and holdings ≤ t-1 are those of step t-1: ``cache_ok``
    says step t-1's ``cache_c``, ``cache_L`` may be compared) extends that robot's; one with c = t-1 restarts from
    the central prior of t; the others restart from x̂_{c|c}. Filters: 0, then the restarting groups (R), the
    extending ones (E) and those restarting at t-1 (A), each in group order, as ``Estimators._step_recent``
    orders them. Returns their holdings ``Lx`` (F, N), R's checkpoints ``c_r``, E's source robots ``src_e`` and
    each robot's filter ``res_of`` (N,)."""
    n = c.shape[0]
    valid = _still_valid(t, c, L, cache_ok, cache_c, cache_L)
    group_of, firsts, G = _shared_filters(c, L)
    NONE, RESTART, EXTEND, AT_T1 = 0, 1, 2, 3
    kind = np.empty(G, dtype=np.int64)
    source = np.full(G, -1, dtype=np.int64)
    counts = np.zeros(4, dtype=np.int64)
    for g in range(G):
        ci = c[firsts[g]]
        if ci >= t:
            kind[g] = NONE
        else:
            if ci < t - 1:  # the group's first robot whose previous estimate is still valid
                for r in range(firsts[g], n):
                    if group_of[r] == g and valid[r]:
                        source[g] = r
                        break
            if source[g] >= 0:
                kind[g] = EXTEND
            elif ci == t - 1:
                kind[g] = AT_T1
            else:
                kind[g] = RESTART
        counts[kind[g]] += 1
    F = 1 + counts[RESTART] + counts[EXTEND] + counts[AT_T1]
    Lx = np.empty((F, n), dtype=np.int64)
    Lx[0, :] = t
    c_r = np.empty(counts[RESTART], dtype=np.int64)
    src_e = np.empty(counts[EXTEND], dtype=np.int64)
    filter_of = np.zeros(G, dtype=np.int64)
    q, qr, qe = 1, 0, 0
    for want in (RESTART, EXTEND, AT_T1):
        for g in range(G):
            if kind[g] == want:
                filter_of[g] = q
                Lx[q, :] = L[firsts[g]]
                if want == RESTART:
                    c_r[qr] = c[firsts[g]]
                    qr += 1
                elif want == EXTEND:
                    src_e[qe] = source[g]
                    qe += 1
                q += 1
    res_of = np.empty(n, dtype=np.int64)
    for i in range(n):
        res_of[i] = filter_of[group_of[i]]
    return Lx, c_r, src_e, res_of
