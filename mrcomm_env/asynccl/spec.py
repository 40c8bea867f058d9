"""AsyncCL-v0's declarations, apart from its behaviour (``env.py``): its arguments, metrics, infos and local view,
its documented configurations and limits, and its memory model with the probes that check it. ``AsyncCLEnv``
inherits them from :class:`AsyncCLSpec`; ``mrcomm docs`` reads them from there."""

from __future__ import annotations

import os
import re

from mrcomm_env.core.base import EnvSpec
from mrcomm_env.core.config import Bool, Choice, Int, ListOf, Optional, Param, Real, Validator

ALL_MODES = ("silent", "scheme1", "scheme2_q1", "scheme2_q2", "scheme2_q4", "scheme2_q8", "scheme2_qinf")
# floors of the filter's noise model so that zero-noise configurations stay numerically sound
SIGMA_FLOOR = 1e-4
MAX_HISTORY = 100_000  # largest max_history; Scheme 2's q is bounded by it (a larger q would mean the same)
MAX_Q = MAX_HISTORY
_SCHEME2_Q = re.compile(r"scheme2_q([0-9]+)")  # ASCII digits only (str.isdigit also accepts '²', which int() rejects)
# Documented limits, measured on one core of the 24 GiB CI machine (``mrcomm_env/experiments/limits.py``,
# random actions). The delay-only bookkeeping holds (N, N) tables and the exchange touches every row on every
# link, O(p N³) per step: N = 200 runs ≈ 10 steps/s in 0.4 GB (N = 400: 0.5 steps/s, 1.5 GB). With the EKFs
# every robot holds the (3N)² covariance and whitened rows of all N(N-1) range/bearing measurements of its
# columns, O(N⁴) memory: N = 30 runs ≥ 1 step/s in 0.8 GB, N = 50 takes 3–7 s per step and 3.2 GB, N = 100
# 47 s and 10 GB. The paper's Table I needs N ≤ 100 (delay only); its estimation study uses N = 5.
MAX_ROBOTS = 200
MAX_ROBOTS_ESTIMATING = 30


class ModeName(Validator):
    """``silent``, ``scheme1``, ``scheme2_q<q>`` with an integer 1 ≤ q ≤ ``MAX_Q``, or ``scheme2_qinf``."""

    def __call__(self, name, value):
        if isinstance(value, str):
            if value in ("silent", "scheme1", "scheme2_qinf"):
                return value
            match = _SCHEME2_Q.fullmatch(value)
            if match:
                q = int(match.group(1))
                if 1 <= q <= MAX_Q:
                    return f"scheme2_q{q}"
                raise ValueError(
                    f"argument '{name}': q of {value!r} must be in [1, {MAX_Q}] or inf (no table holds "
                    f"more than max_history ≤ {MAX_Q} columns, so a larger q would mean the same)"
                )
        self._fail(name, value)

    def describe(self):
        return f"`silent`, `scheme1`, `scheme2_q<q>` (integer 1 ≤ q ≤ {MAX_Q}) or `scheme2_qinf`"


class DataDir(Validator):
    """None or a folder path (``str`` or ``os.PathLike``); whether it holds the data is checked when it is used."""

    def __call__(self, name, value):
        if value is None or isinstance(value, os.PathLike):
            return value
        if isinstance(value, str) and value.strip():
            return value
        self._fail(name, value)

    def describe(self):
        return "None or a folder path"


