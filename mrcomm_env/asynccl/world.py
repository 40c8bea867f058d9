"""The robots' world of paper 000 (§II, §IV): unicycle motion, odometry, range/bearing sensing, packets.

Truth follows the unicycle model ``x_{k+1} = f(x_k, u_k)`` (eq. (1)) with dt = 0.05 s. The true controls
come from a phase-shifted sinusoidal path (the default of §IV: every robot runs the same figure-eight
``x = A sin s, y = B sin 2s`` with its own phase ``s = w t + φ_i``) or from a random-waypoint controller.
With ``trajectory="mrclam"`` a recording replaces all three: truth, odometry and range/bearing are those of
five real robots (``mrclam.MrclamReplay``, a window of UTIAS MRCLAM Dataset 6), and nothing is drawn here.

The measurement packet ``M_k^i`` of eq. (3) holds the odometry ``u_k^i = [v_m, ω_m]`` and the range/bearing
``z_k^{i,j}`` to every robot within the sensing radius (eq. (2)). Noise follows §IV: σ_v = 2 % of v,
σ_ω = 1 deg/s, σ_d = 2 % of d, σ_θ = 1 deg (all arguments).

**Bit size of a packet** (documented, used by the bit ledger and by the bandwidth budget):

* tag: robot id (``ID_BITS`` = 8) + time step (``STEP_BITS`` = 32),
* odometry: 2 × 32-bit floats,
* every range/bearing measurement: target id (8) + 2 × 32-bit floats = 72 bits.

So ``|M_k^i| = 40 + 64 + 72 m_k^i`` bits with ``m_k^i`` measurements. A list entry of ``L_i``
(robot id, latest step) is 40 bits; the header of every transmission carries the sender's id and its
complete and discard frontiers (8 + 2 × 32 = 72 bits).
"""

from __future__ import annotations

import numpy as np

ID_BITS = 8
STEP_BITS = 32
FLOAT_BITS = 32
PACKET_BASE_BITS = ID_BITS + STEP_BITS + 2 * FLOAT_BITS
MEAS_BITS = ID_BITS + 2 * FLOAT_BITS
LIST_ENTRY_BITS = ID_BITS + STEP_BITS
HEADER_BITS = ID_BITS + 2 * STEP_BITS

SIN_A, SIN_B, SIN_W = 2.0, 1.0, 0.25  # figure-eight half-widths (m) and angular rate (rad/s)
CHUNK = 128  # sinusoidal episodes are generated this many steps at a time ...
# ... unless the team is large: a chunk holds (steps × ordered pairs) distances, bearings and noise, so the
# steps per chunk shrink to keep it near this many pair-steps (16 MiB per float array; N ≤ 91 keeps 128 steps,
# N = 200 takes 26). Without this bound N = 2000 asked for 7.6 GiB in one array.
CHUNK_PAIR_STEPS = 1 << 20
MIN_RANGE = 0.05  # closer than this the sensor gives no reading (keeps bearings defined)
WP_ARENA, WP_SPEED, WP_GAIN, WP_MAX_TURN, WP_REACHED = 6.0, 0.4, 2.0, 1.0, 0.3


def wrap(angle):
    """Angle in (-π, π]."""
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


class Packets:
    """The measurement packets of one time step (a column of the information table)."""

    __slots__ = ("u", "a", "b", "z", "n_meas", "bits", "hidx")

    def __init__(self, u, a, b, z, n_meas):
        self.u = u  # (N, 2) measured [v, ω]
        self.a = a  # (m,) observer ids, sorted by (observer, target)
        self.b = b  # (m,) target ids
        self.z = z  # (m, 2) measured [d, θ] (None when estimation is off)
        self.n_meas = n_meas  # (N,) measurements per robot
        self.bits = PACKET_BASE_BITS + MEAS_BITS * n_meas  # (N,) bits of M_k^i
        self.hidx = None  # index tables of the sensing graph, ``ekf.Geometry`` (filled by the EKF on first use)


