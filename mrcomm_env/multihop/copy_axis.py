"""M copies of a MultiHop scene stepped as arrays with a leading copy axis (the copy-axis world).

What :class:`~mrcomm_env.core.batched.BatchedEnv` steps instead of M env objects
(:meth:`MultiHopEnv.copy_axis_world`): the grid or a still field (:class:`StaticFrameBatch`), or robots that move,
in a field or under the coverage controller (:class:`MovingBatch`), in either layout, with either reward and, on
static links, with or without ``observe_heard``. The frame is one
compiled call over every copy (``frame_numba.send_frame``); here everything around it is too: the frame's
lists (the ``relative`` layout's select bits, :func:`~.frame_numba.selected_ranks`; the ``absolute`` layout's
priorities, :func:`~.frame_numba.priority_ranks`), the ages, the eq. (1)-weighted age and the per-hop
statistics of the frame's end, the candidates' ranking and the observation
(:func:`~.frame_numba.observe_candidates`, :func:`~.frame_numba.observe_indices`). The ``neighbourhood`` reward and
what each robot heard (``observe_heard``: its table and its sixth candidate feature) are the protocol's own functions
(:func:`~.protocol.neighbourhood_staleness`, :func:`~.protocol.hear`, :func:`~.protocol.neighbour_lack`), which the
env calls too, applied copy by copy. Every number is the env's, bit
for bit: elementwise work is the env's float64 operations in the same order, and every sum is numpy's pairwise sum
over the same elements in the same order, either :func:`~mrcomm_env.core.sums_numba.numpy_sum` on a copy's scratch
row or numpy's own row reduction of a C-ordered ``(M, K)`` array (which sums each row as numpy sums that row alone).
``tests/multihop/test_multihop_world.py`` compares
every copy with the frame written slot by slot in numpy over whole episodes (``ReferenceMultiHop``, under
``tests/helpers``). A single env steps as this world of one copy (``MultiHopEnv._step_world``): the batch's code at
M = 1; it is MultiHop's only implementation of the frame.

Each copy keeps its env object: its own ``reset_arrays`` lays out the episode from its own generator (slot order,
positions), :meth:`StaticFrameBatch.adopt` copies that start into the copy's rows and :meth:`StaticFrameBatch.store`
writes the rows back, for the metrics of an ended episode and for anything read from the env. A static scene draws
nothing during an episode, so nothing else needs the env objects; robots that move draw their waypoints from their
env's generator (:class:`MovingBatch`).
"""

from __future__ import annotations

import numpy as np

from mrcomm_env.core.base import MASK_INFO_PREFIX
from mrcomm_env.core.comm import disk_links
from mrcomm_env.multihop import coverage as cov
from mrcomm_env.multihop import frame_numba
from mrcomm_env.multihop import protocol as proto
from mrcomm_env.multihop.protocol import HOP_BUCKETS

N_HOP_BUCKETS = len(HOP_BUCKETS)
#: the coverage controller's copies at a time: as many as keep its largest temporary within this many bytes
CENTROID_CHUNK_BYTES = 1 << 20


