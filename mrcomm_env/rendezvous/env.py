"""RendezvousMapping-v0: decentralised multi-vehicle mapping with limited connectivity (Chapman & Sukkarieh, paper 004).

| | |
| --- | --- |
| Agents | `n_vehicles` vehicles `robot_0 … robot_{N-1}` (10 by default) mapping `n_landmarks` landmarks (200) in a square of `area` m² (10,000, §VI-A) |
| Actions | `Discrete(K + 2)`, K = `k_candidates`: `0 … K−1` go to candidate landmark i and observe it (slot 0 is the group's recommended landmark l_p(v) when the vehicle has one); `K` rendezvous at the group's central landmark l_c, observing l_p(v) on the way when the detour fits the window (Fig. 5 actions 2 and 3); `K + 1` hold (keep observing the landmark it is at). Infeasible actions (empty candidate slots) are masked: `env.action_masks()` (N, K+2) and the infos `action_mask_0 …`; taken anyway they act as hold |
| Observations | `Box(0, 1, (11 + 12K,))`: own position, phase, group share, whole-team connected, own map's information fraction; per candidate (relative position, eq. (1) utility, travel time, in main cluster, recommended, valid); the rendezvous landmark (relative position, travel time, detour fits, plan connected); the K nearest vehicles it knows of (relative position, linked now, staleness, valid) |
| Reward | team reward: increase of Σ_l ln det Y_l of the **fused** global map (the information every vehicle holds) over the step, in units of one landmark's available information per vehicle |
| Arguments | `n_vehicles`, `n_landmarks`, `area`, `speed`, `t_window`, `d_comms`, `sigma`, `clumping`, `k_candidates`, `prior_sigma`, `obs_sigma`, `obs_rate`, `obs_per_landmark`, `start_spread`, `max_cycles` (alias `max_phases`) |

**One env step is one decision phase** (§I, Fig. 1): the actions chosen at phase k are carried out over the
gathering window t_window (travel at speed u, observe, wait), and the window ends with the next decision
phase, at which every connected group fuses its maps over a Dijkstra spanning tree (§III) and plans.

**Landmarks** start on a uniform grid and are shifted by N(0, σ²) within the area (§VI-B.1); σ sets the
mean clustering coefficient C of the landmark graphs at d_comms and d_max = u·t_window (metrics
``clustering_dcomms``, ``clustering_dmax``); ``clumping`` then pulls landmarks into clumps, for C beyond what
the σ shift reaches (our extension). Every vehicle starts with the same prior map (§III: each
landmark's estimate off by N(0, σ₀²)); ``planned_clustering`` gives C on that map, the layout the vehicles
plan with. All start together at a launch point drawn in the area, or, with ``start_spread`` > 0, spread
around it by N(0, start_spread²) per axis (as the paper's Fig. 4 shows them); a split team regroups at the
launch point until its first whole-team plan.

**Filters and fusion** (``filters.py``): information form per landmark, observations z = x + N(0, σ_obs²I)
at ``obs_rate`` Hz while at a landmark; each landmark yields at most ``obs_per_landmark`` independent
observations (the sensor floor, ``theory.py``), which makes the available information finite. Fusion
moves whole packets tracked by version vectors (exact channel-filter bookkeeping): nothing is counted
twice, and a vehicle that was cut off sends, when it reconnects, only what the others lack. Packets every
vehicle holds are folded into the fused map and let go, so memory follows what some vehicle still lacks, not
the episode's length (at most one entry per observation the sensor floor allows: *Memory*). Bits are
counted for the version vectors, map updates, positions and utility vectors sent on each tree edge.

**The plan** (``protocol.py``): at each decision phase every connected group runs the recommendation
phase of §IV on its shared map (utility eq. (1)–(4), Munkres, clusters, cluster value eq. (6),
eigenvector centrality, partition eq. (7)–(8)). It defines each member's recommended landmark l_p(v),
the main cluster and the rendezvous landmark l_c of the actions above. **Regrouping** (our rule: the
paper assumes the planned network always forms, §V, and is silent on a split team): while the team is
split into several groups, the rendezvous landmark of every group is the l_c of the last plan the whole
team made together, and the rendezvous action leads to the point where that plan's shared map placed it:
every vehicle holds the same point, so the subgroups meet again (their own maps' estimates of l_c drift
apart while they are split; aimed at those, two subgroups could miss each other for good). A vehicle's candidates are
l_p(v) then its highest-utility landmarks; landmarks it believes exhausted are not candidates.

**Moving** goes to the vehicle's own estimate of a landmark, straight at speed u; a target out of reach
is approached for the whole window (§IV-A's ε utility: "travel towards"). With d_comms = 0 vehicles are
linked only when co-located, i.e. after a rendezvous at the same landmark.
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces
from matplotlib.collections import LineCollection

from mrcomm_env.core import BitLedger, MrcommParallelEnv
from mrcomm_env.core import render as rendering
from mrcomm_env.core.base import MASK_INFO_PREFIX
from mrcomm_env.rendezvous import filters, observe_numba, plan_numba, protocol, theory, window_numba, world
from mrcomm_env.rendezvous.spec import RendezvousMappingSpec

#: action kinds reported in the infos
GO, DETOUR_RENDEZVOUS, RENDEZVOUS, HOLD = 0, 1, 2, 3
#: bits of one position (two floats) and of one utility entry
POSITION_BITS = 2 * filters.FLOAT_BITS


class RendezvousMappingEnv(RendezvousMappingSpec, MrcommParallelEnv):
    ENV_ID = "mrcomm/RendezvousMapping-v0"
    DESCRIPTION = (
        "Which landmark each vehicle maps, or where the team regroups, when maps fuse only over a "
        "connected acyclic network (decentralised mapping with limited connectivity)"
    )
    metadata = {"name": "rendezvous_mapping_v0", "render_modes": ["rgb_array", "human"], "render_fps": 4}
    STEP_UNIT = ("decision phase", False)

    def __init__(self, render_mode: str | None = None, **kwargs):
        if "max_phases" in kwargs:  # the name for the horizon
            if "max_cycles" in kwargs:
                raise ValueError("pass the horizon as 'max_cycles' or 'max_phases', not both")
            kwargs["max_cycles"] = kwargs.pop("max_phases")
        super().__init__(render_mode=render_mode, **kwargs)

    # ----------------------------------------------------------------- setup
    def _setup(self) -> None:
        c = self.cfg
        if c.n_landmarks < c.n_vehicles:
            raise ValueError(
                f"argument 'n_landmarks' must be at least n_vehicles = {c.n_vehicles}, got {c.n_landmarks}"
            )
        n, K = c.n_vehicles, c.k_candidates
        self.n_agents = n
        self.K = K
        self.side = math.sqrt(c.area)
        self.d_max = c.speed * c.t_window
        self.r_info = theory.information_per_observation(c.obs_sigma)
        self.y0_info = theory.prior_information(c.prior_sigma)
        self.avail_per_landmark = theory.available_information(c.prior_sigma, c.obs_sigma, c.obs_per_landmark)
        self.gain_ratio = (c.prior_sigma / c.obs_sigma) ** 2  # σ₀²/σ_obs²: one observation's information over Y₀
        self.available = self.avail_per_landmark * c.n_landmarks
        self.u_max = theory.max_utility(c.prior_sigma, c.obs_sigma, c.obs_per_landmark)
        # reward unit: one landmark's available information per vehicle, so that a team mapping one fresh
        # landmark per vehicle and phase, fused at once, earns about 1 per step
        self.reward_scale = self.avail_per_landmark * n
        ticks = math.floor(c.t_window * c.obs_rate + 1e-9)
        self.ticks = np.arange(1, ticks + 1) / c.obs_rate  # observation instants within a window
        self.obs_dim = 11 + 12 * K
        self._obs_space = spaces.Box(0.0, 1.0, shape=(self.obs_dim,), dtype=np.float32)
        self._act_space = spaces.Discrete(K + 2)
        self.ledger = BitLedger(n)
        self._mask_keys = [f"{MASK_INFO_PREFIX}{i}" for i in range(K + 2)]

    # ----------------------------------------------------------------- episode
    def _reset_world(self) -> None:
        c, n, rng = self.cfg, self.n_agents, self.np_random
        L = c.n_landmarks
        self.landmarks = world.clump(world.jittered_grid(L, self.side, c.sigma, rng), self.side, c.clumping, rng)
        prior_mean = self.landmarks + rng.normal(0.0, c.prior_sigma, size=(L, 2))
        self.prior_mean = prior_mean  # the common map every vehicle starts with and plans its first phase on
        Y0 = np.broadcast_to(np.eye(2) * self.y0_info, (L, 2, 2)).copy()
        y0 = prior_mean * self.y0_info
        self.maps = filters.TeamMaps(n, Y0, y0, np.eye(2) * self.r_info)
        self.logdet0 = float(filters.logdet2(Y0).sum())
        self.fused_gain = 0.0  # Σ_l ln det Y_l − ln det Y₀ of the fused map, kept apart from ln det Y₀ (round-off)
        self.world_count = np.zeros(L, dtype=np.int64)
        launch = rng.uniform(0.0, self.side, size=2)
        self.pos = np.broadcast_to(launch, (n, 2)).copy()
        if c.start_spread > 0:  # drawn last: without a spread, every other draw of the episode is as before
            self.pos = world.reflect(launch + rng.normal(0.0, c.start_spread, size=(n, 2)), self.side)
        self.at_landmark = np.full(n, -1, dtype=np.int64)
        self.known_pos = np.broadcast_to(self.pos, (n, n, 2)).copy()
        self.known_phase = np.zeros((n, n), dtype=np.int64)
        self.ledger.reset()
        self.phases = 0
        self.connected_phases = 0
        self.rendezvous_windows = 0
        self.half_phase = math.nan
        # where a split team regroups: l_c of the last plan the whole team made together, as a landmark and as
        # the point that plan's shared map placed it at. Every vehicle took part in that plan and holds the same
        # point, so the subgroups of a split team head for one place: their own maps' estimates of l_c have
        # drifted apart since, and two subgroups aiming at two estimates could miss each other for good
        # (§IV computes l_c from the information the whole team shares; §V assumes the team never splits).
        # Before the first whole-team plan a split team regroups at the launch point (where all start, unless
        # spread around it).
        self.regroup = np.zeros(n, dtype=np.int64)
        self.regroup_point = np.broadcast_to(launch, (n, 2)).copy()
        self.action_kind = np.full(n, HOLD, dtype=np.int64)
        self.action_ok = np.ones(n, dtype=bool)
        self.step_obs = np.zeros(n, dtype=np.int64)
        self._clustering: dict[str, float] = {}
        self._decision_phase()

    # ----------------------------------------------------------------- dynamics
    def _step_world(self, actions: list) -> float:
        new_pos, new_at, vehicles, observed = self._window(actions)
        kind = self.action_kind
        self.rendezvous_windows += int(np.count_nonzero((kind == DETOUR_RENDEZVOUS) | (kind == RENDEZVOUS)))
        self._apply_observations(vehicles, observed)
        self.pos, self.at_landmark = new_pos, new_at
        before = self.fused_gain
        self.phases += 1
        self._decision_phase()
        self.connected_phases += int(self.n_groups == 1)
        frac = self.info_fraction()
        if math.isnan(self.half_phase) and frac >= 0.5:
            self.half_phase = float(self.phases)
        return (self.fused_gain - before) / self.reward_scale

    def _window(self, actions: list) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The window in one compiled call (``window_numba.window``; its numpy oracle is
        ``tests/helpers/rendezvous_reference.py``): every vehicle's route (Fig. 5: a candidate landmark, the
        rendezvous with a detour over its recommended landmark when it fits, or holding), and the observations its
        landmarks still yield under the sensor floor. Returns the new positions, landmarks stayed at, and the kept
        observations' vehicles and landmarks in time order. Sets ``action_kind`` and ``action_ok``."""
        c = self.cfg
        return window_numba.window(
            np.asarray(actions, dtype=np.int64),
            self.mask,
            self.candidates,
            self.assignment,
            self.central,
            self.rendezvous_point,
            self.at_landmark,
            self.pos,
            self._estimates,
            self.ticks,
            c.t_window,
            c.speed,
            self.world_count,
            c.obs_per_landmark,
            self.action_kind,
            self.action_ok,
        )

    def _apply_observations(self, v: np.ndarray, lm: np.ndarray) -> None:
        """The kept observations (vehicles ``v`` of landmarks ``lm``, in time order), drawn and added to the
        observing vehicles' own maps."""
        c = self.cfg
        self.step_obs[:] = 0
        if len(lm) == 0:
            return
        np.add.at(self.world_count, lm, 1)
        z = self.landmarks[lm] + self.np_random.normal(0.0, c.obs_sigma, size=(len(lm), 2))
        owners, bounds, ids, counts, dy, per_vehicle = self._packets(v, lm, z * self.r_info)
        for owner, start, end in zip(owners.tolist(), bounds[:-1].tolist(), bounds[1:].tolist()):
            self.maps.add_own(owner, filters.Packet(ids[start:end], dy[start:end], counts[start:end]))
        self.step_obs[:] = per_vehicle

    def _packets(self, v: np.ndarray, lm: np.ndarray, weighted: np.ndarray) -> tuple:
        """Every observing vehicle's packet, its landmarks in increasing order, each pair's observations summed in
        time order, in one compiled call (``window_numba.group_observations``; its numpy oracle is
        ``tests/helpers/rendezvous_reference.py``): the owners in increasing order, their bounds into the packets'
        landmark ids, counts and summed information vectors, and each vehicle's observations."""
        return window_numba.group_observations(v, lm, weighted, self.cfg.n_landmarks, self.n_agents)

    def _decision_phase(self) -> None:
        """Fuse over each group's Dijkstra tree, share positions and utilities, update the fused map, plan."""
        n, c, maps = self.n_agents, self.cfg, self.maps
        L = c.n_landmarks
        self.links = world.vehicle_links(self.pos, c.d_comms)
        self.labels, self.parent = world.spanning_forest(self.pos, self.links)
        self.n_groups = int(self.labels.max()) + 1
        bits = np.zeros(n)
        self.group = self.labels[:, None] == self.labels[None, :]
        messages = 0
        self.link_bits: dict[tuple[int, int], float] = {}  # bits over each tree edge at this decision phase
        own = np.arange(n)
        self.known_pos[own, own] = self.pos  # a vehicle always knows where it is
        self.known_phase[own, own] = self.phases
        # the groups of two or more, in label order, each's members in increasing order (alone: nothing to send)
        by_label = np.argsort(self.labels, kind="stable")
        bounds = np.concatenate([[0], np.cumsum(np.bincount(self.labels, minlength=self.n_groups))]).tolist()
        self._teams = [by_label[lo:hi] for lo, hi in zip(bounds[:-1], bounds[1:]) if hi - lo > 1]
        for members in self._teams:
            sides = filters.subtree_sides(members, self.parent)
            sent = maps.fuse_group(members, self.parent, sides)
            messages += 2 * len(sides)
            for a, side in sides.items():
                b = int(self.parent[a])
                # per direction: version vector, then the map packets the other side lacks, then the positions
                # and the utility vectors (eq. 1) of the vehicles on the sender's side
                per_vehicle = POSITION_BITS + L * filters.FLOAT_BITS
                bits[a] += n * filters.COUNT_BITS + sent[(a, b)] + len(side) * per_vehicle
                bits[b] += n * filters.COUNT_BITS + sent[(b, a)] + (len(members) - len(side)) * per_vehicle
                self.link_bits[(a, b)] = (
                    2 * n * filters.COUNT_BITS + sent[(a, b)] + sent[(b, a)] + len(members) * per_vehicle
                )
            rows = members[:, None]  # every member learns every member's position (the same cells np.ix_ picks)
            self.known_pos[rows, members] = self.pos[members]
            self.known_phase[rows, members] = self.phases
        self.ledger.record(bits, messages=messages)
        if maps.update_common():
            self.fused_gain = self.information_gain(maps.common_count)
        self._estimates = filters.mean_of(maps.Y, maps.y)
        self._plan()
        self._views = None

    def _plan(self) -> None:
        """Each group's recommendation phase (§IV) on its shared map; candidates and masks per vehicle."""
        n, c, K, maps = self.n_agents, self.cfg, self.K, self.maps
        self.assignment = np.full(n, -1, dtype=np.int64)
        self.in_main = np.zeros(n, dtype=bool)
        self.central = np.zeros(n, dtype=np.int64)
        self.rendezvous_point = np.zeros((n, 2))
        self.plan_connected = np.zeros(n, dtype=bool)
        # every vehicle's eq. (1) row from its own map; members of a group hold the same map after fusion, so
        # a group's rows form the utility matrix its members assemble from the shared vectors (§IV-A)
        self.utility = protocol.utility_matrix(
            maps.Y,
            maps.count,
            self.pos,
            self._estimates,
            c.speed,
            c.t_window,
            self.r_info,
            c.obs_rate,
            c.obs_per_landmark,
        )
        teams = self._teams
        if n > 1:  # a vehicle alone plans its best landmark (recommend's group of one) and regroups as agreed
            alone = np.ones(n, dtype=bool)
            for members in teams:
                alone[members] = False
            alone = np.flatnonzero(alone)
            self.assignment[alone] = np.argmax(self.utility[alone], axis=1)
            self.in_main[alone] = self.plan_connected[alone] = True
            self.central[alone] = self.regroup[alone]
            self.rendezvous_point[alone] = self.regroup_point[alone]
        else:
            teams = [np.zeros(1, dtype=np.int64)]
        for members in teams:
            rec = protocol.recommend(self.utility[members], self._estimates[int(members[0])], c.d_comms)
            self.assignment[members] = rec.assignment
            self.in_main[members] = rec.in_main
            self.plan_connected[members] = rec.connected
            if len(members) == n:  # the whole team planned together: its l_c is the regroup point from now on
                self.central[members] = rec.central
                self.regroup[:] = rec.central
                # members hold one fused map after the decision phase: they all place l_c at this point
                self.regroup_point[:] = self._estimates[int(members[0]), rec.central]
                self.rendezvous_point[members] = self._estimates[members, rec.central]
            else:  # a split team regroups where it last agreed to meet (our rule; §V assumes no split)
                self.central[members] = self.regroup[members]
                self.rendezvous_point[members] = self.regroup_point[members]
        self.candidates, self.candidate_utility = candidate_lists(self.utility, self.assignment, K)
        self.mask = np.ones((n, K + 2), dtype=bool)
        self.mask[:, :K] = self.candidates >= 0

    # ----------------------------------------------------------------- queries
    def action_label(self, action) -> str:
        """Fig. 5's kinds of decision: slot 0 (the group's recommended landmark l_p(v) when the vehicle has one),
        another candidate landmark, a rendezvous at l_c, or hold."""
        a = int(action)
        if a == 0:
            return "first candidate (recommended)"
        if a < self.K:
            return "other candidate"
        return "rendezvous" if a == self.K else "hold"

    def decision_context(self) -> list[str]:
        """How much of the team a vehicle's connected group holds now (maps are shared within a group)."""
        sizes = self.group.sum(axis=1)
        n = self.n_agents
        return ["with the whole team" if k == n else "alone" if k == 1 else "with part of the team" for k in sizes]

    def action_masks(self) -> np.ndarray:
        """(N, K + 2) bool: the feasible actions of every vehicle (sb3-contrib's MaskablePPO reads this)."""
        return self.mask.copy()

    def information_gain(self, counts: np.ndarray) -> float | np.ndarray:
        """Σ_l ln det Y_l − ln det Y₀ of maps holding ``counts[..., l]`` observations of landmark l.

        The prior Y₀ = I/σ₀² and every observation's R⁻¹ = I/σ_obs² are isotropic and H = I (eq. 3), so each
        Y_l = (1/σ₀² + k_l/σ_obs²)·I and its gain is exactly 2·ln(1 + k_l·σ₀²/σ_obs²), summed with log1p. The
        difference of two log-determinants of the accumulated matrices would lose every digit where one
        observation adds little to the prior (σ₀ = 1e-3 m, σ_obs = 1e4 m: a gain of 2e-14 against ln det Y₀ ≈ 28).
        """
        gains = 2.0 * np.log1p(counts * self.gain_ratio).sum(-1)
        return float(gains) if np.ndim(gains) == 0 else gains

    def info_fraction(self) -> float:
        # ≤ 1 in exact arithmetic (every landmark's count is capped by obs_per_landmark); the sum may round 1 ulp over
        return min(self.fused_gain / self.available, 1.0)

    def own_info_fraction(self) -> np.ndarray:
        return self.information_gain(self.maps.count) / self.available

    def clustering(self, radius: float) -> float:
        """C of the landmark graph of ``radius`` on the true layout."""
        key = f"{radius:.9g}"
        if key not in self._clustering:
            self._clustering[key] = world.clustering_coefficient(self.landmarks, radius)
        return self._clustering[key]

    def planned_clustering(self, radius: float) -> float:
        """C of the landmark graph of ``radius`` on the common prior map: the layout the vehicles plan and travel
        on (§III), which the prior error σ₀ moves away from the true one."""
        key = f"planned {radius:.9g}"
        if key not in self._clustering:
            self._clustering[key] = world.clustering_coefficient(self.prior_mean, radius)
        return self._clustering[key]

    # ----------------------------------------------------------------- views
    def _local_view(self) -> dict:
        if self._views is None:
            self._views = {
                "position": self.pos,
                "phase": np.full(self.n_agents, self.phases),
                "map_information": self.maps.Y,
                "map_vector": self.maps.y,
                "map_count": self.maps.count,
                "landmark_estimates": self._estimates,
                "known_positions": self.known_pos,
                "known_phase": self.known_phase,
                "group": self.group,
                "candidates": self.candidates,
                "candidate_utility": self.candidate_utility,
                "recommended_landmark": self.assignment,
                "in_main_cluster": self.in_main,
                "rendezvous_landmark": self.central,
                "rendezvous_point": self.rendezvous_point,
                "plan_connected": self.plan_connected,
                "action_mask": self.mask,
            }
        return self._views

    def _observe(self) -> np.ndarray:
        """The observation of the module's table in one compiled call (``observe_numba.observe``; its numpy oracle is
        ``tests/helpers/rendezvous_reference.py``)."""
        c = self.cfg
        return observe_numba.observe(
            self.pos,
            self.side,
            min(self.phases / c.max_cycles, 1.0),
            self.group,
            self.n_groups == 1,
            self.own_info_fraction(),
            self.candidates,
            self.candidate_utility,
            self.u_max,
            self._estimates,
            self.in_main,
            self.assignment,
            self.rendezvous_point,
            self.plan_connected,
            self.known_pos,
            self.known_phase,
            self.phases,
            c.speed,
            c.t_window,
            self.d_max,
        )

    def _agent_infos(self) -> dict:
        out = {
            "bits_sent": self.ledger.step_bits,
            "own_info_fraction": self.own_info_fraction(),
            "group_share": self.group.sum(1) / self.n_agents,
            "action_kind": self.action_kind,
            "action_feasible": self.action_ok,
            "observations": self.step_obs,
        }
        for i, key in enumerate(self._mask_keys):
            out[key] = self.mask[:, i]
        return out

    def _terminated(self) -> bool:
        return bool(self.info_fraction() >= 1.0 - 1e-9)

    def _metrics(self) -> dict[str, float]:
        c = self.cfg
        frac = self.info_fraction()
        log_ratio = -self.fused_gain  # ln det P − ln det P₀ of the whole map
        return {
            "iterations_to_half_info": self.half_phase,
            "info_fraction": frac,
            "normalized_det": math.exp(log_ratio / c.n_landmarks),
            "log10_det_ratio": log_ratio / math.log(10.0),
            "connected_fraction": self.connected_phases / self.phases if self.phases else 1.0,
            "bits_sent": float(self.ledger.total_bits.sum()),
            "own_info_fraction": float(self.own_info_fraction().mean()),
            "rendezvous_fraction": self.rendezvous_windows / (self.phases * self.n_agents) if self.phases else 0.0,
            "clustering_dcomms": self.clustering(c.d_comms) if math.isfinite(c.d_comms) else 1.0,
            "clustering_dmax": self.clustering(self.d_max),
        }

    def _render(self, ax) -> None:
        lm = self.landmarks
        est = self._estimates[0]
        if math.isfinite(self.cfg.d_comms) and self.cfg.d_comms > 0:
            ii, jj = np.nonzero(np.triu(world.landmark_graph(est, self.cfg.d_comms)))
            ax.add_collection(LineCollection(np.stack([est[ii], est[jj]], 1), colors="0.85", linewidths=0.5, zorder=1))
        sat = self.maps.common_count / self.cfg.obs_per_landmark
        sc = ax.scatter(lm[:, 0], lm[:, 1], c=sat, cmap="viridis", vmin=0, vmax=1, marker="x", s=18, zorder=2)
        ax.figure.colorbar(sc, ax=ax, label="fused observations / floor")
        ax.scatter(
            self.pos[:, 0], self.pos[:, 1], c=self.labels, cmap="tab10", marker="s", s=40, zorder=3, edgecolors="k"
        )
        edges = np.array(list(self.link_bits), dtype=np.int64).reshape(-1, 2)
        rendering.draw_link_bits(ax, self.pos, edges, np.array(list(self.link_bits.values()), dtype=float))
        lc = self.rendezvous_point
        ax.scatter(lc[:, 0], lc[:, 1], marker="*", s=120, facecolors="none", edgecolors="r", zorder=4)
        ax.set_xlim(-0.02 * self.side, 1.02 * self.side)
        ax.set_ylim(-0.02 * self.side, 1.02 * self.side)
        ax.set_aspect("equal")
        ax.set_title(
            f"phase {self.phases}: fused {100 * self.info_fraction():.0f} % of the information, "
            f"{self.n_groups} group(s)"
        )


def candidate_lists(utility: np.ndarray, assignment: np.ndarray, K: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, K) candidate landmarks and their utilities: the recommended landmark first (when assigned and worth
    anything), then the highest-utility others by (utility, lowest id: a stable ranking, never one whose choice
    among ties depends on the CPU); landmarks worth nothing (believed exhausted) are left out, empty slots are −1.
    Two compiled calls (``plan_numba.negated_work``, ``ranked_candidates``; their numpy oracle is
    ``tests/helpers/rendezvous_reference.py``). A recommendation that is no landmark raises ``IndexError``."""
    k = min(K, utility.shape[1])
    utility = np.ascontiguousarray(utility, dtype=np.float64)
    assignment = np.ascontiguousarray(assignment, dtype=np.int64)
    return plan_numba.ranked_candidates(utility, plan_numba.negated_work(utility, assignment), k, K)
