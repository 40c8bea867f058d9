"""AsyncCL-v0: the robots' estimates against an independent, straightforward EKF written here.

The reference below is a textbook EKF (loops over robots and measurements, standard Kalman form
K = P Hᵀ (H P Hᵀ + R)⁻¹, P = (I − K H) P) following the model documented in ``ekf.py``: per step,
propagate every robot with its odometry u_{k-1} (unicycle, Q = diag((σ_v v)², σ_ω²)), then one batch
update with all range/bearing measurements of step k (R = diag((σ_d d)², σ_θ²)). It shares no code
with the environment's batched information-form filter.

The two filters invert different matrices (S = H P Hᵀ + R here; P⁻ and Y = P⁻⁻¹ + Hᵀ W H there), so they agree
to the forward-error bound of ``tests/helpers/numerics.py`` accumulated over the chain of column steps, with κ_k the sum
of the condition numbers of the three matrices of step k, computed here from the reference's P⁻, S and P.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.numerics import HEADINGS, assert_close_conditioned, condition, episode_tolerance

from mrcomm_env.asynccl_v0 import parallel_env

SV, SW, SD, STH = 0.02, math.radians(1.0), 0.02, math.radians(1.0)


def _wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def ref_propagate(x, P, u, dt, qv=None, qw=None):
    n = len(x) // 3
    x = x.copy()
    F = np.eye(3 * n)
    GQG = np.zeros((3 * n, 3 * n))
    for v in range(n):
        vel, om = u[v]
        phi = x[3 * v + 2]
        F[3 * v, 3 * v + 2] = -vel * math.sin(phi) * dt
        F[3 * v + 1, 3 * v + 2] = vel * math.cos(phi) * dt
        G = np.array([[math.cos(phi) * dt, 0.0], [math.sin(phi) * dt, 0.0], [0.0, dt]])
        Q = np.diag([(SV * vel) ** 2 if qv is None else qv[v], SW**2 if qw is None else qw[v]])
        GQG[3 * v : 3 * v + 3, 3 * v : 3 * v + 3] = G @ Q @ G.T
        x[3 * v] += vel * math.cos(phi) * dt
        x[3 * v + 1] += vel * math.sin(phi) * dt
        x[3 * v + 2] = _wrap(phi + om * dt)
    return x, F @ P @ F.T + GQG


def ref_update(x, P, meas):
    """meas: list of (observer a, target b, [d, θ]). Returns x, P and κ_k = κ(P⁻) + κ(S) + κ(P): the condition
    numbers of what this update inverts (S) and of what the environment's information form inverts (P⁻, Y = P⁻¹)."""
    if not meas:
        return x, P, condition(P)
    n3 = len(x)
    H = np.zeros((2 * len(meas), n3))
    innov = np.zeros(2 * len(meas))
    R = np.zeros((2 * len(meas), 2 * len(meas)))
    for e, (a, b, z) in enumerate(meas):
        dx, dy = x[3 * b] - x[3 * a], x[3 * b + 1] - x[3 * a + 1]
        d2 = dx * dx + dy * dy
        d = math.sqrt(d2)
        H[2 * e, [3 * a, 3 * a + 1, 3 * b, 3 * b + 1]] = [-dx / d, -dy / d, dx / d, dy / d]
        H[2 * e + 1, [3 * a, 3 * a + 1, 3 * a + 2, 3 * b, 3 * b + 1]] = [dy / d2, -dx / d2, -1.0, -dy / d2, dx / d2]
        innov[2 * e] = z[0] - d
        innov[2 * e + 1] = _wrap(z[1] - (math.atan2(dy, dx) - x[3 * a + 2]))
        R[2 * e, 2 * e] = (SD * z[0]) ** 2
        R[2 * e + 1, 2 * e + 1] = STH**2
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    x = x + K @ innov
    for v in range(n3 // 3):
        x[3 * v + 2] = _wrap(x[3 * v + 2])
    Pn = (np.eye(n3) - K @ H) @ P
    return x, Pn, condition(P) + condition(S) + condition(Pn)


def all_meas(pk, rows=None, k=None):
    return [
        (int(a), int(b), pk.z[e])
        for e, (a, b) in enumerate(zip(pk.a, pk.b, strict=True))
        if rows is None or rows[a] >= k
    ]


def run_recorded(seed, steps, n=4, policy_modes=None, **kw):
    """Play an episode with random modes; record packets, tables and estimates after every step."""
    env = parallel_env(n_robots=n, max_cycles=steps, **kw)
    env.reset(seed=seed)
    x0, P0 = env.est.central[-1]
    packets = {0: env.est.packets[0]}
    rng = np.random.default_rng(seed)
    space_n = env.action_space("robot_0").n
    trace = []
    while env.agents:
        t = env.tables.t
        acts = {a: int(rng.integers(space_n)) if policy_modes is None else policy_modes for a in env.agents}
        env.step(acts)
        trace.append(
            (
                t,
                env.tables.c.copy(),
                env.tables.latest.copy(),
                {c: env.est.central[c] for c in set(env.tables.c.tolist()) if c >= -1},
                env.est.X.copy(),
                env.est.P.copy(),
            )
        )
        packets[env.tables.t] = env.est.packets[env.tables.t]
    return env, x0.copy(), P0.copy(), packets, trace


def reference_chain(x0, P0, packets, upto, dt=0.05):
    """x̂_{k|k}, P_{k|k} and the accumulated condition Σ_{j ≤ k} κ_j of the chain, for k = 0 … upto."""
    out = {}
    x, P, total = x0, P0, 0.0
    for k in range(upto + 1):
        if k >= 1:
            x, P = ref_propagate(x, P, packets[k - 1].u, dt)
        x, P, kappa = ref_update(x, P, all_meas(packets[k]))
        total += kappa
        out[k] = (x, P, total)
    return out


def ops(n):
    """Roundings along one entry per step: 3N for the state's solves plus 2m rows (m = N(N−1)) of H, S or Y."""
    return 3 * n + 2 * n * (n - 1)


def bounds(chain_kappa, x, P, n):
    """Bounds for x and P after a chain with accumulated Σκ (``episode_tolerance`` with a single entry)."""
    return (
        float(episode_tolerance([chain_kappa], np.linalg.norm(x), ops(n))[0]),
        float(episode_tolerance([chain_kappa], np.linalg.norm(P, 2), ops(n))[0]),
    )


@pytest.mark.parametrize("seed,kw", [(0, {}), (1, {"packet_loss": 0.2, "link_probability": 0.3})])
def test_delayed_centralized_estimates_equal_an_independent_centralized_ekf(seed, kw):
    env, x0, P0, packets, trace = run_recorded(seed, 90, **kw)
    ref = reference_chain(x0, P0, packets, 90)
    checked = 0
    for t, c, latest, central, X, _P in trace:
        for i in range(env.n_agents):
            ci = int(c[i])
            assert latest[i].min() >= ci  # the robot really holds every packet up to its frontier
            if ci < 0:
                continue
            xe, Pe = central[ci]
            xr, Pr, chain = ref[ci]
            tol_x, tol_p = bounds(chain, xr, Pr, env.n_agents)
            assert_close_conditioned(xe, xr, tol_x, HEADINGS, f"x̂_{{{ci}|{ci}}}")
            assert_close_conditioned(Pe, Pr, tol_p, err_msg=f"P_{{{ci}|{ci}}}")
            if ci == t:  # with everything up to t, the causal estimate is the centralized one
                assert_close_conditioned(X[i], xr, tol_x, HEADINGS, f"causal x̂ at {t}")
            checked += 1
    assert checked > 200


def test_causal_estimates_restart_from_the_checkpoint_with_last_available_odometry():
    env, x0, P0, packets, trace = run_recorded(3, 60, link_probability=0.35)
    ref = reference_chain(x0, P0, packets, 60)
    checked = 0
    for t, c, latest, _, X, P in trace[::5]:
        L = np.minimum(latest, t)
        for i in range(env.n_agents):
            ci = int(c[i])
            if ci >= t:
                continue
            x, Pm, chain = (x0, P0, 0.0) if ci < 0 else ref[ci]
            if ci < 0:  # the prior, then column 0 with what the robot holds
                x, Pm, kappa = ref_update(x, Pm, all_meas(packets[0], L[i], 0))
                chain += kappa
                start = 1
            else:
                start = ci + 1
            for k in range(start, t + 1):
                src = np.minimum(L[i], k - 1)
                u = np.array([packets[s].u[v] if s >= 0 else (0.0, 0.0) for v, s in enumerate(src)])
                qv = [1.0 if s < 0 else (SV * u[v, 0]) ** 2 for v, s in enumerate(src)]
                qw = [1.0 if s < 0 else SW**2 for s in src]
                x, Pm = ref_propagate(x, Pm, u, 0.05, qv, qw)
                x, Pm, kappa = ref_update(x, Pm, all_meas(packets[k], L[i], k))
                chain += kappa
            tol_x, tol_p = bounds(chain, x, Pm, env.n_agents)
            assert_close_conditioned(X[i], x, tol_x, HEADINGS, f"robot {i} at {t}")
            assert_close_conditioned(P[i], Pm, tol_p, err_msg=f"robot {i} at {t}")
            checked += 1
    assert checked > 10


def test_more_information_gives_better_causal_estimates():
    """Scheme 2 (q = ∞) ≈ Scheme 1 for N = 5 and both far better than silence (§IV, Figs. 7–8)."""
    res = {}
    for mode in ("scheme2_qinf", "scheme1", "silent"):
        env = parallel_env(modes=[mode], max_cycles=150)
        env.reset(seed=5)
        while env.agents:
            env.step({a: 0 for a in env.agents})
        res[mode] = env.metrics()["rms_position"]
    assert res["scheme2_qinf"] < 0.5 * res["silent"]
    assert res["scheme1"] < 0.5 * res["silent"]