class StaticFrameBatch:
    """M copies of one MultiHop configuration on static links as arrays (see the module docstring).

    :param envs: the M ``MultiHopEnv`` copies (same arguments, ``copy_axis_world`` allows them), each reset before
        :meth:`adopt` reads it. The world reads the env's constants from the first copy and imports nothing of the
        env module (which builds it).
    """

    def __init__(self, envs: list):
        first = envs[0]
        c, n = first.cfg, first.n_agents
        m = len(envs)
        self.envs, self.n_copies, self.n = envs, m, n
        self.slot_size, self.slot_dur, self.frame_dur = first.m, first.slot_dur, first.frame_dur
        self.diag, self.bits = first.diag, c.bits_per_estimate
        constants = first.world_constants()
        self.lam, self.capacity, self.age_unit = c.lam, constants["capacity"], constants["age_unit"]
        self.max_cycles = c.max_cycles
        self.n_cand = n - 1
        self.relative = c.layout == "relative"
        self.mask_unheld = c.mask_unheld
        self.act_shape = first.action_space(first.possible_agents[0]).shape
        # the hop buckets' flat pair indices, one after the other, and their bounds: a grid's links are the same in
        # every copy (one row for all), a static field's are each copy's own
        rows = 1 if c.scene == "grid" else m
        self.hop_flat = np.zeros((rows, n * (n - 1)), dtype=np.int32)
        self.hop_bounds = np.zeros((rows, N_HOP_BUCKETS + 1), dtype=np.int64)
        # the copies' state: the env's arrays of the same names with a copy axis
        pair = (m, n, n)
        self.stamps = np.empty(pair)
        self.first_known = np.empty(pair)
        self.sent_stamp = np.empty(pair)
        self.last_sent = np.zeros(pair, dtype=bool)
        self.t = np.zeros(m)
        self.tracking = np.zeros(m, dtype=bool)  # not yet ``_all_known``: first arrivals are still recorded
        self.order = np.zeros((m, n), dtype=np.int64)
        self.slot = np.zeros((m, n), dtype=np.int64)
        self.phase = np.empty(pair)
        self.dist = np.empty(pair)
        self.weights = np.empty(pair)
        self.weight_sum = np.zeros(m)
        self.nbr_ptr = np.zeros((m, n + 1), dtype=np.int64)
        self.nbr_idx = np.zeros((m, 0), dtype=np.int64)
        # robot indices (n ≤ 1024) as int16: a quarter of the env's int64 to stream through every frame
        self.candidates = np.zeros((m, n, self.n_cand), dtype=np.int16)
        self.ranked_known = np.zeros(pair, dtype=bool)
        self.near_order = np.zeros(pair, dtype=np.int16)  # each row's robots by the ranking key d̂/diag
        self.slot_order = np.zeros(pair, dtype=np.int16)  # … and by their slot phase after the row's robot
        # the env's time averages: frames, summed mean age, summed weighted mean age, then per hop bucket the
        # largest age and the summed mean age (frame_numba.close_frames)
        self.totals = np.zeros((m, 3 + 2 * N_HOP_BUCKETS))
        self.step_bits = np.zeros((m, n))
        self.total_bits = np.zeros((m, n))
        self.messages = np.zeros(m, dtype=np.int64)
        self.step_count = np.zeros(m, dtype=np.int64)
        # working arrays of a step
        self.rank = np.zeros(pair, dtype=np.int16)
        self.count = np.zeros((m, n), dtype=np.int64)
        self.sent = np.zeros((m, n))
        self.mean_age = np.zeros((m, n))
        self.known_fraction = np.zeros((m, n))
        self.wage = np.zeros(m)
        self.obs = np.zeros((m, n, constants["obs_dim"]), dtype=np.float32)
        self.features = constants["features"]  # per candidate (relative layout)
        # the neighbourhood reward and observe_heard read the links; observe_heard keeps what each robot heard
        self.neighbourhood = c.reward_mode == "neighbourhood"
        self.bit_unit = self.slot_size * self.bits
        self.adj = np.zeros(pair, dtype=bool)  # the env's links (core.comm: boolean)
        self.heard: np.ndarray | None = None
        if c.observe_heard:
            self.heard = np.empty((m, n, n, n))
            # the compiled observation's five features per candidate, before the sixth joins them
            self.obs_five = np.zeros((m, n, (constants["features"] - 1) * self.n_cand + 3), dtype=np.float32)

    # ------------------------------------------------------------------ copies in and out
    def adopt(self, i: int) -> None:
        """Copy ``i``'s env has just been reset (or changed from outside): take its state into the copy's rows."""
        self._adopt_arrays(i, self.envs[i].world_arrays())

    def _adopt_arrays(self, i: int, arrays: dict) -> None:
        """:meth:`adopt` with the env's :meth:`~MultiHopEnv.world_arrays` read."""
        env = self.envs[i]
        self.stamps[i] = env.stamps
        self.first_known[i] = env.first_known
        self.sent_stamp[i] = env.sent_stamp
        self.last_sent[i] = env.last_sent
        self.adopt_counters(i)
        self.order[i] = env.tdma.order
        self.slot[i] = env.tdma.slot_of
        self.phase[i] = arrays["phase"]
        # a static scene's estimates are the true positions: the distances hold all episode (the relative layout
        # keeps them from its last ranking; the absolute one computes them per observation)
        self.dist[i] = arrays["dist"] if self.relative else env.estimated_distances()
        self.weights[i] = arrays["weights"]
        self.weight_sum[i] = arrays["weight_sum"]
        self.adj[i] = arrays["adj"]
        if self.heard is not None:
            self.heard[i] = arrays["heard"]
        if self.hop_flat.shape[0] > 1 or i == 0:
            row = min(i, self.hop_flat.shape[0] - 1)
            buckets = [np.flatnonzero(mask.ravel()) for mask in arrays["hop_masks"]]
            np.cumsum([idx.size for idx in buckets], out=self.hop_bounds[row, 1:])
            self.hop_flat[row, : self.hop_bounds[row, -1]] = np.concatenate(buckets)
        ptr, idx = arrays["nbr_ptr"], arrays["nbr_idx"]
        if idx.size > self.nbr_idx.shape[1]:  # a field's copies have their own links: room for the most
            grown = np.zeros((self.n_copies, idx.size), dtype=np.int64)
            grown[:, : self.nbr_idx.shape[1]] = self.nbr_idx
            self.nbr_idx = grown
        self.nbr_ptr[i] = ptr
        self.nbr_idx[i, : idx.size] = idx
        if not self.relative:
            return
        self.candidates[i] = arrays["candidates"]
        self.ranked_known[i] = arrays["ranked_known"]
        # the two fixed orders whose merge is the ranking (frame_numba.rerank_candidates)
        self.near_order[i] = np.argsort(arrays["dist"] / env.diag, axis=1, kind="stable")
        self.slot_order[i] = np.argsort(2.0 + arrays["phase"], axis=1, kind="stable")

    def adopt_counters(self, i: int) -> None:
        """Take copy ``i``'s clock, first-arrival flag, time averages, bits and step count from its env (what
        :meth:`adopt` takes besides the arrays; the env's world of one copy takes them before every frame)."""
        env = self.envs[i]
        counters = env.world_counters()
        self.t[i] = env.t
        self.tracking[i] = not counters["all_known"]
        self.totals[i, :3] = counters["frames"], counters["sum_age"], counters["sum_wage"]
        self.totals[i, 3 : 3 + N_HOP_BUCKETS] = counters["max_age"]
        self.totals[i, 3 + N_HOP_BUCKETS :] = counters["sum_age_hop"]
        self.step_bits[i] = counters["step_bits"]
        self.total_bits[i] = env.ledger.total_bits
        self.messages[i] = env.ledger.messages
        self.step_count[i] = env.step_count

    def store(self, i: int) -> None:
        """Write copy ``i``'s rows into its env, which then holds the copy's episode as if it had stepped it."""
        env = self.envs[i]
        env.stamps = self.stamps[i].copy()
        env.first_known = self.first_known[i].copy()
        env.sent_stamp = self.sent_stamp[i].copy()
        env.last_sent = self.last_sent[i].copy()
        if self.heard is not None:
            env.heard = self.heard[i].copy()
        env.t = float(self.t[i])
        ranking = (self.candidates[i], self.ranked_known[i].copy(), self.dist[i].copy()) if self.relative else None
        env.load_world_counters(self.counters(i), ranking)
        env.ledger.step_bits[:] = self.step_bits[i]
        env.ledger.total_bits[:] = self.total_bits[i]
        env.ledger.messages = int(self.messages[i])
        env.step_count = int(self.step_count[i])
        if self.step_count[i] >= self.max_cycles:
            env.agents = []

    def counters(self, i: int) -> dict:
        """Copy ``i``'s :meth:`MultiHopEnv.world_counters` as the world holds them (copies, not rows)."""
        totals = self.totals[i]
        return {
            "all_known": not self.tracking[i],
            "frames": totals[0],
            "sum_age": totals[1],
            "sum_wage": totals[2],
            "max_age": totals[3 : 3 + N_HOP_BUCKETS].copy(),
            "sum_age_hop": totals[3 + N_HOP_BUCKETS :].copy(),
            "step_bits": self.step_bits[i].copy(),
        }

    def bits_sent(self) -> np.ndarray:
        """``(M,)``: each copy's bits since its reset (``env.bits_sent()``)."""
        return self.total_bits.sum(1)

    # ------------------------------------------------------------------ one frame of every copy
    def step(self, actions: np.ndarray):
        """``actions`` ``(M, N, N − 1)`` select bits (``relative``) or ``(M, N, N)`` priorities (``absolute``) →
        observations ``(M, N, D)``, rewards ``(M, N)``, terminated ``(M,)``, truncated ``(M,)`` and the info columns;
        copies that end are not reset here. The observations are the world's own buffer, rewritten whole at the next
        step (``BatchedEnv`` copies it unless ``copy=False``)."""
        m, n = self.n_copies, self.n
        if self.relative:
            frame_numba.selected_ranks(self.candidates, self._selected(actions), self.rank, self.count)
        else:
            frame_numba.priority_ranks(self._priorities(actions), self.stamps, self.slot_size, self.rank, self.count)
        self._send_frame()
        np.multiply(self.sent, self.bits, out=self.step_bits)  # BitLedger.record
        self.total_bits += self.step_bits
        self.messages += n
        rewards = self._frame_end()
        self.step_count += 1
        truncated = self.step_count >= self.max_cycles
        if self.relative:
            frame_numba.observe_candidates(
                self.stamps,
                self.sent_stamp,
                self.t,
                self.dist,
                self.phase,
                self.candidates,
                self.slot,
                self.slot_size,
                self.frame_dur,
                self.diag,
                self.obs if self.heard is None else self.obs_five,
                self.known_fraction,
            )
            if self.heard is not None:
                self._observe_heard(self.heard)
        else:
            frame_numba.observe_indices(
                self.stamps,
                self.t,
                self.dist,
                self.phase,
                self.slot,
                self.slot_size,
                self.frame_dur,
                self.diag,
                self.obs,
                self.known_fraction,
            )
        infos = {
            "bits_sent": self.step_bits.copy(),
            "mean_age": self.mean_age.copy(),
            "known_fraction": self.known_fraction.copy(),
            "slot": self.slot.astype(np.float64),
        }
        if self.mask_unheld:  # MultiHopEnv._held_candidates: the observation's first feature of each candidate
            held = self.obs[:, :, 0 : self.features * self.n_cand : self.features] > 0.5
            infos.update((f"{MASK_INFO_PREFIX}{k}", held[:, :, k].astype(np.float64)) for k in range(self.n_cand))
        return self.obs, rewards, np.zeros(m, dtype=bool), truncated, infos

    def _send_frame(self) -> None:
        """``ReferenceMultiHop._step_world``: the whole frame of every copy in one compiled call."""
        frame_numba.send_frame(
            self.stamps,
            self.order,
            self.rank,
            self.count,
            self.slot_size,
            self.t,
            self.slot_dur,
            self.nbr_ptr,
            self.nbr_idx,
            self.first_known,
            self.tracking,
            self.last_sent,
            self.sent_stamp,
            self.sent,
        )

    def _observe_heard(self, heard: np.ndarray) -> None:
        """``observe_heard``'s observation (``MultiHopEnv._observe``): the compiled features of each candidate, then
        the freshness the robot's neighbours lack of it (:func:`~.protocol.neighbour_lack`), then the three robot-level
        features."""
        m, n, cand, f = self.n_copies, self.n, self.n_cand, self.features
        ranked = np.empty((m, n, cand, f), dtype=np.float32)
        ranked[..., : f - 1] = self.obs_five[:, :, : (f - 1) * cand].reshape(m, n, cand, f - 1)
        for i in range(m):
            lack = proto.neighbour_lack(self.stamps[i], heard[i], self.adj[i], self.frame_dur)
            ranked[i, :, :, f - 1] = np.take_along_axis(lack, self.candidates[i].astype(np.int64), axis=1)
        self.obs[:, :, : f * cand] = ranked.reshape(m, n, f * cand)
        self.obs[:, :, -3:] = self.obs_five[:, :, -3:]

    def _selected(self, actions: np.ndarray) -> np.ndarray:
        """The select bits as bool, refusing what the env's MultiBinary check refuses (any real 0s and 1s pass)."""
        if actions.dtype.kind not in "iubf":
            raise ValueError(f"argument 'actions' must hold 0s and 1s (MultiBinary), got dtype {actions.dtype}")
        ok = (actions == 0) | (actions == 1)
        if not ok.all():
            copy, robot = np.argwhere(~ok.all(axis=2))[0].tolist()
            raise ValueError(
                f"action of robot_{robot} (copy {copy}) must be an array of 0s and 1s of shape ({self.n_cand},), "
                f"got {actions[copy, robot]!r}"
            )
        return actions != 0

    def _priorities(self, actions: np.ndarray) -> np.ndarray:
        """The priorities as float64, after the float32 of the env's Box (``ReferenceMultiHop._priorities`` of its checked
        action), refusing what the env's Box check refuses: a non-real array, or entries not finite or outside
        [0, 1]."""
        if actions.dtype.kind not in "iuf" or actions.shape[2:] != self.act_shape:
            raise ValueError(
                f"argument 'actions' must be real arrays of shape {self.act_shape} per robot, got dtype {actions.dtype}"
                f" and shape {actions.shape}"
            )
        priority = actions.astype(np.float32, copy=False)
        ok = (np.isfinite(priority) & (priority >= 0.0) & (priority <= 1.0)).all(axis=2)
        if not ok.all():
            copy, robot = np.argwhere(~ok)[0].tolist()
            raise ValueError(
                f"action of robot_{robot} (copy {copy}) must be finite and within [0, 1], got {actions[copy, robot]!r}"
            )
        return priority.astype(np.float64)

    def _frame_end(self) -> np.ndarray:
        """``ReferenceMultiHop._frame_end`` of every copy: the time averages and per-hop ages (``frame_numba.close_frames``,
        which also ends the frame's slots), what each robot heard (``observe_heard``), the candidates re-ranked where
        what a copy's robots hold changed, and the rewards (M, N)."""
        frame_numba.close_frames(
            self.stamps,
            self.t,
            self.first_known,
            self.tracking,
            self.weights,
            self.weight_sum,
            self.hop_flat,
            self.hop_bounds,
            self.totals,
            self.mean_age,
            self.wage,
        )
        if self.heard is not None:
            for i in range(self.n_copies):
                proto.hear(self.heard[i], self.last_sent[i], self.sent_stamp[i], self.adj[i])
        if self.relative:
            self._rank_candidates()
        if not self.neighbourhood:
            team = -self.wage / self.age_unit - self.lam * self.step_bits.sum(axis=1) / self.capacity
            return np.repeat(team[:, None], self.n, axis=1)
        # each robot: the weighted age its neighbours hold (ReferenceMultiHop._frame_end's ages, as the env computes them)
        rewards = np.empty((self.n_copies, self.n))
        for i in range(self.n_copies):
            ages = np.where(self.stamps[i] > proto.UNKNOWN, self.t[i] - self.stamps[i], self.t[i])
            near = proto.neighbourhood_staleness(self.weights[i] * ages, self.weights[i], self.adj[i])
            rewards[i] = -near / self.age_unit - self.lam * self.step_bits[i] / self.bit_unit
        return rewards

    def _rank_candidates(self) -> None:
        """``MultiHopEnv._rank_candidates`` of a static scene, for the copies whose held estimates changed since
        their last ranking (``frame_numba.rerank_candidates``: a merge of two fixed orders, not a sort)."""
        frame_numba.rerank_candidates(self.stamps, self.ranked_known, self.near_order, self.slot_order, self.candidates)


