"""The UTIAS MRCLAM Dataset 6 (Leung, Halpern, Barfoot & Liu, IJRR 2011): five real robots, their odometry and
robot-to-robot range/bearing, resampled onto the env's time grid and replayed as AsyncCL's trajectory ``mrclam``.

The data are never copied into this repository: the files are read from a folder (:func:`resolve_data_dir`:
the ``data_dir`` argument, else ``$MRCLAM_DIR``, else a ``shared/data/MRCLAM_Dataset6`` folder beside the
repository checkout or one of its parents). Download: http://asrl.utias.utoronto.ca/datasets/mrclam/
(``MRCLAM_Dataset6.zip``, unzip so that ``Barcodes.dat`` sits in the folder).

Resampling onto steps of ``dt`` seconds from the latest common start of ground truth and odometry to the
earliest common end (Robot1's ground truth ends first, ≈ 756 s after the common start, 772 s after its own):

* ground truth ``(K, 5, 3)``: linear interpolation of x, y and the unwrapped heading (motion capture at
  ≈ 100 Hz; its largest gap is 2 s, Robot4's);
* odometry ``(K, 5, 2)``: the latest odometry sample at or before each step (zero-order hold), so
  ``odometry[k]`` is the [v, ω] applied from step k to k+1, the convention of eq. (1);
* measurements: every robot-to-robot range/bearing (subjects 1–5 via ``Barcodes.dat``) assigned to the
  nearest step, in (step, observer, target) order. **Landmark sightings are dropped**: paper 000's
  model (eq. (2)) has relative robot-to-robot measurements only.

**Measured noise** (:func:`measured_noise`, run once per data folder and ``dt``, cached), in the parameters
of the env's EKF model (``ekf.py``): Q = diag((σ_v·v_m)², σ_ω²) per step of dt, R = diag((σ_d·d_m)², σ_θ²).

* Odometry against the ground truth over windows of W = round(1 s / dt) steps: per window and robot the
  error of the travelled distance along the heading, e_v = Σ (Δtruth · heading) − Σ v_m dt, and of the
  turn, e_ω = Σ wrapped Δφ − Σ ω_m dt. A per-step white noise of the model accumulates over W steps to
  Var e_v = σ_v² Σ (v_m dt)² and Var e_ω = W σ_ω² dt², so σ_v² = Σ e_v² / Σ Σ (v_m dt)² (pooled over
  windows: the moment estimate that matches the total error energy; a per-window ratio is dominated by the
  10 % of windows standing still) and σ_ω² = mean e_ω² / (W dt²). One-second windows make the motion
  capture's millimetre noise negligible beside a window's displacement (≈ 10 cm); the real error is not
  white (it grows faster than √W: σ_v 0.36 at W = 1, 0.82 at W = 20, 1.03 at W = 40 for dt = 0.05, and
  the odometry leads the motion by ≈ 0.2 s), so the figures are the white noise that matches the error of
  one second of dead reckoning, the horizon between a robot's relative measurements.
* Range and bearing against the ground-truth geometry at the measurement's step: σ_d the RMS of
  (z_d − d)/z_d and σ_θ the RMS of the wrapped bearing error, over the measurements within ``OUTLIER_GATE``
  robust standard deviations (1.4826 × median absolute deviation) of the median on both. The others are
  misreadings (a wrong barcode, a reflection: bearing errors up to 99°) that a Gaussian model cannot
  describe; the replay drops them too (:func:`replay_measurements`).

For dt = 0.05 s (the env's default), from 3775 one-second windows and 3711 range/bearings: σ_v = 0.817 (of v),
σ_ω = 10.4 deg/s, σ_d = 0.0427 (of d), σ_θ = 0.520 deg; 120 of the 3711 robot-to-robot measurements are
misreadings. (§IV of the paper simulates
σ_v = 0.02, σ_ω = 1 deg/s, σ_d = 0.02, σ_θ = 1 deg: the real odometry is 10–40× noisier, the real range
twice as noisy and the bearing twice as precise.)
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

N_ROBOTS = 5
FOLDER = "MRCLAM_Dataset6"
DOWNLOAD = "http://asrl.utias.utoronto.ca/datasets/mrclam/"
MIN_DT = 0.01  # motion capture at ~100 Hz and odometry at ~67 Hz: a finer grid only repeats samples
NOISE_WINDOW_S = 1.0  # seconds of dead reckoning per odometry-noise window (module doc)
OUTLIER_GATE = 5.0  # robust standard deviations beyond which a range/bearing is a misreading (module doc)
_MAD_TO_SIGMA = 1.4826  # σ of a normal distribution per median absolute deviation


class MrclamNotFoundError(FileNotFoundError, ValueError):
    """No MRCLAM Dataset 6 where it was looked for (a ``ValueError`` too: it is a bad ``data_dir`` argument)."""


def _candidates() -> list[Path]:
    """Where the shared copy may be: ``shared/data/MRCLAM_Dataset6`` in any parent of this checkout (a git
    worktree sits one level deeper than the main checkout) or of the working directory."""
    seen, out = set(), []
    for start in (Path(__file__).resolve().parent, Path.cwd().resolve()):
        for parent in (start, *start.parents):
            p = parent / "shared" / "data" / FOLDER
            if p not in seen:
                seen.add(p)
                out.append(p)
    return out


def _is_dataset(path: Path) -> bool:
    return (path / "Barcodes.dat").is_file()


def resolve_data_dir(data_dir: str | os.PathLike | None = None) -> Path:
    """The folder of Dataset 6: ``data_dir``, else ``$MRCLAM_DIR``, else the first shared copy found
    beside the checkout. Raises :class:`MrclamNotFoundError` saying where it looked and how to get the data."""
    if data_dir is not None:
        tried = [Path(data_dir).expanduser()]
    elif os.environ.get("MRCLAM_DIR"):
        tried = [Path(os.environ["MRCLAM_DIR"]).expanduser()]
    else:
        tried = _candidates()
    for path in tried:
        if _is_dataset(path):
            return path.resolve()
    where = str(tried[0]) if len(tried) == 1 else f"$MRCLAM_DIR (unset) and {', '.join(map(str, tried))}"
    raise MrclamNotFoundError(
        f"argument 'data_dir': no MRCLAM Dataset 6 (Barcodes.dat) in {where}; download {FOLDER}.zip from "
        f"{DOWNLOAD}, unzip it and pass data_dir=<folder> or set MRCLAM_DIR"
    )


def default_path() -> Path | None:
    """The folder :func:`resolve_data_dir` finds without a ``data_dir`` argument, or None when there is none."""
    try:
        return resolve_data_dir()
    except MrclamNotFoundError:
        return None


def _read(path: Path) -> np.ndarray:
    return np.loadtxt(path, comments="#", ndmin=2)


@lru_cache(maxsize=4)
def _raw(root: Path) -> tuple:
    """The published files of one folder, parsed once per process (≈ 1 s: 1.5 million lines)."""
    barcodes = _read(root / "Barcodes.dat").astype(int)
    robot_of_barcode = {int(bc): int(subj) - 1 for subj, bc in barcodes if 1 <= subj <= N_ROBOTS}
    gt = tuple(_read(root / f"Robot{i + 1}_Groundtruth.dat") for i in range(N_ROBOTS))
    odo = tuple(_read(root / f"Robot{i + 1}_Odometry.dat") for i in range(N_ROBOTS))
    mea = tuple(_read(root / f"Robot{i + 1}_Measurement.dat") for i in range(N_ROBOTS))
    return robot_of_barcode, gt, odo, mea


def load_mrclam(path: str | os.PathLike | None = None, dt: float = 0.05, duration: float | None = None) -> dict:
    """Resampled dataset: ``truth``, ``odometry``, ``meas_step``, ``meas_a``, ``meas_b``, ``meas_z``, ``dt``, ``t0``
    and ``root`` (the folder read)."""
    if not (math.isfinite(dt) and dt >= MIN_DT):
        raise ValueError(f"argument 'dt' must be at least {MIN_DT} s to resample MRCLAM (≈ 100 Hz), got {dt!r}")
    root = resolve_data_dir(path)
    robot_of_barcode, gt, odo, mea = _raw(root)
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
        target = np.array([robot_of_barcode.get(int(s), -1) for s in m[:, 1]], dtype=np.int64)
        step = np.rint((m[:, 0] - t0) / dt).astype(np.int64)
        keep = (target >= 0) & (target != i) & (step >= 0) & (step < k)
        steps.append(step[keep])
        obs.append(np.full(int(keep.sum()), i, dtype=np.int64))
        tgt.append(target[keep])
        z.append(m[keep, 2:4])
    steps, obs, tgt = np.concatenate(steps), np.concatenate(obs), np.concatenate(tgt)
    z = np.concatenate(z).reshape(-1, 2)
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
        "root": root,
    }


@lru_cache(maxsize=8)
def _load_cached(root: Path, dt: float) -> dict:
    """One resampling per folder and dt, shared by every env of the process: read-only, so that no env can
    change another's recording (the replay hands out views of these arrays, not copies)."""
    data = load_mrclam(root, dt)
    for value in data.values():
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
    return data


