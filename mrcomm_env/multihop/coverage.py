"""Lloyd-style Voronoi coverage controller (Cortés et al. 2004, the paper's ref. [2]) on received estimates.

Each robot partitions the square into Voronoi cells using its *own* current position and its *estimates*
of the others (unknown estimates are ignored: the robot does not know they exist), takes the centroid
``C_i`` of its own cell (uniform density, sampled on a regular grid) and moves as ``ṗ_i = k (C_i - p_i)``,
speed-limited, like the paper's simulated flying robots. The coverage cost uses the true positions.
"""

from __future__ import annotations

import numpy as np


def sample_points(side: float, res: int) -> np.ndarray:
    """Cell centres of a ``res × res`` grid over ``[0, side]²`` as ``(res², 2)``."""
    c = (np.arange(res) + 0.5) * (side / res)
    xx, yy = np.meshgrid(c, c)
    return np.column_stack([xx.ravel(), yy.ravel()])


def centroids(points: np.ndarray, own: np.ndarray, est: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Centroid of each robot's own cell as *it* sees the partition.

    ``own`` (n, 2) true positions, ``est`` (n, n, 2) robot i's estimate of robot j, ``known`` (n, n); or all three
    with a leading copy axis (M, …), for every copy at once with the numbers each has alone (numpy's ``matmul``
    over a stack multiplies each copy's matrices as it multiplies them alone).
    """
    n = own.shape[-2]
    sites = est.copy()
    idx = np.arange(n)
    sites[..., idx, idx, :] = own
    # ||q - s||² up to the ||q||² term every site shares (argmin over sites only needs the rest)
    flat = sites.reshape(*sites.shape[:-3], n * n, 2)
    d2 = ((flat * flat).sum(-1)[..., None] - 2.0 * (flat @ points.T)).reshape(*sites.shape[:-1], -1)  # (…, n, n, P)
    d2 = np.where((known | np.eye(n, dtype=bool))[..., None], d2, np.inf)
    mine = d2.argmin(axis=-2) == idx[:, None]  # (…, n, P): point is in robot i's cell (its own view)
    cnt = mine.sum(axis=-1)
    c = (mine.astype(np.float64) @ points) / np.maximum(cnt, 1)[..., None]
    return np.where(cnt[..., None] > 0, c, own)


def control_step(pos: np.ndarray, target: np.ndarray, gain: float, vmax: float, dt: float, side: float) -> np.ndarray:
    """``ṗ = k (C - p)`` with ``|ṗ| <= vmax``, one Euler step that never passes ``C``, clipped to the square
    (``pos`` and ``target`` (n, 2), or (M, n, 2) for every copy at once).

    For ``k dt ≤ 1`` (every control period of the default gain) this is the plain Euler step; a larger
    ``k dt`` would overshoot the target and oscillate, which the continuous dynamics never do."""
    v = min(gain, 1.0 / dt) * (target - pos)
    speed = np.linalg.norm(v, axis=-1, keepdims=True)
    v = np.where(speed > vmax, v * (vmax / np.maximum(speed, 1e-12)), v)
    return np.clip(pos + v * dt, 0.0, side)
