"""MapSync-v0: keeping occupancy maps in agreement over a narrow channel (Alsayegh et al., paper 002).

| | |
| --- | --- |
| Agents | `n_robots` robots `robot_0 … robot_{N-1}` (2 by default: Alice and Bob) |
| Actions | `Discrete(5)` per robot: 0 idle, 1 `equality` (Protocol 1), 2 `bisection` (Algorithm 1), 3 `full`, 4 `sketch` |
| Observations | `Box(0, 1, (4(N−1) + 5,))`: per peer (in the order i+1, i+2, … mod N) steps since our maps were last made equal `s/(s+10)`, cells whose bit my own sensing changed since then `c/(c+10)`, link up now, result of the last test (0 none, ½ same, 1 different); then my recent bits `b/(b+n)` (EWMA), my map coverage, busy, progress of my session, `t / max_cycles` |
| Reward | team reward `−(mean normalised Hamming disagreement over pairs) − lam · (team bits this step) / (n · N)` |
| Arguments | `preset`, `grid_size`, `n_obstacles`, `n_robots`, `k`, `res`, `bits_per_step`, `appear_rate`, `vanish_rate`, `lam`, `max_cycles`, `comm_range`, `link_prob`, `database_seed`, `explicit_database` |

**World** (§III, §V-C). A `grid_size²` 4-connected grid; robots random-walk and, on entering a cell, sense it
and its 4-neighbours. Each map is a bit vector of n = `grid_size²` cells (1 = obstacle, 0 = free or unknown).
Preset `paper` is Fig. 7: obstacles at (12,15), (6,13), (6,9), (3,15), (12,3), (12,13), (5,5), (13,7), (14,1),
(6,5), Alice (`robot_0`) at (11,7), Bob (`robot_1`) at (3,7), 200 steps, k = 10.

**Changing world and the merge rule.** Obstacles appear on free unoccupied cells at `appear_rate` and vanish
at `vanish_rate` per cell and step. Every robot stamps each cell with the step it last observed it. A sync
merges *last-writer-wins*: for each cell found to differ, the value with the newer stamp wins, so two maps
that sync agree on every reconciled cell, and gossip converges to each cell's latest observation (a
join-semilattice: commutative, associative, idempotent). The stamps of the differing cells are sent both
ways, ⌈log2(max_cycles + 2)⌉ bits each, and counted. When nothing vanishes (`vanish_rate = 0`, the paper) a 1
is never stale, so the rule reduces to OR and no stamp is sent.

**Syncs.** A robot's action asks for a sync with the linked peer it synced with least recently; a sync needs
a link (core link models: always in range by default, `comm_range` for disk links, `link_prob` for random
drops). The requester is Alice; if both ends ask, one sync runs, with the lower index as Alice and her
protocol. Alice runs the protocol as client (:mod:`protocol`); for `bisection`, `full` and `sketch` Bob then
tells her which cells differ (an enumerative code, :func:`protocol.return_bits`) and the merge applies to
both. The protocol computes on the maps as they were when the sync started; its result is merged into the
maps when its last bit arrives. A link carries at most `bits_per_step` bits per step (both directions), so a
long protocol spans several steps; its latency is counted, and a sync whose link breaks is aborted (bits
spent, nothing merged). A robot in a sync cannot start another. Round trips are taken to be short against a
step. Bits are charged to the robot that sends them (`core.BitLedger`).

**Reward scale.** `lam` is the price of n bits per robot: a step in which the team sends one map's worth of
bits per robot costs `lam`, the same as disagreeing on every cell. The per-step reward lies in
[−1 − lam · bits/(nN), 0] and is O(1) for any protocol mix.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from gymnasium import spaces

from mrcomm_env.core import BitLedger, MrcommParallelEnv
from mrcomm_env.core import render as rendering
from mrcomm_env.mapsync import kernels_numba, world
from mrcomm_env.mapsync.actions import ACTIONS, BISECTION, EQUALITY, FULL, IDLE, SKETCH  # noqa: F401 (the module API)
from mrcomm_env.mapsync.copy_axis import UnlimitedLinkBatch
from mrcomm_env.mapsync.dynamics import WorldDynamics
from mrcomm_env.mapsync.philox import SharedStrings
from mrcomm_env.mapsync.sessions import (  # noqa: F401 — the action and test codes are part of this module's API
    DETECTIONS_KEPT,
    TEST_DIFFERENT,
    TEST_NONE,
    TEST_SAME,
    Session,
    SyncSessions,
)
from mrcomm_env.mapsync.spec import MapSyncSpec


class MapSyncEnv(MapSyncSpec, WorldDynamics, SyncSessions, MrcommParallelEnv):
    ENV_ID = "mrcomm/MapSync-v0"
    DESCRIPTION = (
        "When and how robots reconcile occupancy maps over a narrow channel (equality test, bisection, sketch)"
    )
    metadata = {"name": "mapsync_v0", "render_modes": ["rgb_array", "human"], "render_fps": 10}

    @classmethod
    def copy_axis_world(cls, cfg):
        """Links that carry any transcript within a step (no ``bits_per_step``) and are always up (no ``comm_range``,
        ``link_prob`` 1) step M copies as one batch of arrays (:mod:`.copy_axis`): the default and the shipped
        training configuration. Other configurations step their copies in turn."""
        if cfg.bits_per_step is not None or cfg.comm_range is not None or cfg.link_prob < 1.0:
            return None
        return UnlimitedLinkBatch

    # ----------------------------------------------------------------- setup
    def _setup(self) -> None:
        c = self.cfg
        self.size = c.grid_size
        self.n = c.grid_size**2
        if c.n_obstacles > self.n - 1:
            raise ValueError(
                f"argument 'n_obstacles' must be at most grid_size² − 1 = {self.n - 1} (a free cell is needed), "
                f"got {c.n_obstacles}"
            )
        if c.preset == "paper":
            wrong = {
                "grid_size": (c.grid_size, world.PAPER_GRID),
                "n_robots": (c.n_robots, 2),
                "n_obstacles": (c.n_obstacles, len(world.PAPER_OBSTACLES)),
            }
            for arg, (got, need) in wrong.items():
                if got != need:
                    raise ValueError(
                        f"argument 'preset' = 'paper' is Fig. 7's layout and needs '{arg}' = {need}, got {got}"
                    )
        if c.explicit_database and 100 * self.n * self.n > 100 * 1024 * 1024:
            raise ValueError(f"argument 'explicit_database' needs n ≤ 1024 (grid_size ≤ 32), got n = {self.n}")
        self.n_agents = c.n_robots
        N = self.n_agents
        table = world.neighbour_table(self.size)
        self._neighbour_table = table
        self._no_keys = np.zeros((0, 4))  # the walk's keys when the robots only sense (reset)
        self._sensed, self._sensed_distinct = world.sensing_table(table)
        self._static_links = c.comm_range is None and c.link_prob >= 1.0
        self._stamp_bits = max(1, math.ceil(math.log2(c.max_cycles + 2)))  # steps 0 … max_cycles and "never"
        self._lww = c.vanish_rate > 0.0
        self._obs_space = spaces.Box(0.0, 1.0, shape=(4 * (N - 1) + 5,), dtype=np.float32)
        self._act_space = spaces.Discrete(len(ACTIONS))
        self._peer_order = np.array([[(i + o) % N for o in range(1, N)] for i in range(N)], dtype=np.int64)
        self._peer_lists = self._peer_order.tolist()
        # the protocols' arguments, read once per sync
        self._k, self._res, self._cap = c.k, c.res, c.bits_per_step
        self._eye = np.eye(N, dtype=bool)
        self._pairs = np.triu_indices(N, 1)
        self._horizon = c.max_cycles
        self._bit_scale = self.n * N  # the reward prices team bits in units of n bits per robot (Reward scale)
        self._changing = c.appear_rate > 0.0 or c.vanish_rate > 0.0
        self._obs_buf = np.zeros((N, 4 * (N - 1) + 5), dtype=np.float32)  # written in place by _observe
        self.ledger = BitLedger(N)

    # ----------------------------------------------------------------- episode
    def _reset_world(self) -> None:
        c, rng, n, N = self.cfg, self.np_random, self.n, self.n_agents
        truth = np.zeros(n, dtype=bool)
        if c.preset == "paper":
            truth[[world.cell_of(x, y, self.size) for x, y in world.PAPER_OBSTACLES]] = True
            self.pos = np.array([world.cell_of(x, y, self.size) for x, y in world.PAPER_STARTS], dtype=np.int64)
        else:
            truth[rng.choice(n, size=c.n_obstacles, replace=False)] = True
            free = np.flatnonzero(~truth)
            self.pos = rng.choice(free, size=N, replace=free.size < N).astype(np.int64)
        self.truth = truth
        self.maps = np.zeros((N, n), dtype=bool)
        # int64: a stamp is a step number, up to max_cycles ≤ 2^53 (int32 would wrap to negative stamps at step
        # 2^31, read as "never observed")
        self.stamps = np.full((N, n), -1, dtype=np.int64)
        self.last_sync = np.zeros((N, N), dtype=np.int64)  # step at which each pair's maps were last made equal
        self.new_cells = np.zeros((N, N), dtype=np.int64)
        self.last_test = np.full((N, N), TEST_NONE, dtype=np.int64)
        self.linked = ~self._eye
        self.session_of = np.full(N, -1, dtype=np.int64)
        self.sessions: dict[int, Session] = {}
        self._next_session = 0
        # R is given to the robots before deployment (Protocol 1, step 1): the same for every episode
        self.strings = SharedStrings(n, c.database_seed, explicit=c.explicit_database, cache=True)
        self.sketch_seed = int(rng.integers(2**63))
        self.ledger.reset()
        self.recent_bits = np.zeros(N)
        self._recent_any = False
        self._recent_max = 0.0  # recent_bits.max(), kept as a float
        self._charged = False  # any bits charged in the current step (ledger.step_bits nonzero)
        self.robot_syncs = np.zeros(N, dtype=np.int64)
        self._no_bits = np.zeros(N)  # the infos' bits column of a step without bits
        self._steps = 0
        self._sum_disagreement = 0.0
        self._sum_error = 0.0
        self._counts = dict.fromkeys(("syncs", "false_equal", "equality_tests", "detections", "aborted_syncs"), 0)
        self._corrected = 0
        self._to_correct = 0
        # sync latencies as a running sum and count (a list of every one would grow with the episode)
        self._latency_sum = 0
        self._latency_count = 0
        #: (step, alice, bob, protocol) of the equality tests that found a difference (Fig. 7's list), the most recent
        #: DETECTIONS_KEPT of them
        self.detections: deque[tuple[int, int, int, str]] = deque(maxlen=DETECTIONS_KEPT)
        self.known = np.zeros(N, dtype=np.int64)
        self._events = 0  # counts changes of anything the infos show (they are made anew only then)
        self._map_version = 0
        self._infos_key = None
        self._infos_charged = False  # the cached infos show bits sent
        self._dirty = True
        self._no_progress = np.zeros(N)
        self._move_and_sense(0, walk=False)
        self._update_disagreement()

    # ----------------------------------------------------------------- what its copy-axis world reads and writes
    def world_constants(self) -> dict:
        """Constants of one configuration that its copy-axis world (:mod:`.copy_axis`) computes with: whether the
        world changes and merges by last writer, the reward's bit scale, the horizon, the sensing tables, the robot
        pairs, the link mask's diagonal, the stamp width, each robot's peers in order, the observation's shape."""
        return {
            "changing": self._changing,
            "lww": self._lww,
            "bit_scale": self._bit_scale,
            "horizon": self._horizon,
            "neighbour_table": self._neighbour_table,
            "sensed": self._sensed,
            "sensed_distinct": self._sensed_distinct,
            "pairs": self._pairs,
            "eye": self._eye,
            "stamp_bits": self._stamp_bits,
            "peer_order": self._peer_order,
            "obs_shape": self._obs_buf.shape,
        }

    def world_counters(self) -> dict:
        """The episode's counters and running statistics as they stand (the disagreement brought up to date
        first): the metric counts, cells corrected and to correct, the sync latency's sum and count, the recent
        bits' maximum and whether any, the disagreement column and mean, the errors and their mean, the episode's
        summed disagreement and error, and the next session's number."""
        self._update_disagreement()  # a state changed from outside may await its disagreement
        return {
            "counts": dict(self._counts),
            "corrected": self._corrected,
            "to_correct": self._to_correct,
            "latency_sum": self._latency_sum,
            "latency_count": self._latency_count,
            "recent_max": self._recent_max,
            "recent_any": self._recent_any,
            "disagreement_column": self._disagreement_column,
            "disagreement_mean": self._disagreement_mean,
            "errors": self._errors,
            "error_mean": self._error_mean,
            "sum_disagreement": self._sum_disagreement,
            "sum_error": self._sum_error,
            "next_session": self._next_session,
        }

    def load_world_counters(self, counters: dict) -> None:
        """Take over :meth:`world_counters` of an episode a copy-axis world stepped, as if this env had stepped it.
        The caller has written the maps, stamps, world, positions, sync records, ledger, recent bits, step count
        and generator; the observation and infos are made anew from that state."""
        self._charged = bool(self.ledger.step_bits.any())
        self._counts = dict(counters["counts"])
        self._corrected, self._to_correct = int(counters["corrected"]), int(counters["to_correct"])
        self._latency_sum, self._latency_count = int(counters["latency_sum"]), int(counters["latency_count"])
        self._recent_max, self._recent_any = float(counters["recent_max"]), bool(counters["recent_any"])
        self._dirty = False
        self._disagreement_column = counters["disagreement_column"]
        self._disagreement_mean = float(counters["disagreement_mean"])
        self._errors, self._error_mean = counters["errors"], float(counters["error_mean"])
        self._sum_disagreement, self._sum_error = float(counters["sum_disagreement"]), float(counters["sum_error"])
        self._steps = self.step_count
        self._next_session = int(counters["next_session"])
        self._state_version += 1
        self._events += 1
        self._infos_key = None

    # ----------------------------------------------------------------- dynamics
    def _step_world(self, actions: list) -> float:
        t = self.step_count
        if self._charged:  # the ledger's step bits are already zero otherwise
            self.ledger.begin_step()
            self._charged = False
        if not self._static_links:
            self._links()
        if self._cap is None:  # a link carries any transcript within the step: no sync outlives its step
            if any(actions):
                self._sync_within_step(actions, t)
        else:
            if any(actions):
                self._start_sessions(actions, t)
            if self.sessions:
                self._progress_sessions(t)
        if self._changing and self._change_world():
            self._dirty = True
        self._move_and_sense(t + 1, walk=True)
        self._update_disagreement()
        team_bits = 0.0
        if self._charged or self._recent_any:
            recent = self.recent_bits
            recent *= 0.9  # in place: the same roundings as 0.9 · recent + 0.1 · bits (+ 0.1 · 0 changes nothing)
            if self._charged:
                bits = self.ledger.step_bits
                team_bits = float(bits.sum())  # whole numbers of bits: exact in any summation order
                recent += 0.1 * bits
                self._recent_max = float(recent.max())
            else:  # rounding is monotone, so the largest of the products is the product of the largest
                self._recent_max *= 0.9
            self._recent_any = self._recent_max > 1e-6 * self.n
            if not self._recent_any:
                recent[:] = 0.0
                self._recent_max = 0.0
                self._events += 1
        self._steps += 1
        self._sum_disagreement += self._disagreement_mean
        self._sum_error += self._error_mean
        return -self._disagreement_mean - self.cfg.lam * team_bits / self._bit_scale

    def steps_since(self) -> np.ndarray:
        """(N, N) steps since each pair's maps were last made equal (own entry 0)."""
        out = self.step_count - self.last_sync
        np.fill_diagonal(out, 0)
        return out

    def _local_view(self) -> dict:
        ys, xs = np.divmod(self.pos, self.size)
        return {
            "map": self.maps,
            "stamps": self.stamps,
            "position": np.column_stack([xs, ys]),
            "steps_since_sync": self.steps_since(),
            "new_cells": self.new_cells,
            "last_test": self.last_test,
            "linked": self.linked,
            "busy": (self.session_of >= 0).astype(np.int64),
        }

    def _observe(self) -> np.ndarray:
        """Every column of the module's table in one compiled call (``kernels_numba.observe``; its numpy oracle is
        ``tests/helpers/mapsync_reference.py``)."""
        t = self.step_count
        progress = self._no_progress
        if self.sessions:
            progress = np.zeros(self.n_agents)
            for s in self.sessions.values():
                progress[[s.alice, s.bob]] = s.sent / max(s.total, 1)
        kernels_numba.observe(
            self._obs_buf,
            t,
            min(t / self._horizon, 1.0),
            self.last_sync,
            self.new_cells,
            self.linked,
            self.last_test,
            self.session_of,
            progress,
            self.recent_bits,
            self.known,
            self.n,
        )
        return self._obs_buf.copy()

    def _agent_infos(self) -> dict:
        key = (self._events, self._map_version)
        if key == self._infos_key and not self._charged and not self._infos_charged:
            return self._infos_cache  # nothing the infos show has changed since the last call
        self._infos_key = key
        self._infos_charged = self._charged
        self._infos_cache = {
            "bits_sent": self.ledger.step_bits.copy() if self._charged else self._no_bits,
            "disagreement": self._disagreement_column,
            "error_vs_truth": self._errors,
            "coverage": self.known / self.n,
            # both change only when _events does (a sync opens or closes), which makes these infos anew
            "busy": (self.session_of >= 0).astype(np.float64),
            "syncs": self.robot_syncs.copy(),
        }
        return self._infos_cache

    def action_label(self, action) -> str:
        """Idle, or the sync protocol the robot opens (``actions.ACTIONS``)."""
        return ACTIONS[int(action)]

    def decision_context(self) -> list[str]:
        """Whose sensing has changed cells since a robot's map was last made equal to a linked peer's: the news a
        sync would carry. Split by it, a policy's actions show whether it syncs on a clock or on news."""
        peers = self.linked & ~self._eye
        news = self.new_cells > 0  # [i, j]: i's own sensing changed cells since i and j were last made equal
        own, theirs = (news & peers).any(axis=1), (news.T & peers).any(axis=1)
        context = np.where(own, "own sensing changed cells", np.where(theirs, "only a peer's did", "no news"))
        return np.where(peers.any(axis=1), context, "no link").tolist()

    def _metrics(self) -> dict[str, float]:
        steps = max(self._steps, 1)
        out = {
            "disagreement": self._sum_disagreement / steps if self._steps else self._disagreement_mean,
            "error_vs_truth": self._sum_error / steps if self._steps else float(self._errors.mean()),
            "bits_sent": float(self.ledger.total_bits.sum()),
        }
        out.update({k: float(v) for k, v in self._counts.items()})
        out["corrected_fraction"] = self._corrected / self._to_correct if self._to_correct else math.nan
        # whole numbers: the sum is exact, and the quotient is the mean np.mean gave of the list once kept
        out["sync_latency_steps"] = self._latency_sum / self._latency_count if self._latency_count else math.nan
        out["coverage"] = float(self.known.mean() / self.n)
        return out

    def _render(self, ax) -> None:
        size = self.size
        img = np.ones((size, size, 3))
        img[self.truth.reshape(size, size)] = (0.15, 0.15, 0.15)
        differ = self.maps.any(axis=0) & ~self.maps.all(axis=0)
        img[differ.reshape(size, size) & ~self.truth.reshape(size, size)] = (1.0, 0.75, 0.75)
        img[(differ & self.truth).reshape(size, size)] = (0.75, 0.1, 0.1)
        ax.imshow(img, origin="lower", extent=(-0.5, size - 0.5, -0.5, size - 0.5))
        ys, xs = np.divmod(self.pos, size)
        colors = [f"C{i % 10}" for i in range(self.n_agents)]
        ax.scatter(xs, ys, c=colors, s=60, zorder=3, edgecolors="k")
        for s in self.sessions.values():
            ax.plot([xs[s.alice], xs[s.bob]], [ys[s.alice], ys[s.bob]], "--", color="0.5", zorder=2)
        # a robot syncs with one peer at a time (it is busy meanwhile): its bits this step crossed that link
        pairs = np.array([(s.alice, s.bob) for s in self.sessions.values()], dtype=np.int64).reshape(-1, 2)
        sent = self.ledger.step_bits
        rendering.draw_link_bits(ax, np.column_stack([xs, ys]), pairs, sent[pairs[:, 0]] + sent[pairs[:, 1]])
        ax.set_xlim(-0.5, size - 0.5)
        ax.set_ylim(-0.5, size - 0.5)
        ax.set_aspect("equal")
        ax.set_title(
            f"step {self.step_count}: disagreement {self._disagreement_mean:.3f} (red: cells on which maps differ)"
        )