class MovingBatch(StaticFrameBatch):
    """M copies of a MultiHop scene whose robots move, as arrays: a ``field`` with ``speed`` above 0 (random
    waypoints) or the ``coverage`` scene (each robot flies toward the centroid of its Voronoi cell as it sees the
    others). The static world's frame lists, observation and time averages, with each slot's links taken where the
    robots are at that slot.

    ``ReferenceMultiHop._step_world`` moves every robot after each slot. In the field nothing else in a frame draws and the
    motion does not depend on what is sent, so the frame's motion comes first, slot by slot for all copies
    (:func:`~.frame_numba.slot_receivers`, :func:`~.frame_numba.move_to_waypoints`; only the copies where a robot
    arrived draw its next waypoint, each from its own env's generator, in the env's order), and one compiled call
    sends the whole frame (:func:`~.frame_numba.send_moving_slots`). The coverage controller flies on what each robot
    holds, so there each slot is sent, then every copy's robots fly (``coverage.centroids`` and
    ``coverage.control_step``, the env's own functions, over the copy axis). At the frame's end the links, eq. (1)'s
    weights and the hop buckets follow the positions, as in the env: the links copy by copy with the env's
    ``core.comm.disk_links``, the weights with its :func:`~.protocol.reward_weights` over the copy axis, the buckets
    by a breadth-first search (:func:`~.frame_numba.hop_buckets`), and the candidates are ranked again every frame
    (the estimated distances change with the robots)."""

    def __init__(self, envs: list):
        super().__init__(envs)
        m, n = self.n_copies, self.n
        first = envs[0]
        c = first.cfg
        self.coverage = c.scene == "coverage"
        self.speed, self.comm_range, self.alpha = c.speed, c.comm_range, c.alpha
        self.gain, self.max_speed = c.control_gain, c.max_speed
        self.side = first.side
        if self.coverage:
            constants = first.world_constants()
            self.control_steps, self.control_points = constants["control_steps"], constants["control_points"]
        self.pos = np.zeros((m, n, 2))
        self.waypoint = None if self.coverage else np.zeros((m, n, 2))
        self.est = np.zeros((m, n, n, 2))
        self.receivers = np.zeros((m, n, n), dtype=bool)  # [copy, slot k, robot]: in range of slot k's sender
        self.sender_pos = np.zeros((m, n, 2))
        self.arrived = np.zeros((m, n), dtype=bool)  # [copy, robot]: reached its waypoint in the slot just moved
        self.generators: list = [None] * m
        self.eye = np.eye(n, dtype=bool)

    def adopt(self, i: int) -> None:
        env = self.envs[i]
        arrays = env.world_arrays()
        if arrays.get("ranked_known") is None and self.relative:
            # a moving scene's ranking is made afresh every frame, so its env keeps no held set of the last one
            arrays = {**arrays, "ranked_known": env.stamps > proto.UNKNOWN}
        self._adopt_arrays(i, arrays)
        self.pos[i] = arrays["pos"]
        self.est[i] = arrays["est"]
        if self.waypoint is not None:
            self.waypoint[i] = arrays["waypoint"]
        self.generators[i] = env.np_random  # the waypoints of this episode are drawn from the env's generator

    def store(self, i: int) -> None:
        super().store(i)
        waypoint = None if self.waypoint is None else self.waypoint[i].copy()
        self.envs[i].load_world_motion(self.pos[i].copy(), self.est[i].copy(), waypoint)

    def _send_frame(self) -> None:
        """The frame with each slot's links where the robots are then (the field's motion first, the coverage
        controller's between slots), then the links, weights and hop buckets of the positions at its end."""
        if self.coverage:
            for k in range(self.n):
                self._find_receivers(k)
                self._send_slots(k, k + 1)
                self._fly()
        else:
            waypoint, step = self.waypoint, self.speed * self.slot_dur
            assert waypoint is not None  # a field's robots head for waypoints
            for k in range(self.n):
                self._find_receivers(k)
                arrivals = frame_numba.move_to_waypoints(self.pos, waypoint, step, self.arrived)
                for c in () if arrivals == 0 else np.flatnonzero(self.arrived.any(axis=1)).tolist():
                    robots = self.arrived[c]
                    waypoint[c, robots] = self.generators[c].uniform(0.0, self.side, size=(int(robots.sum()), 2))
            self._send_slots(0, self.n)
        pos = self.pos
        self.est[:, self.eye] = pos
        for c in range(self.n_copies):
            self.adj[c] = disk_links(pos[c], self.comm_range)
        self.weights[:], self.weight_sum[:] = proto.reward_weights(pos, self.alpha)
        frame_numba.hop_buckets(self.adj, self.hop_flat, self.hop_bounds)
        self.dist[:] = proto.estimated_distances(self.est, pos)

    def _find_receivers(self, k: int) -> None:
        """Slot ``k``'s receivers and its sender's position in every copy, where the robots are now."""
        r2 = self.comm_range * self.comm_range
        frame_numba.slot_receivers(self.pos, self.order[:, k], r2, self.receivers[:, k], self.sender_pos[:, k])

    def _send_slots(self, first: int, last: int) -> None:
        frame_numba.send_moving_slots(
            self.stamps,
            self.est,
            self.order,
            self.rank,
            self.count,
            self.slot_size,
            self.t,
            self.slot_dur,
            self.receivers,
            self.sender_pos,
            self.first_known,
            self.tracking,
            self.last_sent,
            self.sent_stamp,
            self.sent,
            first,
            last,
        )

    def _fly(self) -> None:
        """One slot of the coverage controller in every copy (``ReferenceMultiHop._move``): its Euler steps toward each
        robot's centroid as the robot sees the partition, on what it holds now."""
        known = self.stamps > proto.UNKNOWN
        dt = self.slot_dur / self.control_steps
        n, points = self.n, self.control_points
        # copies at a time: the partition's distances, n² sites × P points of float64 per copy, stay within the cache
        # (all 64 copies of the default team at once: 14.9 ms per copy-step, against 8.0 ms a copy at a time)
        chunk = max(1, CENTROID_CHUNK_BYTES // (8 * n * n * len(points)))
        for _ in range(self.control_steps):
            for lo in range(0, self.n_copies, chunk):
                part = slice(lo, lo + chunk)
                target = cov.centroids(points, self.pos[part], self.est[part], known[part])
                self.pos[part] = cov.control_step(self.pos[part], target, self.gain, self.max_speed, dt, self.side)

    def _rank_candidates(self) -> None:
        """``MultiHopEnv._rank_candidates`` of robots that move: every frame, each robot's others by estimated
        distance (held) or slot phase (not held), with the env's stable sort (:func:`~.protocol.ranked_candidates`)."""
        known = self.stamps > proto.UNKNOWN
        self.candidates[:] = proto.ranked_candidates(known, self.dist, self.diag, self.phase)
        self.ranked_known[:] = known