class World:
    def __init__(
        self,
        n,
        dt,
        trajectory,
        sensing_radius,
        sigma_v_frac,
        sigma_omega,
        sigma_d_frac,
        sigma_theta,
        estimation,
        source=None,
    ):
        self.n, self.dt, self.trajectory = n, dt, trajectory
        self.source = source  # a recorded trajectory (``mrclam.MrclamReplay``) when trajectory == "mrclam"
        self.sensing_radius = sensing_radius
        self.sigma_v_frac, self.sigma_omega = sigma_v_frac, sigma_omega
        self.sigma_d_frac, self.sigma_theta = sigma_d_frac, sigma_theta
        self.estimation = estimation
        self._pairs_a, self._pairs_b = np.nonzero(~np.eye(n, dtype=bool))  # all ordered pairs, (a, b) order

    # ------------------------------------------------------------------ truth
    def reset(self, rng: np.random.Generator) -> None:
        n = self.n
        self.k = 0
        if self.source is not None:  # a recording: truth, odometry and measurements are replayed, not drawn
            self.source.reset(rng)
            self.x = self.source.pose(0)
            return
        if self.trajectory == "sinusoid":
            self.phase = 2.0 * np.pi * np.arange(n) / n + rng.uniform(-0.1, 0.1, n)
            self.centre = rng.uniform(-1.0, 1.0, (n, 2))
            s = self.phase
            xd, yd = SIN_A * SIN_W * np.cos(s), 2.0 * SIN_B * SIN_W * np.cos(2.0 * s)
            self.x = np.column_stack(
                [self.centre[:, 0] + SIN_A * np.sin(s), self.centre[:, 1] + SIN_B * np.sin(2.0 * s), np.arctan2(yd, xd)]
            )
            self._chunk_start = 0
            self._build_chunk(rng, self.x)
            return
        self.x = np.column_stack([rng.uniform(0, WP_ARENA, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
        self.waypoint = rng.uniform(0, WP_ARENA, (n, 2))
        self.u_true = self._controls(rng)

    # ------------------------------------------------------------------ sinusoids: CHUNK steps at once
    def _build_chunk(self, rng, x0) -> None:
        """Truth, controls and packets of steps k … k+CHUNK-1 in one vectorised pass.

        The unicycle recursion x_{k+1} = x_k + v_k cos φ_k dt, φ_{k+1} = φ_k + ω_k dt (eq. (1)) is a cumulative
        sum over steps; the open-loop sinusoidal controls do not depend on the state.
        """
        n, dt = self.n, self.dt
        C = self._chunk_len = int(np.clip(CHUNK_PAIR_STEPS // max(len(self._pairs_a), 1), 1, CHUNK))
        s = SIN_W * dt * (self.k + np.arange(C))[:, None] + self.phase[None, :]
        w = SIN_W
        xd, yd = SIN_A * w * np.cos(s), 2.0 * SIN_B * w * np.cos(2.0 * s)
        xdd, ydd = -SIN_A * w * w * np.sin(s), -4.0 * SIN_B * w * w * np.sin(2.0 * s)
        v2 = xd * xd + yd * yd
        v, om = np.sqrt(v2), (xd * ydd - yd * xdd) / v2
        phi = x0[:, 2] + np.concatenate([np.zeros((1, n)), np.cumsum(om * dt, axis=0)])  # (C+1, n)
        px = x0[:, 0] + np.concatenate([np.zeros((1, n)), np.cumsum(v * np.cos(phi[:-1]) * dt, axis=0)])
        py = x0[:, 1] + np.concatenate([np.zeros((1, n)), np.cumsum(v * np.sin(phi[:-1]) * dt, axis=0)])
        xs = np.stack([px, py, wrap(phi)], axis=2)  # (C+1, n, 3): steps k … k+C
        self._xs, self._next_x0 = xs[:C], xs[C]
        self._u_true = np.stack([v, om], axis=2)
        a, b = self._pairs_a, self._pairs_b
        diff = xs[:C, b, :2] - xs[:C, a, :2]
        d = np.sqrt(diff[..., 0] ** 2 + diff[..., 1] ** 2)  # (C, M)
        keep = (d >= MIN_RANGE) & (d <= self.sensing_radius)
        self._keep, self._all_kept = keep, keep.all(axis=1)
        self._n_meas = (
            np.stack([np.bincount(a, weights=kp, minlength=n) for kp in keep]).astype(np.int64)
            if not keep.all()
            else np.full((C, n), n - 1, dtype=np.int64)
        )
        if self.estimation:
            noise = rng.standard_normal((C, n, 2))
            self._u = np.stack(
                [v + self.sigma_v_frac * v * noise[..., 0], om + self.sigma_omega * noise[..., 1]], axis=2
            )
            nz = rng.standard_normal((C, len(a), 2))
            bearing = np.arctan2(diff[..., 1], diff[..., 0]) - xs[:C, a, 2]
            self._z = np.stack(
                [d * (1.0 + self.sigma_d_frac * nz[..., 0]), wrap(bearing + self.sigma_theta * nz[..., 1])], axis=2
            )
        self._chunk_start = self.k
        self.x = self._xs[0]
        self.u_true = self._u_true[0]

    def _controls(self, rng) -> np.ndarray:
        """True [v, ω] applied from step k to k+1."""
        if self.trajectory == "sinusoid":
            s = SIN_W * self.k * self.dt + self.phase
            w = SIN_W
            xd, yd = SIN_A * w * np.cos(s), 2.0 * SIN_B * w * np.cos(2.0 * s)
            xdd, ydd = -SIN_A * w * w * np.sin(s), -4.0 * SIN_B * w * w * np.sin(2.0 * s)
            v2 = xd * xd + yd * yd
            return np.column_stack([np.sqrt(v2), (xd * ydd - yd * xdd) / v2])
        delta = self.waypoint - self.x[:, :2]
        reached = np.einsum("ij,ij->i", delta, delta) < WP_REACHED**2
        if reached.any():
            self.waypoint[reached] = rng.uniform(0, WP_ARENA, (int(reached.sum()), 2))
            delta = self.waypoint - self.x[:, :2]
        err = wrap(np.arctan2(delta[:, 1], delta[:, 0]) - self.x[:, 2])
        return np.column_stack([np.full(self.n, WP_SPEED), np.clip(WP_GAIN * err, -WP_MAX_TURN, WP_MAX_TURN)])

    def advance(self, rng) -> None:
        """Unicycle step of eq. (1) with the true controls, then the controls of the new step."""
        if self.source is not None:
            self.k += 1
            self.x = self.source.pose(self.k)
            return
        if self.trajectory == "sinusoid":
            self.k += 1
            j = self.k - self._chunk_start
            if j >= self._chunk_len:
                self._build_chunk(rng, self._next_x0)
                j = 0
            self.x = self._xs[j]
            self.u_true = self._u_true[j]
            return
        v, w = self.u_true[:, 0], self.u_true[:, 1]
        phi = self.x[:, 2]
        self.x = np.column_stack(
            [
                self.x[:, 0] + v * np.cos(phi) * self.dt,
                self.x[:, 1] + v * np.sin(phi) * self.dt,
                wrap(phi + w * self.dt),
            ]
        )
        self.k += 1
        self.u_true = self._controls(rng)

    # ------------------------------------------------------------------ measurements, eq. (2)-(3)
    def measure(self, rng) -> Packets:
        n = self.n
        if self.source is not None:
            a, b, z, n_meas = self.source.measurements(self.k)
            if not self.estimation:
                return Packets(None, a, b, None, n_meas)
            return Packets(self.source.odometry_at(self.k), a, b, z, n_meas)
        if self.trajectory == "sinusoid":
            j = self.k - self._chunk_start
            a, b = self._pairs_a, self._pairs_b
            if not self._all_kept[j]:
                kp = self._keep[j]
                a, b = a[kp], b[kp]
            if not self.estimation:
                return Packets(None, a, b, None, self._n_meas[j])
            z = self._z[j] if self._all_kept[j] else self._z[j][self._keep[j]]
            return Packets(self._u[j], a, b, z, self._n_meas[j])
        pos = self.x[:, :2]
        a, b = self._pairs_a, self._pairs_b
        diff = pos[b] - pos[a]
        d = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        keep = (d >= MIN_RANGE) & (d <= self.sensing_radius)
        if not keep.all():
            a, b, diff, d = a[keep], b[keep], diff[keep], d[keep]
        n_meas = np.bincount(a, minlength=n)
        if not self.estimation:
            return Packets(None, a, b, None, n_meas)
        v, w = self.u_true[:, 0], self.u_true[:, 1]
        noise = rng.standard_normal((n, 2))
        u = np.column_stack([v + self.sigma_v_frac * np.abs(v) * noise[:, 0], w + self.sigma_omega * noise[:, 1]])
        m = len(a)
        nz = rng.standard_normal((m, 2))
        bearing = np.arctan2(diff[:, 1], diff[:, 0]) - self.x[a, 2]
        z = np.column_stack([d * (1.0 + self.sigma_d_frac * nz[:, 0]), wrap(bearing + self.sigma_theta * nz[:, 1])])
        return Packets(u, a, b, z, n_meas)
