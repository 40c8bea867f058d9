"""RendezvousMapping-v0's declarations, apart from its behaviour (``env.py``): its arguments, metrics, infos and local view,
its documented configurations and limits, and its memory model with the probes that check it. ``RendezvousMappingEnv``
inherits them from :class:`RendezvousMappingSpec`; ``mrcomm docs`` reads them from there."""

from __future__ import annotations

import math

from mrcomm_env.core.base import EnvSpec
from mrcomm_env.core.config import Int, Param, Real
from mrcomm_env.rendezvous import filters


class RendezvousMappingSpec(EnvSpec):
    """The declarations of RendezvousMapping-v0 (module docstring): class attributes the env class inherits."""

    PARAMS = {
        "n_vehicles": Param(10, "N_v: number of vehicles (§VI-A)", Int(lo=1, hi=64, fuzz=(1, 6))),
        "n_landmarks": Param(
            200, "N_l: number of landmarks, at least n_vehicles (§VI-A)", Int(lo=1, hi=5000, fuzz=(6, 60))
        ),
        "area": Param(
            10_000.0,
            "mapping area (m²) of the square map, side √area (§VI-A); 1 m² to 100 km²",
            Real(lo=1.0, hi=1e8, fuzz=(400.0, 20_000.0)),
        ),
        "speed": Param(
            1.0, "u: vehicle speed (m/s), 1 mm/s to 1 km/s; d_max = u·t_window", Real(lo=1e-3, hi=1e3, fuzz=(0.2, 3.0))
        ),
        "t_window": Param(
            15.0,
            "t_window: time between decision phases (s), 10 ms to a day; d_max = 15 m by default (§VI-B)",
            Real(lo=1e-2, hi=86_400.0, fuzz=(1.0, 40.0)),
        ),
        "d_comms": Param(
            10.0,
            "maximum communication distance (m): `inf` (§VI-B.2), 0 = co-located only (§VI-B.3) or finite (§VI-B.4)",
            Real(lo=0.0, hi=1e6, allow_inf=True, fuzz=(0.0, 40.0)),
        ),
        "sigma": Param(
            3.0,
            "σ (m) of the N(0, σ²) shift of the landmark grid (§VI-B.1), at most 10 km; sets the clustering C",
            Real(lo=0.0, hi=1e4, fuzz=(0.0, 30.0)),
        ),
        "clumping": Param(
            0.0,
            "after the σ shift, each landmark moves this fraction of the way to the nearest of ⌈N_l/8⌉ centres "
            "drawn in the area (our extension of §VI-B.1: 0 is the paper's layout; it raises C past a random "
            "layout's, about 0.55 in sparse graphs, towards 1)",
            Real(lo=0.0, hi=0.95, fuzz=(0.0, 0.9)),
        ),
        "k_candidates": Param(5, "K: candidate landmarks listed per vehicle", Int(lo=1, hi=64, fuzz=(1, 8))),
        "prior_sigma": Param(
            5.0,
            "σ₀ (m): std of every landmark's common prior estimate, per axis (1 mm to 10 km: the information "
            "1/σ₀² and its log det stay finite and well above round-off)",
            Real(lo=1e-3, hi=1e4, fuzz=(0.5, 20.0)),
        ),
        "obs_sigma": Param(
            3.0,
            "σ_obs (m): std of one position observation, per axis (1 mm to 10 km, as σ₀)",
            Real(lo=1e-3, hi=1e4, fuzz=(0.2, 10.0)),
        ),
        "obs_rate": Param(
            1.0,
            "observations per second while at a landmark (I_obs = rate·R⁻¹, eq. 3), 0.001 to 1000",
            Real(lo=1e-3, hi=1e3, fuzz=(0.2, 4.0)),
        ),
        "obs_per_landmark": Param(
            5,
            "sensor floor: independent observations a landmark yields in total, by any "
            "vehicle (makes the available information finite)",
            Int(lo=1, hi=10_000, fuzz=(1, 20)),
        ),
        "start_spread": Param(
            0.0,
            "σ_start (m): std per axis of each vehicle's start around the launch point, kept within the area "
            "(0: all start at the launch point; the paper's Fig. 4 shows them spread), at most 10 km",
            Real(lo=0.0, hi=1e4, fuzz=(0.0, 30.0)),
        ),
        "max_cycles": Param(
            100, "episode length in decision phases (`max_phases` is accepted as an alias)", Int(lo=1, fuzz=(1, 30))
        ),
    }

    UNREACHED_TIMES = ("iterations_to_half_info",)

    METRICS = {
        "iterations_to_half_info": "decision phases until the fused map held 50 % of the information available "
        "(§VI-B; nan while not reached)",
        "info_fraction": "information of the fused map, Σ_l ln det Y_l − ln det Y₀, over the information available",
        "normalized_det": "det P / det P₀ of the fused map (Fig. 6) as the per-landmark geometric mean, "
        "(Π_l det P_l / det P₀,l)^(1/N_l), which does not underflow",
        "log10_det_ratio": "log₁₀ of the whole map's det P / det P₀ (the product over landmarks, Fig. 6's quantity)",
        "connected_fraction": "fraction of decision phases after a window at which the whole team was connected",
        "bits_sent": "bits sent in the episode (version vectors, map updates, positions, utility vectors)",
        "own_info_fraction": "mean over vehicles of the information fraction of its own map",
        "rendezvous_fraction": "fraction of vehicle-windows spent on a rendezvous action",
        "clustering_dcomms": "mean clustering coefficient C of the landmark graph at d_comms (§VI-B.1)",
        "clustering_dmax": "mean clustering coefficient C of the landmark graph at d_max = u·t_window",
    }

    INFO_KEYS = {
        "bits_sent": "bits this vehicle sent at the last decision phase",
        "own_info_fraction": "information fraction of this vehicle's own map",
        "group_share": "fraction of the team in this vehicle's connected group",
        "action_kind": "what the last action did: 0 go to a candidate, 1 observe l_p(v) then rendezvous, "
        "2 rendezvous directly, 3 hold",
        "action_feasible": "1 when the last action was feasible (an infeasible one acts as hold)",
        "observations": "independent observations this vehicle made in the last window",
        "action_mask_<i>": "i = 0 … K+1: 1 when action i is feasible now (the same as `env.action_masks()`)",
    }

    LOCAL_VIEW = {
        "position": "(2,) own position (m)",
        "phase": "decision phases so far",
        "map_information": "(L, 2, 2) own information matrices Y_l",
        "map_vector": "(L, 2) own information vectors y_l",
        "map_count": "(L,) observations of each landmark in own map (for the sensor floor)",
        "landmark_estimates": "(L, 2) own estimates Y_l⁻¹ y_l (m)",
        "known_positions": "(N, 2) last known position of every vehicle (own: current)",
        "known_phase": "(N,) phase at which each of those positions was learnt",
        "group": "(N,) bool: vehicles in its connected group now (itself included)",
        "candidates": "(K,) candidate landmark ids, −1 for an empty slot",
        "candidate_utility": "(K,) eq. (1) utility of each candidate",
        "recommended_landmark": "l_p(v) of the group's plan, −1 when unassigned",
        "in_main_cluster": "l_p(v) lies in the plan's main cluster μ_max",
        "rendezvous_landmark": "l_c of the group's plan; while the team is split, the l_c of the last whole-team plan",
        "rendezvous_point": "where the rendezvous action leads (m): l_c as the group's map places it; while the team "
        "is split, where the last whole-team plan placed its l_c, the same point for every vehicle",
        "plan_connected": "the group's plan ended connected (not marked unconnected, §IV-D)",
        "action_mask": "(K + 2,) bool: feasible actions",
    }

    #: configurations at the documented maxima (``tests/core/test_limits.py``, ``mrcomm bench --limits``)
    MEMORY_FORMULA = (
        "18 MiB + 140·`n_vehicles`·`n_landmarks` (every vehicle's information map and utility row) + "
        "12·⌊`t_window`·`obs_rate`⌋ (the observation instants of a window; the compiled window walks each leg's "
        "run of them without listing its observations) + 60·`n_landmarks`·`obs_per_landmark` (the packets some "
        "vehicle still lacks, at most one entry per observation the sensor floor allows: reached only by a team "
        "split for the whole of a long episode)"
    )

    MEMORY_SHARED = 18.0 * 2**20  # the formula's constant term: working memory the copies of a batch share

    MEMORY_ARGS = ("n_vehicles", "n_landmarks", "t_window", "obs_rate", "obs_per_landmark")

    MEMORY_PROBES = {
        "default": {"max_cycles": 3},
        "thirty_vehicles_2000_landmarks_1m_instants": {
            "n_vehicles": 30,
            "n_landmarks": 2000,
            "t_window": 10_000.0,
            "obs_rate": 100.0,
            "max_cycles": 3,
        },
        "largest_team_and_map_3m_instants": {
            "n_vehicles": 64,
            "n_landmarks": 5000,
            "t_window": 30_000.0,
            "obs_rate": 100.0,
            "max_cycles": 3,
        },
    }

    @classmethod
    def memory_estimate(cls, cfg) -> float:
        # measured (tests/core/test_memory.py): ~140 B per vehicle × landmark, ~12 B per observation instant (the
        # window's instants, 8 B each, and their making); the packet logs by their bound (filters.STORED_ENTRY_BYTES
        # per entry, an entry per observation at most)
        instants = math.floor(cfg.t_window * cfg.obs_rate + 1e-9)
        n, landmarks = float(cfg.n_vehicles), float(cfg.n_landmarks)
        packets = filters.STORED_ENTRY_BYTES * landmarks * cfg.obs_per_landmark
        return cls.MEMORY_SHARED + 140.0 * n * landmarks + 12.0 * instants + packets

    LIMIT_CONFIGS = {
        "largest_team_and_map": {
            "n_vehicles": 64,
            "n_landmarks": 5000,
            "k_candidates": 64,
            "obs_per_landmark": 10_000,
            "area": 1e8,
            "d_comms": math.inf,
        },
    }

    DOCUMENTED_CONFIGS = {
        "default": {"max_cycles": 40},
        "infinite_comms": {"d_comms": math.inf, "n_landmarks": 60, "n_vehicles": 4, "area": 2500.0, "max_cycles": 30},
        "zero_comms": {"d_comms": 0.0, "n_landmarks": 60, "n_vehicles": 4, "area": 2500.0, "max_cycles": 30},
        "long_window": {
            "d_comms": 10.0,
            "t_window": 30.0,
            "n_landmarks": 60,
            "n_vehicles": 4,
            "area": 2500.0,
            "max_cycles": 30,
        },
        "single_vehicle": {"n_vehicles": 1, "n_landmarks": 20, "area": 900.0, "k_candidates": 3, "max_cycles": 30},
    }

    VERSION_HISTORY = [
        ("v0", "first version: one step = one decision phase, Discrete(K + 2) actions, fused-map reward"),
        (
            "v0 rev 2",
            "the argument `clumping` (landmark clumps beyond §VI-B.1's shift, for C up to 1); a split team regroups at the point where the last whole-team plan placed its l_c, which every vehicle "
            "holds alike, instead of at each subgroup's own estimate of that landmark (subgroups could miss each "
            "other for good); the observation's and local view's rendezvous point is that point",
        ),
        (
            "v0 rev 3",
            "the argument `start_spread` (vehicles spread around the launch point, as in the paper's Fig. 4; the "
            "default 0 keeps every episode as it was); `planned_clustering(radius)`, C on the prior map the "
            "vehicles plan with",
        ),
        (
            "v0 rev 4",
            "ties among a vehicle's best landmarks go to the lowest landmark id, in the columns Munkres is given "
            "and in the observation's candidate list; they went to numpy's `argpartition`, whose choice among equal "
            "values depends on the SIMD code numpy picks for the CPU, so a seeded episode differed from one CPU to "
            "another (every documented configuration did, between this machine's AVX2 code and numpy's baseline)",
        ),
    ]