def _wrap(angle):
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def measurement_errors(data: dict) -> tuple[np.ndarray, np.ndarray]:
    """Relative range errors (z_d − d)/z_d and wrapped bearing errors of every measurement against the ground truth."""
    truth, s, a, b, z = data["truth"], data["meas_step"], data["meas_a"], data["meas_b"], data["meas_z"]
    diff = truth[s, b, :2] - truth[s, a, :2]
    d = np.hypot(diff[:, 0], diff[:, 1])
    bearing = np.arctan2(diff[:, 1], diff[:, 0]) - truth[s, a, 2]
    return (z[:, 0] - d) / z[:, 0], _wrap(z[:, 1] - bearing)


def inliers(data: dict) -> np.ndarray:
    """Mask of the measurements within ``OUTLIER_GATE`` robust σ of the median on range and bearing (module doc)."""
    er, eb = measurement_errors(data)
    keep = np.ones(len(er), dtype=bool)
    for e in (er, eb):
        centre = np.median(e)
        spread = _MAD_TO_SIGMA * np.median(np.abs(e - centre))
        keep &= np.abs(e - centre) <= OUTLIER_GATE * spread
    return keep


@dataclass(frozen=True)
class MeasuredNoise:
    """Noise of the recording in the env's parameters (module doc): fractions of v and d, rad/s and rad."""

    sigma_v: float
    sigma_omega: float
    sigma_d: float
    sigma_theta: float
    dt: float
    odometry_windows: int
    measurements: int
    misreadings: int

    def as_dict(self) -> dict:
        return asdict(self)