class AsyncCLSpec(EnvSpec):
    """The declarations of AsyncCL-v0 (module docstring): class attributes the env class inherits."""

    PARAMS = {
        "n_robots": Param(
            5,
            f"number of robots N; at most {MAX_ROBOTS_ESTIMATING} with `estimation` (every robot runs a "
            "centralized EKF of the whole team: memory grows as N⁴), at most "
            f"{MAX_ROBOTS} delay-only (Table I needs ≤ 100)",
            Int(lo=2, hi=MAX_ROBOTS, fuzz=(2, 6)),
        ),
        "link_model": Param(
            "bernoulli",
            "`bernoulli` (each pair linked with probability p per step, Table I), "
            "`disk` (within `comm_radius`) or `combined` (both)",
            Choice(("bernoulli", "disk", "combined")),
        ),
        "link_probability": Param(0.5, "p: probability of a link per pair and step", Real(0.0, 1.0, fuzz=(0.0, 1.0))),
        "comm_radius": Param(
            3.0, "r: communication radius (m) of the disk model", Real(0.0, lo_open=True, fuzz=(0.5, 6.0))
        ),
        "sensing_radius": Param(
            10.0,
            "d_max: sensing radius (m) for range and bearing",
            Real(0.0, lo_open=True, allow_inf=True, fuzz=(0.5, 10.0)),
        ),
        "packet_loss": Param(
            0.0, "probability that a directed delivery is lost", Real(0.0, 1.0, hi_open=True, fuzz=(0.0, 0.5))
        ),
        "bit_budget": Param(
            None,
            "per-link bit budget per step; the payload is truncated oldest data first",
            Optional(Real(0.0, fuzz=(50.0, 5000.0))),
        ),
        "modes": Param(ALL_MODES, "the transfer modes an action indexes", ListOf(ModeName())),
        "lam": Param(
            0.05,
            "λ: reward cost of one kbit sent per robot and step (at most 1e6, so that λ times the "
            "bits of any step stays a finite reward)",
            Real(0.0, 1e6, fuzz=(0.0, 1.0)),
        ),
        "reward": Param(
            "delay",
            "what the reward charges besides bits: `delay` (the team's mean t − c_i in units "
            "of 10 steps, eq. (7)'s quantity) or `position` (the causal estimates' mean RMS position "
            "error, m; needs `estimation`)",
            Choice(("delay", "position")),
        ),
        "estimation": Param(True, "run the EKFs (false: delay-only bookkeeping, as for Table I)", Bool()),
        "max_cycles": Param(500, "episode length in time steps", Int(lo=1, fuzz=(1, 60))),
        "max_history": Param(
            500,
            "time steps of packets kept in memory; a robot still missing a column that leaves memory abandons it",
            Int(lo=2, hi=MAX_HISTORY, fuzz=(2, 50)),
        ),
        "trajectory": Param(
            "sinusoid",
            "`sinusoid` (phase-shifted figure-eights, §IV), `waypoint`, or `mrclam`: a window of the UTIAS MRCLAM "
            "Dataset 6 recording (5 real robots; see `data_dir`)",
            Choice(("sinusoid", "waypoint", "mrclam")),
        ),
        "data_dir": Param(
            None,
            "folder of MRCLAM Dataset 6 for `trajectory='mrclam'` (None: `$MRCLAM_DIR`, else "
            "`shared/data/MRCLAM_Dataset6` beside the checkout); ignored by the synthetic trajectories",
            DataDir(),
        ),
        "dt": Param(0.05, "time step (s); at least 0.01 on `mrclam`", Real(0.0, 1.0, lo_open=True, fuzz=(0.01, 0.2))),
        "sigma_v": Param(
            None,
            "σ_v as a fraction of v (None: §IV's 0.02, or the value measured from the data on `mrclam`)",
            Optional(Real(0.0, 1.0, fuzz=(0.0, 0.1))),
        ),
        "sigma_omega_deg": Param(
            None, "σ_ω (deg/s) (None: §IV's 1, or measured on `mrclam`)", Optional(Real(0.0, 90.0, fuzz=(0.0, 5.0)))
        ),
        "sigma_d": Param(
            None,
            "σ_d as a fraction of d (None: §IV's 0.02, or measured on `mrclam`)",
            Optional(Real(0.0, 1.0, fuzz=(0.0, 0.1))),
        ),
        "sigma_theta_deg": Param(
            None, "σ_θ (deg) (None: §IV's 1, or measured on `mrclam`)", Optional(Real(0.0, 90.0, fuzz=(0.0, 5.0)))
        ),
        "q_rule": Param(
            "paper",
            "reading of Scheme 2's q oldest time steps: `paper` (the sender's q oldest "
            "non-discarded columns, discard by the rules of §III-B.3), `oracle` (a column is discarded "
            "as soon as every robot has it) or `receiver` (the q oldest columns in which the receiver "
            "lacks something)",
            Choice(("paper", "oracle", "receiver")),
        ),
        "initial_sigma": Param(
            0.05,
            "std of the initial pose prior (m and rad); at least the filter's noise floor "
            f"{SIGMA_FLOOR:g} (a prior far tighter than every noise makes the information matrix "
            "singular: 1e-8 still ran, 1e-12 did not)",
            Real(SIGMA_FLOOR, 10.0, fuzz=(0.01, 0.5)),
        ),
    }

    #: a team that completes no step (a silent one) has no delay to average: evaluations count its episode at its
    #: length, not as a missing value that an average would skip
    UNREACHED_TIMES = ("mean_delay",)

    METRICS = {
        "mean_delay": "eq. (7): mean steps from k until a robot can compute x̂_{k|k} (complete steps only; nan while no "
        "robot has completed a step, e.g. a silent team: evaluations then count the episode's length)",
        "rms_position": "RMS position error (m) of the robots' causal team estimates, mean over steps and robots",
        "rms_orientation": "RMS orientation error (rad) of the causal team estimates, mean over steps and robots",
        "bits_sent": "bits sent by the team over the episode",
        "bits_per_link": "bits per used directed link per step",
        "table_size": "packets held per robot, mean over steps and robots",
        "max_table_size": "largest table (packets) any robot held",
        "abandoned_steps": "robot-steps dropped because they left memory before being complete",
        "log10_condition": "log10 of the largest condition number κ of the centralized covariance P_k|k over the "
        "episode (≤ log10(1/ε) ≈ 15.7); above ~12 the estimates depend on rounding, not only on the data",
    }

    INFO_KEYS = {
        "delay": "t − c: steps since the newest delayed centralized estimate of this robot",
        "rms_position": "RMS position error (m) of this robot's causal team estimate",
        "rms_orientation": "RMS orientation error (rad) of this robot's causal team estimate",
        "bits_sent": "bits this robot sent this step",
        "table_size": "packets this robot holds",
        "neighbours": "robots it can reach in the coming exchange",
    }

    LOCAL_VIEW = {
        "links": "(N,) bool: the robots this robot can reach in the coming exchange",
        "complete_frontier": "c_i: newest step up to which this robot's table is complete (its delayed estimate)",
        "latest": "(N,) newest step of each robot's row that this robot holds",
        "table_size": "packets this robot holds",
    }

    DOCUMENTED_CONFIGS = {
        "default": {},
        "delay_only_n20": {"n_robots": 20, "estimation": False, "max_cycles": 200},
        "disk_budget": {
            "n_robots": 4,
            "link_model": "combined",
            "comm_radius": 3.0,
            "bit_budget": 3000.0,
            "packet_loss": 0.1,
            "trajectory": "waypoint",
            "max_cycles": 100,
        },
    }

    #: configurations at the documented maxima (``tests/core/test_limits.py``, ``experiments/limits.py``)
    MEMORY_FORMULA = (
        "2 MiB + 4,100·N² (the (N, N) information tables and links) + 16·N·`max_history` (each robot's packet "
        "history) + with `estimation` 1,400·N⁴ (N = `n_robots`): every robot's EKF of the whole team, with the "
        "whitened measurement rows of the columns it still waits for. The N⁴ coefficient is the envelope of "
        "200-step episodes measured at link probabilities 0 to 0.5 (fewer links keep more columns waiting)"
    )

    MEMORY_SHARED = 2.0 * 2**20  # the formula's constant term: working memory the copies of a batch share

    MEMORY_ARGS = ("n_robots", "max_history", "estimation")

    MEMORY_PROBES = {
        "delay_only_100": {"n_robots": 100, "estimation": False, "max_cycles": 3},
        "delay_only_200": {"n_robots": 200, "estimation": False, "max_cycles": 3},
        "delay_only_200_long_history": {
            "n_robots": 200,
            "estimation": False,
            "max_history": 100_000,
            "max_cycles": 3,
        },
    }

    @classmethod
    def memory_estimate(cls, cfg) -> float:
        n = float(cfg.n_robots)
        tables = cls.MEMORY_SHARED + 4100.0 * n * n + 16.0 * n * cfg.max_history
        return tables + (1400.0 * n**4 if cfg.estimation else 0.0)

    LIMIT_CONFIGS = {
        "max_robots_delay_only": {"n_robots": MAX_ROBOTS, "estimation": False},
        "max_robots_delay_only_max_history": {
            "n_robots": MAX_ROBOTS,
            "estimation": False,
            "max_history": MAX_HISTORY,
            "modes": ["scheme2_qinf", f"scheme2_q{MAX_Q}"],
            "lam": 1e6,
        },
        "max_robots_delay_only_budget": {
            "n_robots": MAX_ROBOTS,
            "estimation": False,
            "bit_budget": 5000.0,
            "link_model": "combined",
            "q_rule": "receiver",
        },
        "max_robots_estimating": {"n_robots": MAX_ROBOTS_ESTIMATING, "initial_sigma": 10.0},
        "max_history_estimating": {
            "max_history": MAX_HISTORY,
            "initial_sigma": SIGMA_FLOOR,
            "sigma_v": 0.0,
            "sigma_omega_deg": 0.0,
            "sigma_d": 0.0,
            "sigma_theta_deg": 0.0,
        },
    }

    VERSION_HISTORY = [
        ("v0", "first version: Scheme 1, Scheme 2 (q ≥ 1 and ∞) and silence as per-step actions"),
        (
            "v0 rev 2",
            "learnable: the reward charges the mean delay (`reward=delay`, default; the v0 position error "
            "is `reward=position`) and `lam` prices kbit per robot (was per team bit at 1e-6: 0.002 per step, "
            "noise); the observation is agent-relative per other robot (linked now, how far behind my copy of its "
            "row is, what it lacks as far as I know), with the clock and a log-scale covariance trace",
        ),
        (
            "v0 rev 3",
            "`trajectory=mrclam` replays UTIAS MRCLAM Dataset 6 (5 real robots, `data_dir`) with the noise measured "
            "from it; the `sigma_*` arguments default to None, meaning §IV's values on the synthetic trajectories "
            "(as before) and the measured ones on `mrclam`",
        ),
    ]
