"""MultiHop-v0's declarations, apart from its behaviour (``env.py``): its arguments, metrics, infos and local view,
its documented configurations and limits, and its memory model with the probes that check it. ``MultiHopEnv``
inherits them from :class:`MultiHopSpec`; ``mrcomm docs`` reads them from there."""

from __future__ import annotations

from mrcomm_env.core.base import COPY_OVERHEAD_BYTES, EnvSpec
from mrcomm_env.core.config import Bool, Choice, Int, Optional, Param, Real
from mrcomm_env.multihop import protocol as proto

SUBGRAPHS = (2, 4, 6, 8)
# Documented limits, measured on one core (``mrcomm_env/experiments/limits.py``, random actions): n = 1024
# runs a flooding grid frame (1024 slots, `max_grid_flooding`) in 0.05–0.07 s and a moving field frame in about 1 s,
# in 0.4–0.5 GB (`mrcomm bench MultiHop-v0 --limits`, 2026-12-07);
# the coverage controller re-partitions the square for every robot at every slot, O(n³ · points) per frame:
# n = 25 takes 0.3 s per frame (`max_coverage`; 0.8 s when the cap was set), n = 50 took 2.5–5.5 s and n = 100 over
# a minute.
MAX_COVERAGE_ROBOTS = 25
MAX_ALPHA = 1000.0
MAX_SPEED = 1000.0  # m/s: faster than any robot; keeps speed × slot time finite for the slowest channel
HOP_BUCKETS = proto.HOP_BUCKETS


