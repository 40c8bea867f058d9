"""AsyncCL's observation and team errors written in numpy: the oracles of their compiled kernels (``env_numba``).

The env computes both in one compiled call each (``AsyncCLEnv._observe``, ``_errors``); these are the same formulas
as the module's table and §IV state them, in numpy's own reduction order, kept here and not in the package (#44:
one implementation in the package, the reference under tests/). ``tests/asynccl/test_asynccl.py`` compares them
with the env's byte for byte at every step of whole episodes."""

from __future__ import annotations

import numpy as np

from mrcomm_env.asynccl.env import AGE_SCALE, BITS_SCALE, OTHER_FEATURES, OWN_FEATURES


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