def estimate_noise(data: dict) -> MeasuredNoise:
    """σ_v, σ_ω of the odometry and σ_d, σ_θ of the range/bearing, estimated against the ground truth (module doc)."""
    truth, odo, dt = data["truth"], data["odometry"], data["dt"]
    w = max(1, int(round(NOISE_WINDOW_S / dt)))
    n_win = (len(truth) - 1) // w
    steps = n_win * w
    move = truth[1 : steps + 1, :, :2] - truth[:steps, :, :2]
    heading = truth[:steps, :, 2]
    along = move[..., 0] * np.cos(heading) + move[..., 1] * np.sin(heading)  # distance travelled per step
    turn = _wrap(truth[1 : steps + 1, :, 2] - heading)
    vdt, wdt = odo[:steps, :, 0] * dt, odo[:steps, :, 1] * dt
    e_v = (along - vdt).reshape(n_win, w, -1).sum(axis=1)
    e_w = (turn - wdt).reshape(n_win, w, -1).sum(axis=1)
    v2 = (vdt * vdt).reshape(n_win, w, -1).sum(axis=1)
    sigma_v = math.sqrt(float(np.sum(e_v * e_v)) / float(np.sum(v2)))
    sigma_omega = math.sqrt(float(np.mean(e_w * e_w)) / w) / dt
    er, eb = measurement_errors(data)
    keep = inliers(data)
    return MeasuredNoise(
        sigma_v=sigma_v,
        sigma_omega=sigma_omega,
        sigma_d=math.sqrt(float(np.mean(er[keep] ** 2))),
        sigma_theta=math.sqrt(float(np.mean(eb[keep] ** 2))),
        dt=dt,
        odometry_windows=int(e_v.size),
        measurements=len(er),
        misreadings=int((~keep).sum()),
    )


