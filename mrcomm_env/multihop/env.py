"""MultiHop-v0: multi-hopping time-stamped state estimates over TDMA (Julian et al., paper 003).

| | |
| --- | --- |
| Agents | `n_robots` robots `robot_0 … robot_{N-1}` (grid: `grid_side²`, field: 20, coverage: 9 by default; at most 1024, 25 in the coverage scene) |
| Actions | `layout="relative"` (default): `MultiBinary(N − 1)` per robot, one bit per *candidate*: the other robots ranked by my estimated distance to them (nearest first; estimates I do not hold last, by slot order after mine). The env sends my own estimate plus the first `slot_size − 1` selected candidates I hold at my slot; unselected ones are withheld, so a robot may send fewer than `m` and save bits. `layout="absolute"` (v0): `Box(0, 1, (N,))`, a priority per robot index (ties: lower index; 0 withholds) |
| Observations | `relative`: `Box(0, 1, (5(N − 1) + 3,))`, per candidate rank: held (0/1), estimated distance over the arena diagonal, age `a/(a + T_frame)`, freshness gained since I last broadcast it `g/(g + T_frame)`, its slot position after mine (with `observe_heard`, a sixth: the freshness my neighbours lack of it, as far as what I heard them broadcast and broadcast to them tells, `(6(N − 1) + 3,)`); then my slot `s_i/N`, `m/N` and the fraction of robots I hold. `absolute` (v0): `Box(0, 1, (3N + 2,))` by robot index |
| Reward | `−(Σ w_ij a_ij / Σ w_ij) / (10 T_frame) − lam · bits / (N m b)`: the importance-weighted age of information (eq. (1) weights `w_ij = d_ij^-α`) in units of ten frames, and the share of the slots' capacity used; `reward_mode="neighbourhood"` gives each robot the weighted age held by its neighbours (what its broadcast refreshes) and its own bits instead |
| Arguments | `scene`, `n_robots`, `grid_side`, `slot_size`, `alpha`, `bits_per_estimate`, `baud`, `max_cycles`, `arena_size`, `comm_range`, `speed`, `max_speed`, `control_gain`, `layout`, `lam`, `reward_mode`, `observe_heard` |

Every robot knows its own current state and keeps a list of the others' estimates, each with the time
stamp at which it was valid; at the start it knows only its own (unknown = "infinite", §2.1). TDMA gives
every robot one slot per frame, in an order drawn at random per episode (§4). A slot carries ``m``
estimates of ``b`` bits and lasts ``m b / r_b`` seconds, so a frame lasts ``n m b / r_b`` and the frame
rate is ``r_f = r_b / (m n b)`` (§2.1). Time is kept in these real units (seconds). Receivers keep the
newest time stamp per robot. Scenes: ``grid`` (the paper's stationary 10×10 grid with 4-neighbour links,
Fig. 2), ``field`` (disk links of radius ``comm_range``, random-waypoint motion at ``speed``, 0 = static)
and ``coverage`` (nine flying robots running a Voronoi coverage controller on their *received* estimates,
§4 / Fig. 3; the cost is in the metrics).

**One env step is one TDMA frame.** Every robot transmits exactly once per frame, so in a frame step all
N agents act, which is what a parallel env expresses; with one step per slot 99 of 100 actions would be
ignored each step and every step would pay the PettingZoo overhead of N agents. A robot's priorities are
chosen at the start of the frame and applied *at its slot*, to the estimates it holds then (estimates
received earlier in the same frame are eligible). Algorithm 1's counters live in the policy
(``baselines/multihop.py``); on stationary scenes in steady state this reproduces the per-slot
algorithm exactly; during the cold start the policy sees new estimates one frame later than a per-slot
implementation (the reproduction runs the per-slot algorithm through the same core, ``protocol.py``).
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces
from matplotlib.collections import LineCollection
from matplotlib.colors import LogNorm
from scipy.sparse.csgraph import shortest_path

from mrcomm_env.core import BitLedger, MrcommParallelEnv, TDMASchedule, disk_links, grid_links
from mrcomm_env.core import render as rendering
from mrcomm_env.core.base import MASK_INFO_PREFIX
from mrcomm_env.multihop import copy_axis, frame_numba, theory
from mrcomm_env.multihop import coverage as cov
from mrcomm_env.multihop import protocol as proto
from mrcomm_env.multihop.spec import (  # noqa: F401 — the limits are part of this module's API
    HOP_BUCKETS,
    MAX_ALPHA,
    MAX_COVERAGE_ROBOTS,
    MAX_SPEED,
    SUBGRAPHS,
    MultiHopSpec,
)

RELATIVE_FEATURES = 5  # per candidate: held, distance, age, freshness gained, slot position
AGE_SCALE_FRAMES = 10.0  # the reward's age unit: ten frames keep it O(1) per step
CONTROL_PERIOD, MAX_CONTROL_STEPS = 0.25, 16  # coverage controller: seconds per Euler step, steps per slot at most


class MultiHopEnv(MultiHopSpec, MrcommParallelEnv):
    ENV_ID = "mrcomm/MultiHop-v0"
    DESCRIPTION = "Which time-stamped state estimates fill each robot's TDMA slot (location-based multi-hopping)"
    metadata = {"name": "multihop_v0", "render_modes": ["rgb_array", "human"], "render_fps": 4}
    STEP_UNIT = ("slot", True)  # one env step is one TDMA frame: N slots

    @classmethod
    def copy_axis_world(cls, cfg):
        """Every scene (the grid, the field with robots still or moving, the coverage controller), in either layout,
        with either reward and, on static links, with or without ``observe_heard``, steps M copies as one batch of
        arrays (:mod:`.copy_axis`); the env itself steps as that world of its one copy."""
        moving = cfg.scene == "coverage" or (cfg.scene == "field" and cfg.speed > 0)
        return copy_axis.MovingBatch if moving else copy_axis.StaticFrameBatch

    # ----------------------------------------------------------------- setup
    def _setup(self) -> None:
        c = self.cfg
        if c.scene == "grid":
            n = c.grid_side**2 if c.n_robots is None else c.n_robots
        else:
            n = c.n_robots if c.n_robots is not None else (9 if c.scene == "coverage" else 20)
        if c.scene == "coverage" and n > MAX_COVERAGE_ROBOTS:
            raise ValueError(
                f"argument 'n_robots' must be at most {MAX_COVERAGE_ROBOTS} when 'scene' is 'coverage' "
                f"(every robot's Voronoi controller runs at every slot: O(n³) per frame), got {n}"
            )
        m = min(7, n) if c.slot_size is None else c.slot_size
        if m > n:
            raise ValueError(f"argument 'slot_size' must be in [1, n_robots = {n}], got {m}")
        self.n_agents = n
        self.m = m
        self.slot_dur = theory.slot_duration(self.m, c.bits_per_estimate, c.baud)
        self.frame_dur = n * self.slot_dur
        self._age_unit = AGE_SCALE_FRAMES * self.frame_dur  # the reward's unit of age
        self._moving = (c.scene == "field" and c.speed > 0) or c.scene == "coverage"
        if c.scene == "grid":
            cols = c.grid_side
            rows = -(-n // cols)
            self.side = float(max(cols, rows) - 1)
            r = np.arange(n)
            self._grid_pos = np.column_stack([r % cols, r // cols]).astype(np.float64)
            self._static_adj = grid_links(rows, cols)[:n, :n]  # row-major ids: a partial last row is a slice
            square = n == cols * cols
            self._blocks = {k: proto.centred_block(cols, k) if square else np.empty(0, np.int64) for k in SUBGRAPHS}
        else:
            self.side = float(c.arena_size)
            self._blocks = {}
        self.diag = max(self.side * math.sqrt(2.0), 1e-9)
        if c.scene != "grid":
            self._cost_points = cov.sample_points(self.side, 40)
            self._ctrl_points = cov.sample_points(self.side, 30)
        self._relative = c.layout == "relative"
        if c.observe_heard and (not self._relative or self._moving):
            raise ValueError(
                "argument 'observe_heard' needs the 'relative' layout on static links (scene 'grid', or 'field' with "
                f"speed 0): what a robot heard bounds its neighbours' tables only while the links hold; got layout "
                f"{c.layout!r}, scene {c.scene!r}, speed {c.speed!r}"
            )
        if c.mask_unheld and not self._relative:
            raise ValueError(
                "argument 'mask_unheld' needs the 'relative' layout (it masks select bits, one per candidate); got "
                f"layout {c.layout!r}"
            )
        if c.mask_unheld:
            # an instance attribute, not a method: whether an env masks actions is whether it has action_masks()
            # (sb3-contrib, the trainers and the adapters ask that way), and without the argument this env does not
            self.action_masks = self._held_candidates
            self._mask_keys = [f"{MASK_INFO_PREFIX}{k}" for k in range(n - 1)]
        #: per candidate: RELATIVE_FEATURES, and with ``observe_heard`` the freshness its neighbours lack
        self._features = RELATIVE_FEATURES + int(c.observe_heard)
        if self._relative:
            self._obs_space = spaces.Box(0.0, 1.0, shape=(self._features * (n - 1) + 3,), dtype=np.float32)
            self._act_space = spaces.MultiBinary(n - 1)
        else:
            self._obs_space = spaces.Box(0.0, 1.0, shape=(3 * n + 2,), dtype=np.float32)
            self._act_space = spaces.Box(0.0, 1.0, shape=(n,), dtype=np.float32)
        self._eye = np.eye(n, dtype=bool)
        self._others = ~self._eye
        self._capacity = n * self.m * c.bits_per_estimate  # bits one frame can carry
        self.ledger = BitLedger(n)

    # ----------------------------------------------------------------- episode
    def _reset_world(self) -> None:
        c, n, rng = self.cfg, self.n_agents, self.np_random
        self.tdma = TDMASchedule(n, rng)  # random slot order per episode (§4)
        slot = self.tdma.slot_of
        self._phase = ((slot[None, :] - slot[:, None]) % n) / n  # j's slot position after i's
        if c.scene == "grid":
            self.pos = self._grid_pos.copy()
        elif c.scene == "field":
            self.pos = rng.uniform(0.0, self.side, size=(n, 2))
            self.waypoint = rng.uniform(0.0, self.side, size=(n, 2))
        else:  # coverage: take off from a corner region, spread out by the controller
            self.pos = rng.uniform(0.0, 0.25 * self.side, size=(n, 2))
        self._links()
        self._hops()
        self.t = 0.0
        self.stamps = np.full((n, n), proto.UNKNOWN)
        self.stamps[self._eye] = 0.0
        self.est = np.broadcast_to(self.pos, (n, n, 2)).copy()  # only entries with a stamp mean anything
        self.first_known = np.full((n, n), np.inf)
        self.first_known[self._eye] = 0.0
        self._all_known = False
        self.last_sent = np.zeros((n, n), dtype=bool)
        self.sent_stamp = np.full((n, n), -self.frame_dur)  # never sent: as if sent one frame before start
        # heard[i, k, j]: the freshest stamp of j robot i heard k broadcast, or broadcast to k (observe_heard)
        self.heard = np.full((n, n, n), proto.UNKNOWN) if c.observe_heard else None
        self.ledger.reset()
        self._step_bits = np.zeros(n)
        self._frames = 0
        self._sum_age = 0.0
        self._sum_wage = 0.0
        self._max_age = np.zeros(len(HOP_BUCKETS))
        self._sum_age_hop = np.zeros(len(HOP_BUCKETS))
        self._reward_weights()
        self._ages: np.ndarray | None = np.zeros((n, n))
        # what the robots held when the candidates were last ranked (static scenes)
        self._ranked_known: np.ndarray | None = None
        if self._relative:
            self._rank_candidates()
        # every scene steps as a copy-axis world of this one copy (copy_axis.py, the code a batch of M copies runs),
        # built at the first step; the frame slot by slot in numpy is its test oracle (tests/helpers/multihop_reference.py)
        self._world_obs: np.ndarray | None = None  # the observation and infos of the world's last frame
        self._world_infos: dict | None = None
        if self.__dict__.get("_one_copy") is not None:
            self._bind_one_copy()

    def _links(self) -> None:
        if self.cfg.scene == "grid":
            self.adj = self._static_adj
        else:
            self.adj = disk_links(self.pos, self.cfg.comm_range)

    def _hops(self) -> None:
        """Hop-distance buckets of the current topology (for the max-age-by-hop metrics)."""
        hops = shortest_path(self.adj, unweighted=True, directed=False)
        self._hop_masks = [hops == 1, hops == 2, hops == 3, (hops >= 4) & ~self._eye]

    def _reward_weights(self) -> None:
        """Eq. (1)'s weights of the reward at the positions now (:func:`.protocol.reward_weights`)."""
        self._w, total = proto.reward_weights(self.pos, self.cfg.alpha)
        self._wsum = float(total)

    # ----------------------------------------------------------------- dynamics
    def _step_world(self, actions: list) -> float | np.ndarray:
        """One frame as the copy-axis world of this one copy (:mod:`.copy_axis`)."""
        if self.__dict__.get("_one_copy") is None:
            self._one_copy = type(self).copy_axis_world(self.cfg)([self])
            self._bind_one_copy()
        elif any(getattr(self, name) is not view for name, view in zip(self._view_names, self._world_views)):
            self._bind_one_copy()  # an array replaced from outside (a batch writing a copy back, a user): take it in
        else:
            self._one_copy.adopt_counters(0)  # the clock, time averages and bits as the env holds them now
        world = self._one_copy
        obs, rewards, _, _, infos = world.step(np.asarray(actions)[None])
        self.t = float(world.t[0])
        if self._moving:
            self._wsum = float(world.weight_sum[0])
        self._take_counters(world.counters(0))
        self.ledger.record(self._step_bits, messages=self.n_agents)
        self._world_obs = obs[0]
        self._world_infos = {key: column[0] for key, column in infos.items()}
        return rewards[0].copy() if self.cfg.reward_mode == "neighbourhood" else float(rewards[0, 0])

    # ----------------------------------------------------------------- what its copy-axis world reads and writes
    def world_constants(self) -> dict:
        """Constants of one configuration that its copy-axis world (:mod:`.copy_axis`) computes with: the bits a
        frame can carry, the reward's unit of age, the observation's width and its features per candidate; in the
        coverage scene, the controller's Euler steps per slot and the points its cells are sampled on."""
        obs_dim = int(np.prod(self._obs_space.shape or (1,)))  # a flat Box
        constants = {
            "capacity": self._capacity,
            "age_unit": self._age_unit,
            "obs_dim": obs_dim,
            "features": self._features,
        }
        if self.cfg.scene == "coverage":
            constants.update(control_steps=self._control_steps(self.slot_dur), control_points=self._ctrl_points)
        return constants

    def world_arrays(self) -> dict:
        """The episode's fixed arrays and its ranking, which a copy-axis world copies into its rows at a reset:
        slot phases, eq. (1)'s weights and their sum, the hop buckets' pair masks, the links (the matrix, and its
        rows as CSR pointer and indices) and, in the relative layout, the estimated distances of its last ranking, the
        ranked candidates and whether each is held; with ``observe_heard``, what each robot heard. The env's own arrays: copy what is kept."""
        ptr, idx = frame_numba.neighbour_lists(self.adj)
        arrays = {
            "phase": self._phase,
            "weights": self._w,
            "weight_sum": self._wsum,
            "hop_masks": self._hop_masks,
            "adj": self.adj,
            "nbr_ptr": ptr[0],
            "nbr_idx": idx[0],
        }
        if self.heard is not None:
            arrays.update(heard=self.heard)
        if self._moving:
            # where the robots are, where they head and what each holds of the others' positions (the links, weights
            # and hop buckets above a moving world computes again at every frame's end, from the positions then)
            arrays.update(pos=self.pos, est=self.est)
            if self.cfg.scene == "field":
                arrays.update(waypoint=self.waypoint)
        if self.cfg.layout == "relative":  # the absolute layout ranks no candidates
            arrays.update(dist=self._dist, candidates=self._candidates, ranked_known=self._ranked_known)
        return arrays

    def world_counters(self) -> dict:
        """Whether every estimate has arrived (first arrivals are no longer tracked), the time averages (frames,
        summed mean age and weighted mean age, per hop bucket the largest age and the summed mean age) and the
        last frame's bits per robot."""
        return {
            "all_known": self._all_known,
            "frames": self._frames,
            "sum_age": self._sum_age,
            "sum_wage": self._sum_wage,
            "max_age": self._max_age,
            "sum_age_hop": self._sum_age_hop,
            "step_bits": self._step_bits,
        }

    def load_world_counters(self, counters: dict, ranking: tuple | None = None) -> None:
        """Take over the :meth:`world_counters` (and, in the relative layout, ``ranking`` = the ranked candidates,
        whether each is held, the estimated distances) of an episode a copy-axis world stepped, as if this env had:
        what it observes and reports is computed from the state written here. The caller writes the stamps, the
        clock, the ledger and the step count."""
        n = self.n_agents
        if ranking is not None:
            candidates, ranked_known, dist = ranking
            self._candidates = candidates.astype(np.int64)
            self._cand_flat = (self._candidates + np.arange(n)[:, None] * n).ravel()
            self._ranked_known, self._dist = ranked_known, dist
        self._take_counters(counters)
        self._state_version += 1
        # observe and report from the state just written (an env that steps alone later takes it into its own world
        # of one copy: its arrays are no longer that world's rows)
        self._world_obs = self._world_infos = None

    def load_world_motion(self, pos: np.ndarray, est: np.ndarray, waypoint: np.ndarray | None = None) -> None:
        """Take over where a copy-axis world moved the robots of an episode it stepped (``pos``; in the field, their
        ``waypoint``) and the positions their estimates carry (``est``): the links, eq. (1)'s weights and the hop
        buckets follow from them, as at the end of the env's own frame."""
        self.pos, self.est = pos, est
        if waypoint is not None:
            self.waypoint = waypoint
        self._links()
        self._reward_weights()
        self._hops()

    def _take_counters(self, counters: dict) -> None:
        """:meth:`world_counters` written back, as a copy-axis world hands them over (its ``counters``)."""
        self._all_known = bool(counters["all_known"])
        self._ages = None  # the world keeps no ages: ages() computes them from the stamps and the clock
        self._frames = int(counters["frames"])
        self._sum_age, self._sum_wage = float(counters["sum_age"]), float(counters["sum_wage"])
        self._max_age, self._sum_age_hop = counters["max_age"], counters["sum_age_hop"]
        self._step_bits = counters["step_bits"]

    # ----------------------------------------------------------------- the world of one copy
    #: the env's arrays that are rows of its world of one copy (views), as :meth:`_bind_one_copy` binds them (and
    #: ``heard`` with ``observe_heard``)
    _WORLD_VIEWS = ("stamps", "first_known", "sent_stamp", "last_sent", "_ranked_known", "_candidates", "heard")
    #: … and of robots that move: the env's arrays of the motion, the links and what follows from them (the world's
    #: ``pos``, ``est``, ``adj``, ``dist`` and ``weights``; in the field, ``waypoint`` too)
    _MOVING_VIEWS = ("pos", "est", "adj", "_dist", "_w")

    def _bind_one_copy(self) -> None:
        """Take this episode's state into the one-copy world, whose rows then are this env's arrays (views): what
        the world steps, every reader of the env sees."""
        world = self._one_copy
        world.adopt(0)
        views = (world.stamps, world.first_known, world.sent_stamp, world.last_sent, world.ranked_known)
        heard = world.heard[0] if world.heard is not None else None
        rows = [view[0] for view in (*views, world.candidates)] + [heard]
        names = list(self._WORLD_VIEWS)
        if self._moving:
            rows += [view[0] for view in (world.pos, world.est, world.adj, world.dist, world.weights)]
            names += self._MOVING_VIEWS
            if world.waypoint is not None:
                rows.append(world.waypoint[0])
                names.append("waypoint")
        self._world_views, self._view_names = tuple(rows), tuple(names)
        for name, view in zip(self._view_names, self._world_views, strict=True):
            setattr(self, name, view)

    def ages(self) -> np.ndarray:
        """(n, n) age (s) of every robot's estimate of every robot at the last frame end (unknown: the time since
        the start; 0 before the first frame)."""
        if self._ages is not None:
            return self._ages
        return np.where(self.stamps > proto.UNKNOWN, self.t - self.stamps, self.t)

    def __getstate__(self):
        state = super().__getstate__()
        state["_one_copy"] = None  # the env's arrays are views of its rows: a copy rebuilds it at its next step
        return state

    def observation_layout(self) -> dict[str, int] | None:
        if not self._relative:
            return None
        # choose: the env sends at most m − 1 selected candidates besides the robot's own estimate
        return {
            "candidates": self.n_agents - 1,
            "features": self._features,
            "globals": 3,
            "extra_actions": 0,
            "choose": self.m - 1,
        }

    def _rank_candidates(self) -> None:
        """Each robot's others, nearest estimated first; estimates it lacks last, by slot order after its own
        (:func:`.protocol.ranked_candidates`)."""
        n = self.n_agents
        known = self.stamps > proto.UNKNOWN
        if not self._moving:
            # a static topology: the estimates are the true positions all episode (nobody moves), so the ranking
            # changes only with what each robot holds, and not at all once everyone holds everything
            if self._ranked_known is not None and np.array_equal(known, self._ranked_known):
                return
            self._ranked_known = known
        self._dist = self.estimated_distances()  # reused by this frame's observation
        self._candidates = proto.ranked_candidates(known, self._dist, self.diag, self._phase)
        #: flat (robot, candidate) indices into an (N·N,) array: one gather per feature block
        self._cand_flat = (self._candidates + np.arange(n)[:, None] * n).ravel()

    @staticmethod
    def _control_steps(duration: float) -> int:
        """The coverage controller's Euler steps over ``duration`` seconds: at most ``CONTROL_PERIOD`` each, so that slow
        frames are integrated as finely as fast ones, and at most ``MAX_CONTROL_STEPS`` (a very slow channel takes
        longer steps)."""
        return min(max(1, math.ceil(duration / CONTROL_PERIOD - 1e-9)), MAX_CONTROL_STEPS)

    def neighbour_lack(self) -> np.ndarray:
        """(n, n) ``observe_heard``'s feature (:func:`.protocol.neighbour_lack`): for robot i and estimate j, the mean
        over i's neighbours k ≠ j of the freshness they lack of i's estimate, as far as what i heard tells."""
        if self.heard is None:
            raise ValueError("neighbour_lack() needs the env built with observe_heard=True")
        return proto.neighbour_lack(self.stamps, self.heard, self.adj, self.frame_dur)

    # ----------------------------------------------------------------- views
    def estimated_distances(self) -> np.ndarray:
        """(n, n) distance from each robot's own position to its estimate of each other robot."""
        return proto.estimated_distances(self.est, self.pos)

    def _local_view(self) -> dict:
        return {
            "stamps": self.stamps,
            "estimated_distances": self.estimated_distances(),
            "sent_stamp": self.sent_stamp,
            "slot": self.tdma.slot_of,
            "slot_size": np.full(self.n_agents, self.m),
            "candidates": self._candidates.astype(np.int64, copy=False)
            if self._relative
            else np.zeros((self.n_agents, 0), dtype=np.int64),
            "heard": np.zeros((self.n_agents, 0, self.n_agents)) if self.heard is None else self.heard,
            "action_mask": self._held_candidates()
            if self.cfg.mask_unheld
            else np.ones((self.n_agents, self.n_agents - 1 if self._relative else 0), dtype=bool),
        }

    def _observe(self) -> np.ndarray:
        if self._world_obs is not None:
            return self._world_obs.copy()  # the world's buffer: rewritten at its next frame
        n = self.n_agents
        known = self.stamps > proto.UNKNOWN
        age = np.where(known, self.t - self.stamps, 0.0)
        age_n = np.where(known, age / (age + self.frame_dur), 1.0)
        dist = self._dist if self._relative else self.estimated_distances()
        dist_n = np.where(known, np.minimum(dist / self.diag, 1.0), 1.0)
        slot = self.tdma.slot_of
        if not self._relative:
            extra = np.column_stack([slot / n, np.full(n, self.m / n)])
            return np.concatenate([age_n, dist_n, self._phase, extra], axis=1).astype(np.float32)
        # freshness gained since this robot last broadcast each estimate: what resending it would add
        gain = np.where(known, np.maximum(self.stamps - self.sent_stamp, 0.0), 0.0)
        gain_n = gain / (gain + self.frame_dur)
        features = [known, dist_n, age_n, gain_n, self._phase]
        if self.heard is not None:
            features.append(self.neighbour_lack())
        out = np.empty((n, self._features * (n - 1) + 3), dtype=np.float32)
        ranked = out[:, : self._features * (n - 1)].reshape(n, n - 1, self._features)
        flat = self._cand_flat
        for k, feature in enumerate(features):
            ranked[:, :, k] = feature.reshape(-1)[flat].reshape(n, n - 1)
        out[:, -3] = slot / n
        out[:, -2] = self.m / n
        out[:, -1] = (known & self._others).sum(axis=1) / (n - 1)
        return out

    def _agent_infos(self) -> dict:
        if self._world_infos is not None:
            return self._world_infos
        n = self.n_agents
        off = ~self._eye
        infos = {
            "bits_sent": self._step_bits,
            "mean_age": (self.ages() * off).sum(axis=1) / (n - 1),
            "known_fraction": ((self.stamps > proto.UNKNOWN) & off).sum(axis=1) / (n - 1),
            "slot": self.tdma.slot_of,
        }
        if self.cfg.mask_unheld:
            held = self._held_candidates()
            infos.update((key, held[:, k]) for k, key in enumerate(self._mask_keys))
        return infos

    def action_label(self, action) -> str:
        """How many estimates the robot selects: its set select bits (relative layout: the base class's count), or its
        priorities above 0, since 0 withholds (absolute layout). The slot sends at most ``slot_size − 1`` of them,
        those the robot holds."""
        if self._relative:
            return super().action_label(action)
        return f"{int(np.count_nonzero(np.asarray(action) > 0.0))} selected"

    def action_measures(self, agent: str, action) -> dict[str, np.ndarray]:
        """Per estimate the robot selects and holds (those its slot may relay, up to ``slot_size − 1``): its age in
        seconds, and whether no neighbour in reach lacks it, from the robots' true tables (each neighbour k ≠ j
        already holds robot j's estimate at least as fresh). These are what the age-of-information rules of §IV
        trade: old estimates cost weighted age (eq. 1), and an estimate every neighbour holds spends bits on
        nothing."""
        i = self._index_of(agent)
        action = np.asarray(action)
        if self._relative:
            chosen = self._candidates[i][action > 0.5]
        else:
            chosen = np.flatnonzero(action > 0.0)
            chosen = chosen[chosen != i]  # a robot's own estimate is always sent
        own = self.stamps[i, chosen]
        held = own > proto.UNKNOWN
        chosen, own = chosen[held], own[held]
        neighbours = np.flatnonzero(self.adj[i])
        theirs = self.stamps[neighbours[:, None], chosen[None, :]]  # (neighbours, chosen)
        judged = neighbours[:, None] != chosen[None, :]  # a neighbour's own estimate is always current
        lacks = ((theirs < own[None, :]) & judged).any(axis=0)
        return {"age of a selected estimate (s)": self.t - own, "selected estimates no neighbour lacks": ~lacks}

    def _held_candidates(self) -> np.ndarray:
        """(N, N − 1) bool: whether robot i holds an estimate of its candidate at rank k (the observation's first
        feature of that candidate): with ``mask_unheld``, the select bits it may set (``action_masks()``)."""
        known = self.stamps > proto.UNKNOWN
        return np.take_along_axis(known, self._candidates.astype(np.int64, copy=False), axis=1)

    def propagation_times(self) -> dict[int, float]:
        """Cold-start propagation time (s) of each centred subgraph; nan while incomplete or not fitting."""
        out = {}
        for k in SUBGRAPHS:
            blk = self._blocks.get(k)
            if blk is None or blk.size == 0:
                out[k] = math.nan
                continue
            v = float(self.first_known[np.ix_(blk, blk)].max())
            out[k] = v if math.isfinite(v) else math.nan
        return out

    def coverage_cost(self) -> float:
        if self.cfg.scene == "grid":
            return math.nan
        return theory.coverage_cost(self.pos, self._cost_points)

    def _metrics(self) -> dict[str, float]:
        f = max(self._frames, 1)
        out = {f"propagation_time_{k}x{k}": v for k, v in self.propagation_times().items()}
        out["mean_age"] = self._sum_age / f
        out["weighted_mean_age"] = self._sum_wage / f
        for h, v in zip(HOP_BUCKETS, self._sum_age_hop, strict=True):
            out[f"mean_age_hop{h}"] = float(v) / f
        for h, v in zip(HOP_BUCKETS, self._max_age, strict=True):
            out[f"max_age_hop{h}"] = float(v)
        out["frame_rate"] = theory.frame_rate(self.m, self.n_agents, self.cfg.bits_per_estimate, self.cfg.baud)
        out["coverage_cost"] = self.coverage_cost()
        n = self.n_agents
        out["known_fraction"] = float(((self.stamps > proto.UNKNOWN) & ~self._eye).sum() / (n * (n - 1)))
        out["bits_sent"] = float(self.ledger.total_bits.sum())
        return out

    def _render(self, ax) -> None:
        p = self.pos
        ii, jj = np.nonzero(np.triu(self.adj))
        ax.add_collection(LineCollection(np.stack([p[ii], p[jj]], axis=1), colors="0.8", linewidths=0.6, zorder=1))
        # a slot's broadcast crosses every link of its sender: the bits over a link are both ends' broadcasts
        sent = self.ledger.step_bits
        rendering.draw_link_bits(ax, p, np.column_stack([ii, jj]), sent[ii] + sent[jj])
        age = (self.ages() * ~self._eye).sum(axis=1) / max(self.n_agents - 1, 1)
        # one colour scale for the whole episode (it used to follow each frame's own range): from one frame to
        # the horizon, on a log axis, since ages span both ends of it over a cold start
        norm = LogNorm(vmin=self.frame_dur, vmax=self.frame_dur * max(self.cfg.max_cycles, 2), clip=True)
        sc = ax.scatter(p[:, 0], p[:, 1], c=np.maximum(age, self.frame_dur), cmap="viridis", norm=norm, s=30, zorder=2)
        ax.figure.colorbar(sc, ax=ax, label="mean age of held estimates (s, log scale)")
        ax.set_xlim(-0.05 * self.side - 0.5, 1.05 * self.side + 0.5)
        ax.set_ylim(-0.05 * self.side - 0.5, 1.05 * self.side + 0.5)
        ax.set_aspect("equal")
        ax.set_title(f"{self.cfg.scene}: m={self.m}, frame {self.step_count}, t={self.t:.1f} s")
