"""Loader for the UTIAS MRCLAM Dataset 6 (Leung et al., IJRR 2011): five real robots, odometry and
robot-to-robot range/bearing, resampled onto the env's time grid.

The data are never copied into this repository: :func:`load_mrclam` reads the published files from a
folder (default ``$MRCLAM_DIR`` or ``../shared/data/MRCLAM_Dataset6`` next to the repository).

Resampling onto steps of ``dt`` seconds from the latest common start time:

* ground truth ``(K, 5, 3)``: linear interpolation of x, y and the unwrapped heading;
* odometry ``(K, 5, 2)``: the latest odometry sample at or before each step (zero-order hold);
* measurements: every robot-to-robot range/bearing (subjects 1–5 via ``Barcodes.dat``; landmarks are
  dropped) assigned to the nearest step, in (step, observer, target) order.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

N_ROBOTS = 5


def default_path() -> Path:
    env = os.environ.get("MRCLAM_DIR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "shared" / "data" / "MRCLAM_Dataset6"


def _read(path: Path) -> np.ndarray:
    return np.loadtxt(path, comments="#", ndmin=2)


def load_mrclam(path: str | Path | None = None, dt: float = 0.05, duration: float | None = None) -> dict:
    """Resampled dataset: ``truth``, ``odometry``, ``meas_step``, ``meas_a``, ``meas_b``, ``meas_z``, ``dt``."""
    root = Path(path) if path is not None else default_path()
    if not (root / "Barcodes.dat").exists():
        raise FileNotFoundError(f"argument 'path': no MRCLAM dataset at {root}")
    barcodes = _read(root / "Barcodes.dat").astype(int)
    robot_of_barcode = {int(bc): int(subj) - 1 for subj, bc in barcodes if 1 <= subj <= N_ROBOTS}
    gt = [_read(root / f"Robot{i + 1}_Groundtruth.dat") for i in range(N_ROBOTS)]
    odo = [_read(root / f"Robot{i + 1}_Odometry.dat") for i in range(N_ROBOTS)]
    mea = [_read(root / f"Robot{i + 1}_Measurement.dat") for i in range(N_ROBOTS)]
    t0 = max(max(g[0, 0], o[0, 0]) for g, o in zip(gt, odo, strict=True))
    t_end = min(min(g[-1, 0], o[-1, 0]) for g, o in zip(gt, odo, strict=True))
    if duration is not None:
        t_end = min(t_end, t0 + duration)
    k = int(np.floor((t_end - t0) / dt)) + 1
    times = t0 + dt * np.arange(k)
    truth = np.empty((k, N_ROBOTS, 3))
    odometry = np.empty((k, N_ROBOTS, 2))
    for i in range(N_ROBOTS):
        g = gt[i]
        truth[:, i, 0] = np.interp(times, g[:, 0], g[:, 1])
        truth[:, i, 1] = np.interp(times, g[:, 0], g[:, 2])
        heading = np.interp(times, g[:, 0], np.unwrap(g[:, 3]))
        truth[:, i, 2] = (heading + np.pi) % (2 * np.pi) - np.pi
        idx = np.clip(np.searchsorted(odo[i][:, 0], times, side="right") - 1, 0, len(odo[i]) - 1)
        odometry[:, i] = odo[i][idx, 1:3]
    steps, obs, tgt, z = [], [], [], []
    for i in range(N_ROBOTS):
        m = mea[i]
        for tm, subj, rng, brg in m:
            j = robot_of_barcode.get(int(subj))
            s = int(round((tm - t0) / dt))
            if j is None or j == i or not 0 <= s < k:
                continue
            steps.append(s)
            obs.append(i)
            tgt.append(j)
            z.append((rng, brg))
    steps, obs, tgt = np.array(steps, dtype=np.int64), np.array(obs, dtype=np.int64), np.array(tgt, dtype=np.int64)
    z = np.array(z, dtype=float).reshape(-1, 2)
    order = np.lexsort((tgt, obs, steps))
    return {
        "truth": truth,
        "odometry": odometry,
        "meas_step": steps[order],
        "meas_a": obs[order],
        "meas_b": tgt[order],
        "meas_z": z[order],
        "dt": dt,
        "t0": t0,
    }