class MultiHopSpec(EnvSpec):
    """The declarations of MultiHop-v0 (module docstring): class attributes the env class inherits."""

    PARAMS = {
        "scene": Param(
            "grid",
            "`grid` (stationary 4-neighbour grid, Fig. 2), `field` (disk links, optional motion) "
            "or `coverage` (Voronoi coverage by flying robots, Fig. 3)",
            Choice(("grid", "field", "coverage")),
        ),
        "n_robots": Param(
            None,
            "number of robots n; default grid_side² (grid), 20 (field), 9 (coverage); "
            "in the grid scene robots fill rows of grid_side columns (a partial last row is allowed); at most "
            f"{MAX_COVERAGE_ROBOTS} in the coverage scene (the paper flies 9)",
            Optional(Int(lo=2, hi=1024, fuzz=(4, 12))),
        ),
        "grid_side": Param(
            10,
            "columns of the grid scene (robots at unit spacing; a square grid by default)",
            Int(lo=2, hi=32, fuzz=(2, 5)),
        ),
        "slot_size": Param(
            None,
            "m: estimates per TDMA slot, 1 <= m <= n (m = n is flooding, m = 1 no hop); "
            "default min(7, n), 7 being the paper's choice for the 10×10 grid",
            Optional(Int(lo=1, hi=1024, fuzz=(1, 4))),
        ),
        "alpha": Param(
            1.0,
            "α of the importance d^-α, eq. (1) (at most 1000: d^-α is evaluated in log form, and beyond "
            "that only the nearest robot counts at any distance ratio above 1.0007)",
            Real(lo=0.0, hi=MAX_ALPHA, lo_open=True, fuzz=(0.25, 3.0)),
        ),
        "bits_per_estimate": Param(
            192,
            "b: bits per estimate incl. time stamp (six 32-bit integers, §4)",
            Int(lo=1, hi=1_000_000, fuzz=(8, 256)),
        ),
        "baud": Param(
            3000.0,
            "r_b: channel bit rate (bits/s, §4); 1 bit/s to 1 Tbit/s keeps slot times and ages "
            "finite and well above round-off",
            Real(lo=1.0, hi=1e12, fuzz=(300.0, 1e5)),
        ),
        "max_cycles": Param(
            400, "episode length in TDMA frames (400 lets the 8×8 cold start finish at m = 7)", Int(lo=1, fuzz=(1, 30))
        ),
        "arena_size": Param(
            100.0,
            "side of the square (m), field and coverage scenes (1 m to 1000 km: squared distances stay finite)",
            Real(lo=1.0, hi=1e6, fuzz=(10.0, 200.0)),
        ),
        "comm_range": Param(
            40.0,
            "disk link radius (m), field and coverage scenes (above 1e7 m every robot of the "
            "largest arena is linked anyway)",
            Real(lo=0.0, hi=1e7, lo_open=True, fuzz=(5.0, 200.0)),
        ),
        "speed": Param(
            0.0, "field scene: random-waypoint speed (m/s), 0 = stationary", Real(lo=0.0, hi=MAX_SPEED, fuzz=(0.0, 5.0))
        ),
        "max_speed": Param(
            5.0,
            "coverage scene: speed limit of the flying robots (m/s)",
            Real(lo=0.0, hi=MAX_SPEED, lo_open=True, fuzz=(0.5, 5.0)),
        ),
        "control_gain": Param(
            1.0, "coverage scene: k of ṗ = k (C_i − p_i) (1/s)", Real(lo=0.0, hi=1000.0, lo_open=True, fuzz=(0.1, 2.0))
        ),
        "layout": Param(
            "relative",
            "`relative`: agent-relative candidates ranked by estimated distance, one "
            "select bit each (MultiBinary); `absolute`: v0's priority per robot index (Box)",
            Choice(("relative", "absolute")),
        ),
        "lam": Param(
            0.0,
            "λ: reward cost of the share of slot capacity used (bits / (N m b) per frame)",
            Real(lo=0.0, hi=100.0, fuzz=(0.0, 2.0)),
        ),
        "observe_heard": Param(
            False,
            "`relative` layout on static links (the grid, or a field with `speed` 0) only: add to each candidate "
            "what the robot heard, the freshness its neighbours lack of that estimate as far as the broadcasts it "
            "heard and sent tell (a sixth feature per candidate; the robot keeps an n × n table per robot, so the "
            "memory grows as n³)",
            Bool(),
        ),
        "mask_unheld": Param(
            False,
            "`relative` layout only: mask the select bit of every candidate the robot holds no estimate of at the "
            "frame's start (`env.action_masks()`, the infos `action_mask_<k>` and the local view's `action_mask`), "
            "so a masked policy (MaskablePPO, the batched trainer) spends its m − 1 picks on estimates it can send. "
            "The env itself still takes any select bits: one set on an estimate that arrives before the robot's "
            "slot is sent, as without the mask",
            Bool(),
        ),
        "reward_mode": Param(
            "team",
            "`team`: one team reward; `neighbourhood`: each robot gets the weighted age "
            "its neighbours hold and its own bit cost",
            Choice(("team", "neighbourhood")),
        ),
    }

    METRICS = {
        **{
            f"propagation_time_{k}x{k}": f"cold start: seconds until every member of the centred {k}×{k} subgraph "
            "holds an estimate of every other member (square grid scene; nan if it does not fit or is not complete)"
            for k in SUBGRAPHS
        },
        "mean_age": "time-average over frame ends of the mean age (s) of the estimates of all pairs i≠j "
        "(unknown = age since the start)",
        "weighted_mean_age": "time-average over frame ends of the d^-α-weighted mean age (s) of eq. (1)",
        **{
            f"mean_age_hop{h}": f"time-average over frame ends of the mean age (s) of estimates of robots at hop "
            f"distance {h.replace('plus', ' or more')}"
            for h in HOP_BUCKETS
        },
        **{
            f"max_age_hop{h}": f"largest age (s) of an estimate of a robot at hop distance "
            f"{h.replace('plus', ' or more')} seen at any frame end"
            for h in HOP_BUCKETS
        },
        "frame_rate": "r_f = r_b / (m n b) (Hz)",
        "coverage_cost": "mean squared distance (m²) from the square to the nearest robot, H/area "
        "(true positions; coverage and field scenes, nan on the grid)",
        "known_fraction": "fraction of pairs i≠j holding an estimate",
        "bits_sent": "bits broadcast in the episode (all robots)",
    }

    INFO_KEYS = {
        "bits_sent": "bits this robot broadcast this frame",
        "mean_age": "mean age (s) of this robot's estimates of the others (unknown = age since the start)",
        "known_fraction": "fraction of the others this robot holds an estimate of",
        "slot": "this robot's slot index within the frame",
        "action_mask_<k>": "with `mask_unheld`, k = 0 … N − 2: 1 when the robot holds the candidate at rank k (its "
        "select bit may be set; the same as `env.action_masks()`)",
    }

    LOCAL_VIEW = {
        "stamps": "(N,) time stamp (s) of this robot's estimate of each robot (−inf: none yet; own entry = now)",
        "estimated_distances": "(N,) distance from this robot's own position to its estimate of each robot",
        "sent_stamp": "(N,) the stamp of each estimate this robot last broadcast (one frame before start: never)",
        "slot": "this robot's slot index within the frame",
        "slot_size": "m: estimates per slot (the same for every robot)",
        "candidates": "(N − 1,) robot index at each candidate rank of the `relative` layout (this frame)",
        "heard": "(N, N) with `observe_heard`: row k, the freshest stamp of each estimate this robot heard "
        "neighbour k broadcast or broadcast to k itself (a lower bound on k's table; −inf: none); (0, N) without it",
        "action_mask": "(N − 1,) bool in the `relative` layout: the select bits this robot may set (with "
        "`mask_unheld`, the candidates it holds; without it, all); (0,) in the `absolute` layout",
    }

    DOCUMENTED_CONFIGS = {
        "default": {},
        "small_grid": {"grid_side": 4, "slot_size": 3, "max_cycles": 40},
        "flooding_grid": {"grid_side": 4, "slot_size": 16, "max_cycles": 40},
        "field_moving": {"scene": "field", "n_robots": 12, "speed": 2.0, "comm_range": 35.0, "max_cycles": 40},
        "coverage": {"scene": "coverage", "slot_size": 3, "max_cycles": 40},
        "absolute_layout": {"grid_side": 4, "slot_size": 3, "max_cycles": 30, "layout": "absolute"},
        "neighbourhood_reward": {
            "grid_side": 5,
            "slot_size": 4,
            "max_cycles": 30,
            "lam": 0.5,
            "reward_mode": "neighbourhood",
        },
        "heard": {"grid_side": 6, "slot_size": 4, "max_cycles": 60, "observe_heard": True},
        "heard_masked": {
            "grid_side": 6,
            "slot_size": 4,
            "max_cycles": 30,
            "observe_heard": True,
            "mask_unheld": True,
            "reward_mode": "neighbourhood",
        },
    }

    MEMORY_FORMULA = (
        "8 MiB + 180·n² for n robots (`n_robots`, or `grid_side`² in the grid scene): every robot's estimate "
        "table, its candidate observation and the pairwise distances and links are n × n; every scene adds 24 MiB + 48·n² (it steps as the "
        "copy-axis world of one copy: numba's kernels, and the world's rows beside the env's arrays); "
        "`observe_heard` adds 28·n³ (each robot's n × n table of what it heard and the frame's two n³ temporaries); "
        "`mask_unheld` adds 72·n² (every robot's n − 1 mask columns in the infos, as arrays and as its info dict)"
    )

    MEMORY_SHARED = 8.0 * 2**20  # the formula's constant term: working memory the copies of a batch share

    MEMORY_ARGS = ("n_robots", "grid_side", "observe_heard", "mask_unheld")

    MEMORY_PROBES = {
        "field_384": {"scene": "field", "n_robots": 384, "max_cycles": 3},
        "field_768": {"scene": "field", "n_robots": 768, "max_cycles": 3},
        "moving_768": {"scene": "field", "n_robots": 768, "speed": 2.0, "max_cycles": 3},
        "grid_32x32": {"grid_side": 32, "max_cycles": 3},
        "masked_32x32": {"grid_side": 32, "mask_unheld": True, "max_cycles": 3},
        "heard_16x16": {"grid_side": 16, "observe_heard": True, "max_cycles": 3},
    }

    @classmethod
    def memory_estimate(cls, cfg) -> float:
        # measured (tests/core/test_memory.py): about 180 bytes per robot pair, whatever the scene and slot size
        n = cls._robot_count(cfg)
        one = cls.MEMORY_SHARED + 180.0 * n * n
        if cls.copy_axis_world(cfg) is not None:  # the single env steps as the world of its one copy
            one += cls.WORLD_SHARED + cls.WORLD_ONE_COPY_PER_PAIR * n * n
        if cfg.observe_heard:
            one += 28.0 * n**3
        if cfg.mask_unheld:  # measured at n = 1,024: 67 MB more on numpy, 83 MB as the world of one copy
            one += 72.0 * n * n
        return one

    #: bytes per robot pair of each further copy in a copy-axis world (:mod:`.copy_axis`): its (n, n) arrays of the
    #: frame, the ranking and the observation, beside its env object's (measured: ``tests/core/test_batched.py``)
    WORLD_BYTES_PER_PAIR = 160.0

    #: what stepping as the world of one copy adds to a single env: numba's kernels (once per process) and the
    #: world's rows that are not views of the env's arrays; tracemalloc measured 32, 40 and 51 MB more than the
    #: numpy reference at n = 384, 768 and 1,024 (``tests/core/test_memory.py``)
    WORLD_SHARED = 24.0 * 2**20

    WORLD_ONE_COPY_PER_PAIR = 48.0

    @classmethod
    def batch_memory_estimate(cls, cfg, n_copies: int) -> float:
        """The copies' env objects (:meth:`MrcommParallelEnv.batch_memory_estimate`), plus, when two or more copies
        step as a copy-axis world, each copy's rows of the world."""
        if n_copies < 2 or cls.copy_axis_world(cfg) is None:
            return super().batch_memory_estimate(cfg, n_copies)
        # the env objects of a batch never step, so none builds a world of its own: each is the reference's state
        n = cls._robot_count(cfg)
        objects = cls.MEMORY_SHARED + n_copies * (180.0 * n * n + COPY_OVERHEAD_BYTES)
        world = cls.WORLD_SHARED + n_copies * cls.WORLD_BYTES_PER_PAIR * n * n
        if cfg.observe_heard:
            # per copy, what it heard (float64 n³) in its env object and again in the world's rows; once, the two n³
            # temporaries of a copy's feature
            objects += n_copies * 8.0 * n**3
            world += n_copies * 8.0 * n**3 + 16.0 * n**3
        return objects + world

    @staticmethod
    def _robot_count(cfg) -> float:
        if cfg.n_robots is not None:
            return float(cfg.n_robots)
        return float(cfg.grid_side**2) if cfg.scene == "grid" else (9.0 if cfg.scene == "coverage" else 20.0)

    #: configurations at the documented maxima (``tests/core/test_limits.py``, ``experiments/limits.py``)
    LIMIT_CONFIGS = {
        "max_grid_flooding": {"grid_side": 32, "slot_size": 1024},
        "max_field_moving": {
            "scene": "field",
            "n_robots": 1024,
            "speed": MAX_SPEED,
            "arena_size": 1e6,
            "comm_range": 1e7,
            "alpha": MAX_ALPHA,
            "baud": 1e12,
        },
        "max_coverage": {
            "scene": "coverage",
            "n_robots": MAX_COVERAGE_ROBOTS,
            "alpha": MAX_ALPHA,
            "max_speed": MAX_SPEED,
            "control_gain": 1000.0,
        },
        "slowest_channel_coverage": {
            "scene": "coverage",
            "baud": 1.0,
            "bits_per_estimate": 1_000_000,
            "slot_size": 9,
            "arena_size": 1.0,
        },
    }

    VERSION_HISTORY = [
        ("v0", "first version: grid, field and coverage scenes; one step = one TDMA frame"),
        (
            "v0 rev 2",
            "learnable by a shared policy: default `layout=relative` (MultiBinary select bits over "
            "candidates ranked by estimated distance, agent-relative observation with the freshness gained since "
            "the last broadcast, so sending fewer estimates saves bits); reward in units of ten frames plus "
            "`lam` × share of slot capacity used (was seconds, −40 to −1470 per step); `reward_mode` "
            "`neighbourhood`; v0's layout stays as `layout=absolute`",
        ),
    ]
