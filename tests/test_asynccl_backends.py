"""AsyncCL-v0: the compiled twins (numba) of the hot loops agree with the numpy reference.

``ekf_numba.py`` re-implements the EKF kernels of ``ekf.py`` and ``table_numba.py`` the dense table
exchange (checked exactly in ``test_asynccl.py``). Here: kernel by kernel on random problems (full and
partial sensing graphs, shared and own priors, random row masks), then whole seeded episodes run once
on each backend, step by step.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

pytest.importorskip("numba")

from mrcomm_env.asynccl import ekf, ekf_numba  # noqa: E402
from mrcomm_env.asynccl import table as table_mod  # noqa: E402
from mrcomm_env.asynccl_v0 import parallel_env  # noqa: E402
from mrcomm_env.core import backend  # noqa: E402

SD, STH = 0.02, np.radians(1.0)


def _spd(rng, G, n3):
    Q = rng.standard_normal((G, n3, n3))
    return Q @ Q.transpose(0, 2, 1) + 0.5 * np.eye(n3)


def _problem(rng, n, G, full):
    a, b = np.nonzero(~np.eye(n, dtype=bool))
    if not full:  # a partial sensing graph, as with a short sensing radius
        keep = rng.random(len(a)) < 0.6
        keep[0] = True
        a, b = a[keep], b[keep]
    geo = ekf.Geometry(a, b, n, 1.0 / STH)
    X = rng.uniform(-3, 3, (G, 3 * n))
    X[:, 2::3] = rng.uniform(-np.pi, np.pi, (G, n))
    z = np.column_stack([rng.uniform(0.5, 5.0, len(a)), rng.uniform(-np.pi, np.pi, len(a))])
    return geo, X, z


@pytest.mark.parametrize("n,G,full", [(2, 1, True), (5, 1, True), (5, 4, True), (5, 3, False), (8, 6, False)])
def test_kernels_agree(n, G, full):
    rng = np.random.default_rng(100 * n + G)
    geo, X, z = _problem(rng, n, G, full)
    P = _spd(rng, G, 3 * n)
    ud = np.abs(rng.standard_normal((G, n, 4))) * 0.05

    Xa, Pa = ekf.propagate(X, P, ud)
    Xb, Pb = ekf_numba.propagate(X, P, ud)
    np.testing.assert_allclose(Xb, Xa, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Pb, Pa, rtol=1e-12, atol=1e-12)

    Aa = ekf.information(X, geo, z, 1.0 / SD, 1.0 / STH)
    Ab = ekf_numba.information(X, geo, z, 1.0 / SD, 1.0 / STH)
    np.testing.assert_allclose(Ab, Aa, rtol=1e-12, atol=1e-9)

    Yp = ekf.inv(P)
    np.testing.assert_allclose(ekf_numba.inv(P), Yp, rtol=1e-9, atol=1e-12)

    hold = rng.random((G + 2, 2 * geo.m)) < 0.7
    hold[0] = True
    # own priors, one shared prior (broadcast), and an explicit prior index per filter
    cases = [((X[:1].repeat(G + 2, 0), Yp[:1].repeat(G + 2, 0), Aa[:1].repeat(G + 2, 0)), None),
             ((X[0], Yp[0], Aa[0]), None),
             ((X, Yp, Aa), rng.integers(0, G, G + 2))]
    for (xp, yp, a), prior in cases:
        ref = ekf.update(xp, yp, a, hold, prior)
        got = ekf_numba.update(xp, yp, a, hold, prior, geo)
        scale = np.abs(ref[1]).max()
        np.testing.assert_allclose(got[1], ref[1], rtol=0, atol=1e-8 * scale)  # LU vs Cholesky: cond(Y)·ε
        np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-9)
        assert np.array_equal(got[1], got[1].transpose(0, 2, 1))  # the Cholesky inverse is exactly symmetric

    # the fused column step is the composition of the four kernels, on both backends
    prior = rng.integers(0, G, G + 2)
    ref = ekf.column(X, P, ud, geo, z, 1.0 / SD, 1.0 / STH, hold, prior)
    got = ekf_numba.column(X, P, ud, geo, z, 1.0 / SD, 1.0 / STH, hold, prior)
    comp = ekf.update(Xa, Yp_a := ekf.inv(Pa), Aa_p := ekf.information(Xa, geo, z, 1.0 / SD, 1.0 / STH), hold, prior)
    for r, c in zip(ref, (Xa, Yp_a, Aa_p) + comp, strict=True):
        np.testing.assert_array_equal(r, c)
    for r, g in zip(ref, got, strict=True):
        np.testing.assert_allclose(g, r, rtol=1e-8, atol=1e-8 * max(1.0, np.abs(r).max()))


def test_inverse_falls_back_when_not_positive_definite():
    A = np.diag([1.0, -2.0, 3.0])[None]
    np.testing.assert_allclose(ekf_numba.inv(A)[0], np.diag([1.0, -0.5, 1.0 / 3.0]))


def _episode(seed, kw, compiled, monkeypatch):
    with monkeypatch.context() as m:  # whatever MRCOMM_BACKEND says, run the backend asked for
        m.setattr(table_mod.backend, "compiled", lambda: compiled)
        env = parallel_env(**kw)
        env.reset(seed=seed)
        env.est.k = ekf.backend("numba" if compiled else "numpy")
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        n_modes = env.action_space("robot_0").n
        record = []
        while env.agents:
            _, rew, _, _, infos = env.step({a: int(rng.integers(n_modes)) for a in env.agents})
            record.append((env.est.X.copy(), env.est.P.copy(), env.tables.latest.copy(), env.tables.known.copy(),
                           rew["robot_0"], [infos[a]["bits_sent"] for a in env.agents]))
        return record, env.metrics()


@pytest.mark.parametrize("seed,kw", [(0, {"max_cycles": 150}),
                                     (1, {"max_cycles": 120, "link_probability": 0.3, "packet_loss": 0.2}),
                                     (2, {"n_robots": 3, "trajectory": "waypoint", "sensing_radius": 3.0,
                                          "max_cycles": 120, "max_history": 12})])
def test_whole_episodes_agree_across_backends(seed, kw, monkeypatch):
    fast, m_fast = _episode(seed, kw, True, monkeypatch)
    ref, m_ref = _episode(seed, kw, False, monkeypatch)
    assert len(fast) == len(ref) == kw["max_cycles"]
    for (x1, p1, l1, k1, r1, b1), (x2, p2, l2, k2, r2, b2) in zip(fast, ref, strict=True):
        np.testing.assert_allclose(x1, x2, rtol=0, atol=1e-8)
        np.testing.assert_allclose(p1, p2, rtol=1e-7, atol=1e-12)
        np.testing.assert_array_equal(l1, l2)
        np.testing.assert_array_equal(k1, k2)
        assert b1 == b2
        assert r1 == pytest.approx(r2, abs=1e-8)
    for key in m_ref:
        assert m_fast[key] == pytest.approx(m_ref[key], rel=1e-9, abs=1e-9), key


def test_backend_variable_is_validated(monkeypatch):
    try:
        monkeypatch.setenv(backend.VARIABLE, "fortran")
        backend.compiled.cache_clear()
        with pytest.raises(ValueError, match="MRCOMM_BACKEND"):
            backend.compiled()
        monkeypatch.setenv(backend.VARIABLE, "numpy")
        backend.compiled.cache_clear()
        assert backend.compiled() is False and backend.name() == "numpy"
    finally:
        monkeypatch.undo()
        backend.compiled.cache_clear()
    # numba is importable here: the ambient choice decides again
    assert backend.compiled() is (os.environ.get(backend.VARIABLE, "auto") != "numpy")
