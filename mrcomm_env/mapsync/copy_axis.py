"""M copies of a MapSync configuration whose links carry any transcript within a step, stepped as arrays with a
leading copy axis (the copy-axis world).

What :class:`~mrcomm_env.core.batched.BatchedEnv` steps instead of M env objects when
:meth:`MapSyncEnv.copy_axis_world` allows it: no ``bits_per_step`` (every sync opens, completes and closes in the step
it is asked for, ``SyncSessions._sync_within_step``), links always up (no ``comm_range``, ``link_prob`` 1).
That is the default and the shipped training configuration.

A step is three compiled calls over all copies. ``kernels_numba.open_syncs`` opens the syncs the robots ask for, in
the env's order (``SyncSessions._sync_within_step``: each asking robot not yet in a sync, with the free peer it synced
with least recently). ``kernels_numba.settle_syncs`` runs each sync's protocol (Protocol 1, Algorithm 1, the full
map, the sketch: the env's compiled twins), charges its transcript and finishes it (verdict, last-writer-wins merge,
counts). ``kernels_numba.advance_copies`` changes the world, walks and senses, and computes the disagreement, the
recent bits, the reward and the observation. Between the last two, Python charges Bob's way back of each Algorithm 1
sync (``protocol.return_bits``: its ⌈log2 C(C, d)⌉ needs big integers) and lists the detections.

Each copy draws from its own generator, what the env draws and in its order (Alice's picks, the world's changes, the
walk's keys): the world holds the generator's PCG64 state and draws with numpy's own algorithms, compiled
(:mod:`~mrcomm_env.core.pcg64_numba`). Every number is the env's: the kernels' operations are the env's, in its
order (``tests/mapsync/test_mapsync_world.py`` compares each copy with the single env over whole episodes, the
generator's state
included).

Each copy keeps its env object: its ``reset_arrays`` begins the episode from its own generator,
:meth:`UnlimitedLinkBatch.adopt` takes that start (the generator's state and session counter included) into the
copy's rows, and :meth:`UnlimitedLinkBatch.store` writes the rows back, for the metrics of an ended episode and for
anything read from the env. The world appends to the env's list of detections as it goes.
"""

from __future__ import annotations

import numpy as np

from mrcomm_env.core import pcg64_numba
from mrcomm_env.mapsync import kernels_numba, pinsketch, theory
from mrcomm_env.mapsync import protocol as proto
from mrcomm_env.mapsync.actions import ACTIONS, BISECTION, EQUALITY
from mrcomm_env.mapsync.philox import DOMAIN_PARITY, SharedStrings, seed_key

_COUNT_NAMES = ("syncs", "false_equal", "equality_tests", "detections", "aborted_syncs")  # the env's _counts


