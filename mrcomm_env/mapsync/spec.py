"""MapSync-v0's declarations, apart from its behaviour (``env.py``): its arguments, metrics, infos and local view,
its documented configurations and limits, and its memory model with the probes that check it. ``MapSyncEnv``
inherits them from :class:`MapSyncSpec`; ``mrcomm docs`` reads them from there."""

from __future__ import annotations

from mrcomm_env.core.base import EnvSpec
from mrcomm_env.core.config import Bool, Choice, Int, Optional, Param, Real
from mrcomm_env.mapsync import world


class MapSyncSpec(EnvSpec):
    """The declarations of MapSync-v0 (module docstring): class attributes the env class inherits."""

    PARAMS = {
        "preset": Param(
            "random",
            "`random`: obstacles and starts drawn per episode; `paper`: Fig. 7's layout "
            "(needs grid_size 16, n_robots 2, n_obstacles 10)",
            Choice(("random", "paper")),
        ),
        "grid_size": Param(
            world.PAPER_GRID,
            "side of the square 4-connected grid; n = grid_size² map bits",
            Int(lo=2, hi=256, fuzz=(2, 12)),
        ),
        "n_obstacles": Param(10, "obstacles at the start (at most grid_size² − 1)", Int(lo=0, fuzz=(0, 12))),
        "n_robots": Param(2, "number of robots", Int(lo=2, hi=64, fuzz=(2, 5))),
        "k": Param(
            world.PAPER_K,
            "Protocol 1 rounds (one-sided error ≤ 2^−k, Prop. 2); the case study's k = 10",
            Int(lo=1, hi=64, fuzz=(1, 12)),
        ),
        "res": Param(
            1,
            "Algorithm 1's resolution: segments of at most res cells are compared bit by bit (at most 65,536, "
            "the cells of the largest map: a larger res means the same, and the compiled kernel takes 64-bit "
            "integers)",
            Int(lo=1, hi=256 * 256, fuzz=(1, 16)),
        ),
        "bits_per_step": Param(
            None,
            "bits a link carries per step, both directions together (null: no limit, "
            "every sync completes in the step it starts)",
            Optional(Int(lo=1, fuzz=(8, 600))),
        ),
        "appear_rate": Param(
            0.0,
            "probability per free unoccupied cell and step that an obstacle appears",
            Real(lo=0.0, hi=1.0, fuzz=(0.0, 0.01)),
        ),
        "vanish_rate": Param(
            0.0,
            "probability per obstacle and step that it disappears (> 0 switches the merge "
            "from OR to last-writer-wins with stamps sent)",
            Real(lo=0.0, hi=1.0, fuzz=(0.0, 0.05)),
        ),
        "lam": Param(
            0.1,
            "price of n bits per robot in reward units (see Reward scale); at most 1e6, so that λ times the bits "
            "of any step stays a finite reward",
            Real(lo=0.0, hi=1e6, fuzz=(0.0, 2.0)),
        ),
        "max_cycles": Param(
            world.PAPER_STEPS,
            "episode length in steps (the case study runs 200); at most 2⁵³, where step counts stay exact in the "
            "float64 clock t / max_cycles; memory does not grow with it",
            Int(lo=1, hi=2**53, fuzz=(1, 40)),
        ),
        "comm_range": Param(
            None,
            "disk link radius in cells (null: always in range)",
            Optional(Real(lo=0.0, lo_open=True, fuzz=(1.0, 20.0))),
        ),
        "link_prob": Param(
            1.0,
            "probability a link in range is up this step (core.bernoulli_links)",
            Real(lo=0.0, hi=1.0, fuzz=(0.3, 1.0)),
        ),
        "database_seed": Param(
            0,
            "seed of Protocol 1's shared database R, given to the robots before deployment "
            "(the same in every episode; Alice's picks of i are random per episode)",
            Int(lo=0, hi=2**63 - 1, fuzz=(0, 1000)),
        ),
        "explicit_database": Param(
            False,
            "keep Protocol 1's database of 100n strings in memory (n ≤ 1024) instead "
            "of generating r_i on demand from the shared seed (same strings)",
            Bool(),
        ),
    }

    METRICS = {
        "disagreement": "time-average over steps of the mean normalised Hamming distance between two robots' maps",
        "error_vs_truth": "time-average over steps and robots of the fraction of cells where a map differs from "
        "the world (unknown cells read as free)",
        "bits_sent": "bits sent in the episode, all robots and protocols",
        "syncs": "syncs completed (any protocol, equality tests included)",
        "false_equal": "equality tests (Protocol 1 as `equality`, or Algorithm 1's first test) that said "
        '"same" while the maps differed',
        "corrected_fraction": "over completed bisection/full/sketch syncs: cells reconciled / cells that differed "
        "when the sync started (nan if none differed)",
        "sync_latency_steps": "mean steps from a sync's start to its last bit (1 = within the step; nan if none)",
        "equality_tests": "equality tests run (both kinds above)",
        "detections": "equality tests that found a difference",
        "aborted_syncs": "syncs aborted because their link broke",
        "coverage": "mean fraction of cells a robot has observed or learned, at the end",
    }

    INFO_KEYS = {
        "bits_sent": "bits this robot sent this step",
        "disagreement": "mean normalised Hamming distance between this robot's map and each other robot's",
        "error_vs_truth": "fraction of cells where this robot's map differs from the world",
        "coverage": "fraction of cells this robot has observed or learned",
        "busy": "1 while this robot is in a sync",
        "syncs": "syncs this robot completed so far",
    }

    LOCAL_VIEW = {
        "map": "(n,) this robot's occupancy bits (1 = obstacle)",
        "stamps": "(n,) step at which this robot last observed each cell, or received it in a merge (−1: never)",
        "position": "(2,) this robot's cell (x, y)",
        "steps_since_sync": "(N,) steps since this robot's maps were last made equal to each robot's (own: 0)",
        "new_cells": "(N,) cells this robot's own sensing changed since then",
        "last_test": "(N,) last equality verdict with each robot: 1 same, 0 different, −1 none (both ends learn it)",
        "linked": "(N,) link to each robot this step",
        "busy": "1 while this robot is in a sync",
    }

    #: configurations at the documented maxima (``tests/core/test_limits.py``, ``mrcomm bench --limits``)
    MEMORY_FORMULA = (
        "2 MiB + 450·n + 16·N·n for n = `grid_size`² cells and N = `n_robots` (the world and Protocol 1's per-cell "
        "work, every robot's map and stamps), + 90·n² with `explicit_database` (Protocol 1's 100n strings of n "
        "bits). Nothing grows with `max_cycles`"
    )

    MEMORY_SHARED = 2.0 * 2**20  # the formula's constant term: working memory the copies of a batch share

    MEMORY_ARGS = ("grid_size", "n_robots", "explicit_database")

    MEMORY_PROBES = {
        "map_181x181": {"grid_size": 181, "max_cycles": 3},
        "explicit_database_32x32": {"grid_size": 32, "explicit_database": True, "max_cycles": 3},
        "map_256x256_64_robots": {"grid_size": 256, "n_robots": 64, "max_cycles": 3},
    }

    @classmethod
    def memory_estimate(cls, cfg) -> float:
        cells = float(cfg.grid_size) ** 2
        database = 90.0 * cells * cells if cfg.explicit_database else 0.0
        return cls.MEMORY_SHARED + 450.0 * cells + 16.0 * cfg.n_robots * cells + database

    LIMIT_CONFIGS = {
        "largest_team_and_map": {
            "grid_size": 256,
            "n_robots": 64,
            "k": 64,
            "n_obstacles": 1000,
            "database_seed": 2**63 - 1,
            "res": 256 * 256,
        },
        # the longest horizon: nothing is sized by it (the observation's clock and ages are computed per step)
        "longest_horizon": {"max_cycles": 2**53, "lam": 1e6},
    }

    DOCUMENTED_CONFIGS = {
        "default": {},
        "paper": {"preset": "paper"},
        "changing": {"appear_rate": 0.002, "vanish_rate": 0.02, "max_cycles": 100},
        "narrow_team": {"n_robots": 4, "bits_per_step": 64, "comm_range": 8.0, "link_prob": 0.8, "max_cycles": 80},
        "explicit_database": {"grid_size": 8, "explicit_database": True, "max_cycles": 60},
    }

    VERSION_HISTORY = [
        (
            "v0",
            "first version: Protocol 1, Algorithm 1, full and streaming PinSketch syncs; "
            "last-writer-wins merge; per-link bit budget with latency",
        )
    ]