@lru_cache(maxsize=8)
def _noise_cached(root: Path, dt: float) -> MeasuredNoise:
    return estimate_noise(_load_cached(root, dt))


def measured_noise(data_dir: str | os.PathLike | None = None, dt: float = 0.05) -> MeasuredNoise:
    """:func:`estimate_noise` of the folder's recording on a grid of ``dt``, computed once per folder and dt."""
    return _noise_cached(resolve_data_dir(data_dir), float(dt))


class MrclamReplay:
    """The trajectory source ``mrclam`` of AsyncCL's ``World``: windows of the recording, replayed step by step.

    An episode of ``horizon`` steps needs steps k₀ … k₀ + horizon of the recording; k₀ is drawn uniformly from
    the seeded generator. The replay serves the true poses (``truth``), the odometry (``odometry``) and the
    range/bearing measurements of a step: the recording's robot-to-robot measurements without misreadings
    (``inliers``) and without those beyond ``sensing_radius`` (measured range), in (observer, target) order.
    A step's observer/target arrays are shared by every step with the same sensing graph, so the EKF's
    per-graph tables (``ekf.Geometry``) are found by identity. Pickling keeps only (folder, dt, horizon,
    sensing radius, k₀): the arrays come back from the per-process cache.
    """

    def __init__(self, data_dir, dt: float, horizon: int, sensing_radius: float):
        self.root = resolve_data_dir(data_dir)
        self.dt, self.horizon, self.sensing_radius = float(dt), int(horizon), float(sensing_radius)
        self.k0 = 0
        self._build()
        if self.horizon + 1 > self.n_steps:
            raise ValueError(
                f"argument 'max_cycles' must be at most {self.n_steps - 1} on trajectory='mrclam' with dt={dt} "
                f"(the recording holds {self.n_steps} steps, {self.n_steps * dt:.0f} s), got {horizon}"
            )

    def _build(self) -> None:
        data = _load_cached(self.root, self.dt)
        self.truth, self.odometry = data["truth"], data["odometry"]
        self.n_steps = len(self.truth)
        keep = inliers(data) & (data["meas_z"][:, 0] <= self.sensing_radius)
        s, a, b, z = data["meas_step"][keep], data["meas_a"][keep], data["meas_b"][keep], data["meas_z"][keep]
        self._start = np.searchsorted(s, np.arange(self.n_steps + 1))  # measurements of step k: start[k]:start[k+1]
        self._z = np.ascontiguousarray(z)
        graphs: dict[bytes, tuple] = {}
        empty = np.zeros(0, dtype=np.int64)
        graphs[b""] = (empty, empty, np.zeros(N_ROBOTS, dtype=np.int64))
        self._graph = [None] * self.n_steps
        for k in range(self.n_steps):
            lo, hi = self._start[k], self._start[k + 1]
            key = a[lo:hi].tobytes() + b[lo:hi].tobytes()
            g = graphs.get(key)
            if g is None:
                ak, bk = a[lo:hi].copy(), b[lo:hi].copy()
                g = graphs[key] = (ak, bk, np.bincount(ak, minlength=N_ROBOTS).astype(np.int64))
            self._graph[k] = g
        self.n_measurements = len(s)

    def __getstate__(self):
        return {key: getattr(self, key) for key in ("root", "dt", "horizon", "sensing_radius", "k0")}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._build()

    def reset(self, rng: np.random.Generator) -> None:
        """Draw the window's first step k₀ from the env's seeded generator."""
        self.k0 = int(rng.integers(0, self.n_steps - self.horizon))

    def pose(self, k: int) -> np.ndarray:
        return self.truth[self.k0 + k]

    def odometry_at(self, k: int) -> np.ndarray:
        return self.odometry[self.k0 + k]

    def measurements(self, k: int) -> tuple:
        """(observer ids, target ids, [d, θ] rows, measurements per robot) of episode step k."""
        j = self.k0 + k
        a, b, n_meas = self._graph[j]
        return a, b, self._z[self._start[j] : self._start[j + 1]], n_meas