class UnlimitedLinkBatch:
    """M copies of one MapSync configuration as arrays (see the module docstring).

    :param envs: the M ``MapSyncEnv`` copies (same arguments, ``copy_axis_world`` allows them), each reset before
        :meth:`adopt` reads it. The world reads the env's constants from the first copy.
    """

    def __init__(self, envs: list):
        first = envs[0]
        c = first.cfg
        m, N, n = len(envs), first.n_agents, first.n
        self.envs, self.n_copies, self.n_agents, self.n = envs, m, N, n
        self.max_cycles = c.max_cycles
        constants = first.world_constants()
        self.changing, self.lww = bool(constants["changing"]), bool(constants["lww"])
        self.appear_rate, self.vanish_rate, self.lam = float(c.appear_rate), float(c.vanish_rate), float(c.lam)
        self.bit_scale, self.horizon = int(constants["bit_scale"]), int(constants["horizon"])
        self.neighbours, self.sensed = constants["neighbour_table"], constants["sensed"]
        self.distinct = constants["sensed_distinct"]
        self.pair_rows, self.pair_cols = (np.ascontiguousarray(p, dtype=np.int64) for p in constants["pairs"])
        self.linked = np.ascontiguousarray(~constants["eye"])
        self.no_sessions = np.full(N, -1, dtype=np.int64)
        self.no_progress = np.zeros(N)
        # what the compiled protocols need: Protocol 1's shared strings (the same database seed in every copy) and
        # bits, the sketch's parity count, domain and field, Bob's way back for every count of found cells
        self.stamp_bits = int(constants["stamp_bits"])
        strings = SharedStrings(n, c.database_seed, explicit=c.explicit_database, cache=True)  # as the env's reset
        self.protocol1 = (*proto.kernel_strings(strings), theory.protocol1_bits(n, c.k), int(c.k), int(c.res))
        m_bits = pinsketch.field_bits(n)
        self.sketch_consts = (proto.sketch_verify_bits(n), DOMAIN_PARITY, m_bits)
        field = pinsketch.field(m_bits)
        self.exp, self.log = field.exp, field.log
        self.return_table = proto.return_bits_table(n)
        self.sketch_keys = np.zeros((m, 2), dtype=np.int64)  # each copy's episode key of the sketch's strings
        # the copies' state: the env's arrays of the same names with a copy axis
        self.maps = np.zeros((m, N, n), dtype=bool)
        self.stamps = np.zeros((m, N, n), dtype=np.int64)
        self.truth = np.zeros((m, n), dtype=bool)
        self.pos = np.zeros((m, N), dtype=np.int64)
        self.known = np.zeros((m, N), dtype=np.int64)
        self.new_cells = np.zeros((m, N, N), dtype=np.int64)
        self.last_sync = np.zeros((m, N, N), dtype=np.int64)
        self.last_test = np.zeros((m, N, N), dtype=np.int64)
        self.robot_syncs = np.zeros((m, N), dtype=np.int64)
        self.step_bits = np.zeros((m, N))  # the ledgers
        self.total_bits = np.zeros((m, N))
        self.messages = np.zeros(m, dtype=np.int64)
        self.counts = np.zeros((m, kernels_numba.N_COUNTS), dtype=np.int64)
        self.recent = np.zeros((m, N))
        self.recent_max = np.zeros(m)
        self.recent_any = np.zeros(m, dtype=bool)
        self.dirty = np.zeros(m, dtype=bool)
        self.column = np.zeros((m, N))  # the disagreement: each robot's, the pairs' mean, the errors and their mean
        self.mean = np.zeros(m)
        self.errors = np.zeros((m, N))
        self.error_mean = np.zeros(m)
        self.sums = np.zeros((m, 2))  # summed disagreement and error over the episode's steps
        self.step_count = np.zeros(m, dtype=np.int64)
        # each copy's generator (its env's, which it continues while the world steps) and session counter
        self.rng_state = np.zeros((m, pcg64_numba.STATE_WORDS), dtype=np.uint64)
        self.next_session = np.zeros(m, dtype=np.int64)
        self.peer_order = np.ascontiguousarray(constants["peer_order"], dtype=np.int64)
        self.pick_range = int(strings.size)  # Protocol 1's 100n strings
        # a step's syncs, at most one per two robots of every copy
        most = m * (N // 2)
        self.sync_copy, self.sync_a, self.sync_b = (np.zeros(most, dtype=np.int64) for _ in range(3))
        self.sync_kind, self.sync_nonce = np.zeros(most, dtype=np.int64), np.zeros(most, dtype=np.int64)
        self.sync_equal = np.zeros(most, dtype=bool)
        self.sync_candidates, self.sync_found = np.zeros(most, dtype=np.int64), np.zeros(most, dtype=np.int64)
        self.charged = np.zeros(m, dtype=bool)
        self.obs = np.zeros((m, *constants["obs_shape"]), dtype=np.float32)
        self.rewards = np.zeros((m, N))

    # ------------------------------------------------------------------ copies in and out
    def adopt(self, i: int) -> None:
        """Copy ``i``'s env has just been reset (or changed from outside): take its state into the copy's rows."""
        env = self.envs[i]
        if env.sessions:  # cannot happen without bits_per_step: every sync ends in its step
            raise RuntimeError("a MapSync copy-axis world takes no sync in flight")
        self.maps[i] = env.maps
        self.stamps[i] = env.stamps
        self.truth[i] = env.truth
        self.pos[i] = env.pos
        self.known[i] = env.known
        self.new_cells[i] = env.new_cells
        self.last_sync[i] = env.last_sync
        self.last_test[i] = env.last_test
        self.robot_syncs[i] = env.robot_syncs
        self.step_bits[i] = env.ledger.step_bits
        self.total_bits[i] = env.ledger.total_bits
        self.messages[i] = env.ledger.messages
        counters = env.world_counters()
        self.counts[i, : len(_COUNT_NAMES)] = [counters["counts"][name] for name in _COUNT_NAMES]
        self.counts[i, kernels_numba.CORRECTED] = counters["corrected"]
        self.counts[i, kernels_numba.TO_CORRECT] = counters["to_correct"]
        self.counts[i, kernels_numba.LATENCY_SUM] = counters["latency_sum"]
        self.counts[i, kernels_numba.LATENCY_COUNT] = counters["latency_count"]
        self.recent[i] = env.recent_bits
        self.recent_max[i] = counters["recent_max"]
        self.recent_any[i] = counters["recent_any"]
        self.dirty[i] = False
        self.column[i] = counters["disagreement_column"]
        self.mean[i] = counters["disagreement_mean"]
        self.errors[i] = counters["errors"]
        self.error_mean[i] = counters["error_mean"]
        self.sums[i] = counters["sum_disagreement"], counters["sum_error"]
        self.step_count[i] = env.step_count
        self.sketch_keys[i] = seed_key(env.sketch_seed)
        pcg64_numba.state_of(env.np_random, self.rng_state[i])  # a reset with a seed makes a new generator
        self.next_session[i] = counters["next_session"]

    def store(self, i: int) -> None:
        """Write copy ``i``'s rows into its env, which then holds the copy's episode as if it had stepped it."""
        env = self.envs[i]
        env.maps = self.maps[i].copy()
        env.stamps = self.stamps[i].copy()
        env.truth = self.truth[i].copy()
        env.pos = self.pos[i].copy()
        env.known = self.known[i].copy()
        env.new_cells = self.new_cells[i].copy()
        env.last_sync = self.last_sync[i].copy()
        env.last_test = self.last_test[i].copy()
        env.robot_syncs = self.robot_syncs[i].copy()
        env.ledger.step_bits[:] = self.step_bits[i]
        env.ledger.total_bits[:] = self.total_bits[i]
        env.ledger.messages = int(self.messages[i])
        env.recent_bits = self.recent[i].copy()
        env.step_count = int(self.step_count[i])
        pcg64_numba.set_state(env.np_random, self.rng_state[i])
        counts = self.counts[i]
        env.load_world_counters(
            {
                "counts": {name: int(counts[k]) for k, name in enumerate(_COUNT_NAMES)},
                "corrected": counts[kernels_numba.CORRECTED],
                "to_correct": counts[kernels_numba.TO_CORRECT],
                "latency_sum": counts[kernels_numba.LATENCY_SUM],
                "latency_count": counts[kernels_numba.LATENCY_COUNT],
                "recent_max": self.recent_max[i],
                "recent_any": self.recent_any[i],
                "disagreement_column": self.column[i].copy(),
                "disagreement_mean": self.mean[i],
                "errors": self.errors[i].copy(),
                "error_mean": self.error_mean[i],
                "sum_disagreement": self.sums[i, 0],
                "sum_error": self.sums[i, 1],
                "next_session": self.next_session[i],
            }
        )
        if env.step_count >= self.max_cycles:
            env.agents = []

    def bits_sent(self) -> np.ndarray:
        """``(M,)``: each copy's bits since its reset (``env.bits_sent()``)."""
        return self.total_bits.sum(1)

    # ------------------------------------------------------------------ one step of every copy
    def step(self, actions: np.ndarray):
        """``actions`` ``(M, N)`` (0 idle, 1–4 a sync) → observations ``(M, N, D)``, rewards ``(M, N)``, terminated
        ``(M,)``, truncated ``(M,)`` and the info columns; copies that end are not reset here. The observations are
        the world's own buffer, rewritten whole at the next step (``BatchedEnv`` copies it unless ``copy=False``)."""
        actions = self._checked(actions)
        count = kernels_numba.open_syncs(
            actions,
            len(ACTIONS),
            self.peer_order,
            self.last_sync,
            self.next_session,
            self.sync_copy,
            self.sync_a,
            self.sync_b,
            self.sync_kind,
            self.sync_nonce,
        )
        if count < 0:
            self._refuse(actions, -1 - count)
        copies, alices, bobs, kinds = (
            self.sync_copy[:count],
            self.sync_a[:count],
            self.sync_b[:count],
            self.sync_kind[:count],
        )
        equal, candidates, found = self.sync_equal[:count], self.sync_candidates[:count], self.sync_found[:count]
        for_python = kernels_numba.settle_syncs(
            copies,
            alices,
            bobs,
            kinds,
            self.sync_nonce[:count],
            equal,
            candidates,
            found,
            self.rng_state,
            self.pick_range,
            self.protocol1,
            self.sketch_keys,
            self.sketch_consts,
            self.exp,
            self.log,
            self.return_table,
            self.stamp_bits,
            self.lww,
            self.maps,
            self.stamps,
            self.known,
            self.last_sync,
            self.new_cells,
            self.last_test,
            self.robot_syncs,
            self.step_bits,
            self.total_bits,
            self.messages,
            self.counts,
            self.dirty,
            self.charged,
            self.step_count,
        )
        if for_python:
            self._after_syncs(copies, alices, bobs, kinds, equal, candidates, found)
        kernels_numba.advance_copies(
            self.rng_state,
            self.charged,
            self.maps,
            self.stamps,
            self.truth,
            self.pos,
            self.known,
            self.new_cells,
            self.last_sync,
            self.last_test,
            self.step_bits,
            self.recent,
            self.recent_max,
            self.recent_any,
            self.dirty,
            self.column,
            self.mean,
            self.errors,
            self.error_mean,
            self.sums,
            self.step_count,
            self.changing,
            self.appear_rate,
            self.vanish_rate,
            self.neighbours,
            self.sensed,
            self.distinct,
            self.pair_rows,
            self.pair_cols,
            self.linked,
            self.no_sessions,
            self.no_progress,
            self.lam,
            self.bit_scale,
            self.horizon,
            self.obs,
            self.rewards,
        )
        N = self.n_agents
        infos = {  # MapSyncEnv._agent_infos, in its order
            "bits_sent": self.step_bits.copy(),
            "disagreement": self.column.copy(),
            "error_vs_truth": self.errors.copy(),
            "coverage": self.known / self.n,
            "busy": np.zeros((self.n_copies, N)),  # every sync ended in its step
            "syncs": self.robot_syncs.astype(np.float64),
        }
        truncated = self.step_count >= self.max_cycles
        return self.obs, self.rewards.copy(), np.zeros(self.n_copies, dtype=bool), truncated, infos

    def _checked(self, actions: np.ndarray) -> np.ndarray:
        """The actions as int64, refusing a dtype the env's Discrete(5) check refuses (``open_syncs`` checks the
        values, and :meth:`_refuse` names the first outside the range)."""
        if actions.dtype.kind not in "iu":
            raise ValueError(
                f"argument 'actions' must hold integers in [0, {len(ACTIONS) - 1}] (Discrete({len(ACTIONS)})), "
                f"got dtype {actions.dtype}"
            )
        return actions if actions.dtype == np.int64 else actions.astype(np.int64)

    def _refuse(self, actions: np.ndarray, flat: int) -> None:
        copy, robot = divmod(flat, self.n_agents)
        raise ValueError(
            f"action of robot_{robot} (copy {copy}) must be an integer in [0, {len(ACTIONS) - 1}], "
            f"got {actions[copy, robot].item()!r}"
        )

    def _after_syncs(self, copies, alices, bobs, kinds, equal, candidates, found) -> None:
        """What needs Python after ``kernels_numba.settle_syncs``: Bob's way back of every Algorithm 1 sync
        (``protocol.return_bits`` of its candidates: ⌈log2 C(C, d)⌉ needs big integers), added to Bob's one ledger
        entry of the step (whole bits: the float sums are exact in any grouping), and the list of detections
        (``SyncSessions._verdict``: the tests that found a difference, in the order the syncs opened)."""
        for s in np.flatnonzero(kinds == BISECTION).tolist():
            back = proto.return_bits(int(candidates[s]), int(found[s]))
            if back > 0:
                m, b = int(copies[s]), int(bobs[s])
                self.step_bits[m, b] += back
                self.total_bits[m, b] += back
                self.messages[m] += 1
                self.charged[m] = True
        for s in np.flatnonzero(~equal & ((kinds == EQUALITY) | (kinds == BISECTION))).tolist():
            m = int(copies[s])
            step = int(self.step_count[m])  # the step the sync opened and ended in (advance_copies counts it)
            self.envs[m].detections.append((step, int(alices[s]), int(bobs[s]), ACTIONS[kinds[s]]))
