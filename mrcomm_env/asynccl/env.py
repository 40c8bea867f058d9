"""AsyncCL-v0: asynchronous multi-centralized cooperative localization (Nerurkar & Roumeliotis, paper 000).

| | |
| --- | --- |
| Agents | `n_robots` robots `robot_0 … robot_{N-1}` (default 5; at most 30 with `estimation`, 200 delay-only) |
| Actions | `Discrete(len(modes))` per robot: the transfer mode it uses on all its links this step, an index into `modes` (default `silent`, `scheme1`, `scheme2_q1`, `scheme2_q2`, `scheme2_q4`, `scheme2_q8`, `scheme2_qinf`) |
| Observations | `Box(0, 1, (3(N − 1) + 5,))`, agent-relative: for each other robot, in the order i+1, i+2, … (mod N): linked in the coming exchange (0/1), how many steps behind my copy of its row is `b/(b+10)`, how far behind its complete frontier is as far as I know (what it lacks) `a/(a+10)`; then my own delay `d/(d+10)`, the episode clock `t/max_cycles`, my own-pose covariance trace on a log scale `(log10 tr + 6)/8` (clipped), my neighbours now `/(N−1)`, bits I sent recently (EMA) `e/(e+10⁴)` |
| Reward | team reward `−(mean delay t − c_i)/10` (`reward="delay"`, default) or `−mean_i RMS_pos` of the causal team estimates in metres (`reward="position"`), minus `lam` × kbit sent per robot this step |
| Arguments | `n_robots`, `link_model`, `link_probability`, `comm_radius`, `sensing_radius`, `packet_loss`, `bit_budget`, `modes`, `lam`, `reward`, `estimation`, `max_cycles`, `max_history`, `trajectory`, `data_dir`, `dt`, `sigma_v`, `sigma_omega_deg`, `sigma_d`, `sigma_theta_deg`, `q_rule`, `initial_sigma` |

N robots move in 2D on unicycle paths (phase-shifted sinusoids of §IV, random waypoints, or the recorded paths of
five real robots), measure
their odometry and the range and bearing to every robot within ``sensing_radius``, and communicate over
time-varying bidirectional links: independent Bernoulli(p) links per pair and step (Table I's model),
disk links of radius ``comm_radius``, or both. Each robot keeps the information table T of §II (robots ×
time steps of measurement packets M_k^j) and, at every step, chooses *what to send*: nothing, its own
row (Scheme 1, §III-A) or all it holds from its q oldest columns (Scheme 2, §III-B; q = ∞ is the scheme
of [11] with the L_i / D1 / D2 book-keeping). Information moves one hop per step: what robot j sends at
step k comes from T_k^{j-} (eq. (4)–(5)). The discard rules of §III-A.3 / §III-B.3 keep the tables small.

From its table every robot computes the **delayed centralized estimate** x̂_{c|c} at its complete
frontier c — identical to a centralized EKF on all measurements (tested within the forward-error bound of
the matrices the two filters invert, ``tests/helpers/numerics.py``) — and a **causal
estimate** of the whole team at the current step from what it holds (missing odometry replaced by the
last available one, §IV). The reward trades the delay of eq. (7) (or the causal estimates' position
error) against bits.
``mean_delay`` is eq. (7): steps from k until robot i can compute x̂_{k|k}, over k and robots, ignoring
steps still incomplete when the episode ends. ``estimation=False`` skips the EKF (delay-only runs,
Table I); the error terms are then 0.

**Real robots** (``trajectory="mrclam"``, ``mrclam.py``): the team is the five robots of UTIAS MRCLAM Dataset 6
(Leung et al., IJRR 2011; ``n_robots`` must be 5) and an episode replays a window of ``max_cycles`` steps of
``dt`` of the recording, its start drawn from the seed, inside Robot1's ground truth (the shortest, ≈ 756 s of
common recording): the true poses are the motion-capture ground truth, the odometry the robots' recorded
[v, ω], the measurements their recorded robot-to-robot range/bearing (landmark sightings are not used: the
paper's model has relative robot measurements only; misreadings — a wrong barcode — and ranges beyond
``sensing_radius`` are dropped). Nothing is random but the window, the prior and the links. The links stay the
link models above: the data do not record who could talk to whom. The filters' noise is the one measured from
the data against ground truth (``mrclam.measured_noise``, cached per folder and ``dt``): at dt = 0.05 s
σ_v = 0.817 of v, σ_ω = 10.4 deg/s (odometry, white noise matching one-second dead-reckoning errors),
σ_d = 0.0427 of d, σ_θ = 0.520 deg (120 of 3711 measurements are misreadings), against §IV's 0.02, 1 deg/s,
0.02, 1 deg; an explicit ``sigma_*`` argument sets what the filters assume instead. ``data_dir`` (default
``$MRCLAM_DIR``, else ``shared/data/MRCLAM_Dataset6`` beside the checkout) names the folder; without it the
env raises ``mrclam.MrclamNotFoundError`` (a ``FileNotFoundError`` and a ``ValueError``) saying where it looked
and where to download the data.

One env step = one time step k: the exchange of step k with the chosen modes, the estimates of step k,
then the world moves to k+1 and every robot adds its new packet M_{k+1}^i. The links of the coming
exchange are drawn beforehand, so the observation shows the current neighbour count. Mixed modes in
one step are allowed; a sender never sends what its receiver already holds (idealised hand-shake,
exact for the pure schemes).

**Bits** (``world.py``): a packet M_k^i is 40 bits of tag (8-bit robot id, 32-bit step) + odometry
2 × 32-bit floats + 72 bits per range/bearing measurement (8-bit target id, 2 × 32-bit floats); every
transmission carries a 72-bit header (sender id, its complete and discard frontiers) and under q = ∞
also the list L_i, 40 bits per (robot, latest step) entry. ``bit_budget`` caps the bits per link and
step: header first, then packets oldest step first. ``q_rule`` selects the reading of "the q oldest
time steps" (only the Table I discussion uses the variants). ``max_history`` bounds memory: a robot
that never completed a step which leaves memory abandons it and restarts from its causal estimate.

**Speed**: the table exchange of teams of up to 24 robots without a budget, the observation and the team's errors
are compiled (numba), and so are the EKF column steps (``ekf_numba.py``), whose numpy oracle is under
``tests/``. Tables, bits and delays are the oracle's exactly. Estimates differ by rounding (LU versus Cholesky
inverses), within β·‖x‖ where β = 2·3·(3N + 2m)·ε·Σ_k κ_k adds up the condition numbers κ_k of the matrices each
column step inverts (P⁻ and the information matrix Y, eq. (2)). They agree to round-off while β ≪ 1: over 150 steps
β ≈ 2·10⁻⁷ with the defaults (estimates 10⁻¹⁴ m apart), 2·10⁻⁴ with near-noiseless sensing
(``sigma_d=0.001``, ``sigma_theta_deg=0.01``, 4·10⁻¹⁰ m apart). Only the prior fixes the team's rigid
motion, so κ grows like (``initial_sigma`` / (σ·d))², σ·d the position precision of a range or bearing at
distance d. A prior metres wide with near-noiseless sensing (``initial_sigma=5`` and the values above) puts
κ at 10¹³–10¹⁴ (ε·κ ≈ 10⁻², β ≈ 50): the filter linearises at estimates metres off and amplifies rounding
up to 10–50-fold per step, so the two implementations end metres apart — and so does one whose prior
mean moved by one ulp: the result is set by rounding, not by the data. The metric ``log10_condition`` (log₁₀ of the
largest κ(P_{k|k}) of the centralized estimate) flags it: ≈ 4 by default, ≤ 10.5 where the two agree to
10⁻⁷ m, ≥ 12.5 where they differ by centimetres to metres (docs/architecture.md, "Compiled twins").
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces
from numpy.linalg import _umath_linalg

from mrcomm_env.asynccl import env_numba, mrclam
from mrcomm_env.asynccl.estimator import Estimators
from mrcomm_env.asynccl.spec import (  # noqa: F401 — the limits are part of this module's API
    _SCHEME2_Q,
    ALL_MODES,
    MAX_HISTORY,
    MAX_Q,
    MAX_ROBOTS,
    MAX_ROBOTS_ESTIMATING,
    SIGMA_FLOOR,
    AsyncCLSpec,
    DataDir,
    ModeName,
)
from mrcomm_env.asynccl.table import QINF, SCHEME1, SILENT, InfoTables
from mrcomm_env.asynccl.world import World, wrap
from mrcomm_env.core import (
    BitLedger,
    MrcommParallelEnv,
    apply_packet_loss,
    bernoulli_links,
    combined_links,
    disk_links,
)
from mrcomm_env.core import render as rendering

PAPER_SIGMA_V, PAPER_SIGMA_OMEGA_DEG, PAPER_SIGMA_D, PAPER_SIGMA_THETA_DEG = 0.02, 1.0, 0.02, 1.0  # §IV
AGE_SCALE, BITS_SCALE, EMA = 10.0, 1.0e4, 0.2
OTHER_FEATURES, OWN_FEATURES = 3, 5  # per other robot: linked, row lag, what it lacks; then five of my own
KBIT = 1000.0
EPS = float(np.finfo(np.float64).eps)  # a condition number beyond 1/ε means a numerically singular covariance
_sum = np.add.reduce  # = ndarray.sum without its two Python frames per call (tiny arrays: half the cost)


def mode_code(name: str) -> int:
    """``silent`` → -1, ``scheme1`` → 0, ``scheme2_q<q>`` → q, ``scheme2_qinf`` → ∞ (``QINF``)."""
    if name == "silent":
        return SILENT
    if name == "scheme1":
        return SCHEME1
    if name == "scheme2_qinf":
        return QINF
    return int(name[len("scheme2_q") :])


class AsyncCLEnv(AsyncCLSpec, MrcommParallelEnv):
    ENV_ID = "mrcomm/AsyncCL-v0"
    DESCRIPTION = "Which information-transfer scheme each robot uses per step in asynchronous multi-centralized CL"
    metadata = {"name": "asynccl_v0", "render_modes": ["rgb_array", "human"], "render_fps": 10}

    def _replay(self) -> mrclam.MrclamReplay:
        """The recording of ``trajectory='mrclam'`` (its 5 robots; a window of ``max_cycles`` steps of ``dt``)."""
        cfg = self.cfg
        if cfg["n_robots"] != mrclam.N_ROBOTS:
            raise ValueError(
                f"argument 'n_robots' must be {mrclam.N_ROBOTS} on trajectory='mrclam' (the recording's robots), "
                f"got {cfg['n_robots']}"
            )
        if cfg["dt"] < mrclam.MIN_DT:
            raise ValueError(
                f"argument 'dt' must be at least {mrclam.MIN_DT} s on trajectory='mrclam' (motion capture at "
                f"≈ 100 Hz, odometry at ≈ 67 Hz), got {cfg['dt']!r}"
            )
        return mrclam.MrclamReplay(cfg["data_dir"], cfg["dt"], cfg["max_cycles"], cfg["sensing_radius"])

    def _setup(self) -> None:
        cfg = self.cfg
        n = self.n_agents = cfg["n_robots"]
        if cfg["estimation"] and n > MAX_ROBOTS_ESTIMATING:
            raise ValueError(
                f"argument 'n_robots' must be at most {MAX_ROBOTS_ESTIMATING} when 'estimation' is true "
                f"(every robot's EKF of the whole team needs memory growing as N⁴), got n_robots={n}; "
                f"pass estimation=False for delay-only runs of up to {MAX_ROBOTS} robots"
            )
        if cfg["reward"] == "position" and not cfg["estimation"]:
            raise ValueError("argument 'reward' = 'position' needs estimation=True (no estimates, no position error)")
        self.mode_names = tuple(cfg["modes"])
        self._codes = np.array([mode_code(m) for m in self.mode_names], dtype=np.int64)
        self._obs_space = spaces.Box(0.0, 1.0, shape=(OTHER_FEATURES * (n - 1) + OWN_FEATURES,), dtype=np.float32)
        self._act_space = spaces.Discrete(len(self.mode_names))
        source = None
        if cfg["trajectory"] == "mrclam":
            source = self._replay()
            measured = mrclam.measured_noise(source.root, cfg["dt"])
            defaults = (measured.sigma_v, measured.sigma_omega, measured.sigma_d, measured.sigma_theta)
        else:
            defaults = (
                PAPER_SIGMA_V,
                math.radians(PAPER_SIGMA_OMEGA_DEG),
                PAPER_SIGMA_D,
                math.radians(PAPER_SIGMA_THETA_DEG),
            )
        given = (
            cfg["sigma_v"],
            None if cfg["sigma_omega_deg"] is None else math.radians(cfg["sigma_omega_deg"]),
            cfg["sigma_d"],
            None if cfg["sigma_theta_deg"] is None else math.radians(cfg["sigma_theta_deg"]),
        )
        #: σ_v (of v), σ_ω (rad/s), σ_d (of d), σ_θ (rad): the world's noise on the synthetic trajectories (on
        #: ``mrclam`` the data's own), and before the floor below the noise the filters assume
        self.noise = tuple(float(d if g is None else g) for g, d in zip(given, defaults, strict=True))
        self.world = World(
            n, cfg["dt"], cfg["trajectory"], cfg["sensing_radius"], *self.noise, cfg["estimation"], source
        )
        self.tables = InfoTables(n, cfg["max_history"], cfg["q_rule"])
        self.est = Estimators(n, cfg["dt"], *(max(s, SIGMA_FLOOR) for s in self.noise), cfg["max_history"])
        self.ledger = BitLedger(n)

    # ------------------------------------------------------------------ episode
    def _reset_world(self) -> None:
        cfg, n, rng = self.cfg, self.n_agents, self.np_random
        self.world.reset(rng)
        pk = self.world.measure(rng)
        self.tables.reset(pk.bits)
        self.ledger.reset()
        self._ema = np.zeros(n)
        self._links_used = 0.0
        self._err_pos = np.zeros(n)
        self._err_ori = np.zeros(n)
        self._sum_pos = self._sum_ori = self._sum_table = 0.0
        self._n_err = 0
        self._n_table = 0
        self._max_table = 0.0
        if cfg["estimation"]:
            s0 = cfg["initial_sigma"]
            x0 = (self.world.x + s0 * rng.standard_normal((n, 3))).ravel()
            x0[2::3] = wrap(x0[2::3])
            self.est.reset(x0, np.eye(3 * n) * s0 * s0, pk)
            self.est.step(0, self.tables.c, self.tables.latest)
            self._max_cond = 1.0
            self._note_condition(0)
            self._errors()
        self._draw_links()
        self._account_table()

    def _draw_links(self) -> None:
        cfg, rng = self.cfg, self.np_random
        model = cfg["link_model"]
        if model == "bernoulli":
            adj = bernoulli_links(rng, self.n_agents, cfg["link_probability"])
        elif model == "disk":
            adj = disk_links(self.world.x[:, :2], cfg["comm_radius"])
        else:
            adj = combined_links(rng, self.world.x[:, :2], cfg["comm_radius"], cfg["link_probability"])
        self.adj = adj
        self.delivered = apply_packet_loss(rng, adj, cfg["packet_loss"])
        self.neighbours = _sum(adj, axis=1)

    def _step_world(self, actions: list) -> float:
        cfg, rng, tab = self.cfg, self.np_random, self.tables
        modes = self._codes[actions]
        t = tab.t
        bits, links = tab.exchange(modes, self.adj, self.delivered, cfg["bit_budget"])
        self._sent_per_link = np.divide(bits, links, out=np.zeros(self.n_agents), where=np.asarray(links) > 0)
        n_links = float(_sum(links, axis=None))
        self.ledger.record(bits, messages=int(n_links))
        self._links_used += n_links
        self._ema += EMA * (bits - self._ema)
        if cfg["estimation"]:
            self.est.step(t, tab.c, tab.latest)
            self._note_condition(t)
            self._errors()
        if cfg["reward"] == "position":
            reward = -self._mean_pos  # = mean over robots of the RMS position errors
        else:  # eq. (7)'s quantity: steps until each robot can compute x̂_{t|t}
            reward = -float(_sum(t - tab.c, axis=None)) / (self.n_agents * AGE_SCALE)
        reward -= cfg["lam"] * float(_sum(bits, axis=None)) / (self.n_agents * KBIT)
        # the world moves on to step t+1; every robot adds its own packet M_{t+1}^i (eq. (5))
        self.world.advance(rng)
        pk = self.world.measure(rng)
        if cfg["estimation"]:
            floor = t + 1 - cfg["max_history"]
            L_old, c_old = tab.latest.copy(), tab.c.copy()
            lagging = tab.new_step(pk.bits)
            self.est.add_packets(t + 1, pk, floor)
            if lagging.size:
                self.est.abandon(lagging, floor, L_old[lagging], c_old[lagging])
        else:
            tab.new_step(pk.bits)
        self._draw_links()
        self._account_table()
        return reward

    def _note_condition(self, t: int) -> None:
        """Track the largest κ₂ of the centralized covariance P_{t|t}: it is the inverse of the information matrix
        the column step of t inverted (eq. (2) in information form), so κ(P) = κ(Y), and ε·κ bounds the digits the
        step loses. One symmetric eigenvalue solve of one 3N × 3N matrix per step (without numpy.linalg's per-call
        checks): 1–3 % of a step at N = 5, under 0.5 % at N = 20."""
        w = _umath_linalg.eigvalsh_lo(self.est.central[t][1], signature="d->d")
        cond = w[-1] / w[0] if w[0] > EPS * w[-1] else 1.0 / EPS
        if cond > self._max_cond:
            self._max_cond = cond

    def _errors(self) -> None:
        """Every robot's RMS position and orientation errors over the team, and their means, in one compiled call
        (``env_numba.errors``; its numpy oracle is ``tests/helpers/asynccl_reference.py``)."""
        self._err_pos, self._err_ori, mean_pos, mean_ori = env_numba.errors(self.est.X, self.world.x)
        self._mean_pos = mean_pos
        self._sum_pos += mean_pos
        self._sum_ori += mean_ori
        self._n_err += 1

    def _account_table(self) -> None:
        size = self.tables.table_size()
        self._table = size
        self._sum_table += float(_sum(size, axis=None)) / self.n_agents
        self._n_table += 1
        self._max_table = max(self._max_table, float(np.maximum.reduce(size, axis=None)))

    # ------------------------------------------------------------------ views
    def _observe(self) -> np.ndarray:
        """The observation of the module's table: every column but the trace's log scale in one compiled call
        (``env_numba.observe``; its numpy oracle is ``tests/helpers/asynccl_reference.py``)."""
        tab, n = self.tables, self.n_agents
        t = tab.t
        k = OTHER_FEATURES * (n - 1)
        out = np.empty((n, k + OWN_FEATURES), dtype=np.float32)
        clock = min(t / self.cfg["max_cycles"], 1.0)
        env_numba.observe(
            out, self.adj, tab.latest, tab.known, tab.c, t, clock, self.neighbours, self._ema, AGE_SCALE, BITS_SCALE
        )
        if self.cfg["estimation"]:
            trace = env_numba.own_pose_traces(self.est.P)
            # a log scale: the trace spans 1e-6 (well localised) to 1e2 (lost); tr/(tr+1) was flat at 1e-3
            out[:, k + 2] = np.clip((np.log10(np.maximum(trace, 1e-12)) + 6.0) / 8.0, 0.0, 1.0)
        else:
            out[:, k + 2] = 0.0
        return out

    def _local_view(self) -> dict:
        tab = self.tables
        return {"links": self.adj, "complete_frontier": tab.c, "latest": tab.latest, "table_size": self._table}

    def _agent_infos(self) -> dict:
        tab = self.tables
        return {
            "delay": tab.t - tab.c,
            "rms_position": self._err_pos,
            "rms_orientation": self._err_ori,
            "bits_sent": self.ledger.step_bits,
            "table_size": self._table,
            "neighbours": self.neighbours,
        }

    def action_label(self, action) -> str:
        """The transfer mode the action indexes (argument ``modes``)."""
        return self.mode_names[int(action)]

    def decision_context(self) -> list[str]:
        """Whether a robot can reach any other in the coming exchange (a mode sends nothing without a link)."""
        return ["no robot in reach" if k == 0 else "robots in reach" for k in self.neighbours]

    def _metrics(self) -> dict[str, float]:
        tab = self.tables
        links = self._links_used
        return {
            "mean_delay": tab.mean_delay(),
            "rms_position": self._sum_pos / self._n_err if self._n_err else 0.0,
            "rms_orientation": self._sum_ori / self._n_err if self._n_err else 0.0,
            "bits_sent": float(self.ledger.total_bits.sum()),
            "bits_per_link": float(self.ledger.total_bits.sum()) / links if links else 0.0,
            "table_size": self._sum_table / self._n_table if self._n_table else 0.0,
            "max_table_size": self._max_table,
            "abandoned_steps": float(tab.abandoned),
            "log10_condition": math.log10(self._max_cond) if self.cfg["estimation"] else 0.0,
        }

    def _render(self, ax) -> None:
        x = self.world.x
        pairs = np.argwhere(np.triu(np.asarray(self.adj)))
        for i, j in pairs:
            ax.plot(x[[i, j], 0], x[[i, j], 1], color="0.8", lw=0.8, zorder=1)
        if self.step_count:  # a sender's table goes to each receiver alike: bits over a link = its share, both ways
            per = self.__dict__.get("_sent_per_link", np.zeros(self.n_agents))
            rendering.draw_link_bits(ax, x[:, :2], pairs, per[pairs[:, 0]] + per[pairs[:, 1]])
        ax.scatter(x[:, 0], x[:, 1], c="tab:blue", s=30, zorder=2, label="truth")
        if self.cfg["estimation"]:
            e = self.est.X[0].reshape(-1, 3)
            ax.scatter(e[:, 0], e[:, 1], marker="x", c="tab:red", s=25, zorder=3, label="robot_0's estimate")
        ax.set_aspect("equal")
        ax.legend(loc="upper right", fontsize=7)
        ax.set_title(f"AsyncCL  k={self.tables.t}  delay robot_0={int(self.tables.t - self.tables.c[0])}")
