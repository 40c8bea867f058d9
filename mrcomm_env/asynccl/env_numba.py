"""Two per-step computations of ``AsyncCLEnv``: the observation (``_observe``) and the
team's position and heading errors (``_errors``), compiled (numba).

Both are a few dozen numpy operations on N × N arrays (N = 5 by default), so numpy's per-call overhead is most of
their cost (about a tenth of a step). The kernels compute every entry with the same operations in the same order:
the reductions add in numpy's order at these sizes (robot after robot: the reduced axis is not the contiguous
one), a heading is wrapped with Python's float modulo, which is ``np.remainder``'s rule, and a float32 entry is
rounded once from float64, as numpy's assignment into a float32 array rounds it. The own-pose log scale is left to
numpy (``np.log10``, whose vectorised loops may round otherwise than the C library's). Tests compare both with the
numpy oracle bit for bit (``tests/helpers/asynccl_reference.py``, ``tests/asynccl/test_asynccl.py``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mrcomm_env.core.backend import configure_numba_cache

configure_numba_cache()  # before the @njit(cache=True) below: never cache into the package


@numba.njit(cache=True)
def observe(out, adj, latest, known, c, t, clock, neighbours, ema, age_scale, bits_scale):
    """Every column of the observation but the own-pose trace (column ``3(N−1) + 2``) into ``out`` (N, 3(N−1) + 5)
    float32: per other robot (i + k mod N in block k − 1) linked, row lag, what it lacks; then delay, clock,
    (trace: left), neighbours, recent bits."""
    n = adj.shape[0]
    k = 3 * (n - 1)
    for i in range(n):
        for o in range(1, n):
            j = (i + o) % n
            base = 3 * (o - 1)
            behind = t - latest[i, j]
            lacks = t - known[i, j]
            out[i, base] = 1.0 if adj[i, j] else 0.0
            out[i, base + 1] = behind / (behind + age_scale)
            out[i, base + 2] = lacks / (lacks + age_scale)
        delay = t - 1 - c[i]
        out[i, k] = delay / (delay + age_scale)
        out[i, k + 1] = clock
        out[i, k + 3] = neighbours[i] / (n - 1)
        out[i, k + 4] = ema[i] / (ema[i] + bits_scale)


@numba.njit(cache=True)
def own_pose_traces(P):
    """(N,) the trace of each robot's own-pose block of its covariance ``P`` (N, 3N, 3N), summed x, y, φ."""
    n = P.shape[0]
    out = np.empty(n)
    for i in range(n):
        out[i] = P[i, 3 * i, 3 * i] + P[i, 3 * i + 1, 3 * i + 1] + P[i, 3 * i + 2, 3 * i + 2]
    return out


@numba.njit(cache=True)
def errors(X, x):
    """``(rms_position, rms_orientation, mean_position, mean_orientation)``: each robot's RMS error over the team
    of its estimates ``X`` (N, 3N) against the truth ``x`` (N, 3), headings wrapped into [−π, π), and their
    means over the robots."""
    n = x.shape[0]
    pos = np.empty(n)
    ori = np.empty(n)
    two_pi = 2.0 * np.pi
    for i in range(n):
        sx = sy = sp = 0.0
        for j in range(n):
            ex = X[i, 3 * j] - x[j, 0]
            ey = X[i, 3 * j + 1] - x[j, 1]
            ep = ((X[i, 3 * j + 2] - x[j, 2]) + np.pi) % two_pi - np.pi
            sx += ex * ex
            sy += ey * ey
            sp += ep * ep
        pos[i] = math.sqrt((sx + sy) * (1.0 / n))
        ori[i] = math.sqrt(sp * (1.0 / n))
    mean_pos = mean_ori = 0.0
    for i in range(n):
        mean_pos += pos[i]
        mean_ori += ori[i]
    return pos, ori, mean_pos * (1.0 / n), mean_ori * (1.0 / n)
