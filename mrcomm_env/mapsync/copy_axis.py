"""M copies of a MapSync configuration whose links carry any transcript within a step, stepped as arrays with a
leading copy axis (the copy-axis world).

What :class:`~mrcomm_env.core.batched.BatchedEnv` steps instead of M env objects when
:meth:`MapSyncEnv.copy_axis_world` allows it: no ``bits_per_step`` (every sync opens, completes and closes in the step
it is asked for, ``SyncSessions._sync_within_step``), links always up (no ``comm_range``, ``link_prob`` 1), on the
compiled backend. That is the default and the shipped training configuration.

A step has two parts. First the syncs: for every copy whose robots asked for one, the env's own choice of peers and
the env's protocol runs (``SyncSessions._transcript``: Protocol 1, Algorithm 1, the full map, the sketch) on the
copy's maps, with the copy's generator, in the env's order; they are Python and the protocols' compiled kernels, as
in the env. Then everything else, for all copies in one compiled call (``kernels_numba.step_copies``): each sync's
charges, verdict, last-writer-wins merge and counts, the changing world, the walk and sensing, the disagreement,
the recent bits, the reward and the observation. Each copy's keys of the step (the world's changes, then the walk's)
are drawn from its own generator in one call, the same stream as the env's two calls. Every number is the env's:
the kernel's operations are the env's, in its order (``tests/test_batched.py`` compares each copy with the single env
over whole episodes).

Each copy keeps its env object: its ``reset_arrays`` begins the episode from its own generator,
:meth:`UnlimitedLinkBatch.adopt` takes that start into the copy's rows, and :meth:`UnlimitedLinkBatch.store` writes the
rows back, for the metrics of an ended episode and for anything read from the env. The env object also keeps what
the syncs use: its generator, its session counter (the sketch's nonce) and its list of detections.
"""

from __future__ import annotations

import numpy as np

from mrcomm_env.core import pcg64_numba
from mrcomm_env.mapsync import kernels_numba, pinsketch, theory
from mrcomm_env.mapsync import protocol as proto
from mrcomm_env.mapsync.philox import DOMAIN_PARITY, SharedStrings, seed_key
from mrcomm_env.mapsync.sessions import _STALE_ALL, ACTIONS, BISECTION, EQUALITY, FULL, SKETCH

# the kernel's sync kinds are the actions that ask for them
assert (kernels_numba._EQUALITY, kernels_numba._BISECTION, kernels_numba._FULL, kernels_numba._SKETCH) == (
    EQUALITY,
    BISECTION,
    FULL,
    SKETCH,
)

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
        self.changing, self.lww = bool(first._changing), bool(first._lww)
        self.appear_rate, self.vanish_rate, self.lam = float(c.appear_rate), float(c.vanish_rate), float(c.lam)
        self.bit_scale, self.horizon = int(first._bit_scale), int(first._horizon)
        self.neighbours, self.sensed, self.distinct = first._neighbour_table, first._sensed, first._sensed_distinct
        self.pair_rows, self.pair_cols = (np.ascontiguousarray(p, dtype=np.int64) for p in first._pairs)
        self.linked = np.ascontiguousarray(~first._eye)
        self.peer_lists = first._peer_lists
        self.no_sessions = np.full(N, -1, dtype=np.int64)
        self.no_progress = np.zeros(N)
        # what the compiled protocols need: Protocol 1's shared strings (the same database seed in every copy) and
        # bits, the sketch's parity count, domain and field, Bob's way back for every count of found cells
        self.k, self.stamp_bits = int(c.k), int(first._stamp_bits)
        strings = SharedStrings(n, c.database_seed, explicit=c.explicit_database, cache=True)  # as the env's reset
        self.strings = (*proto._kernel_strings(strings), theory.protocol1_bits(n, c.k))
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
        self.peer_order = np.ascontiguousarray(first._peer_order, dtype=np.int64)
        self.pick_range = int(strings.size)  # Protocol 1's 100n strings
        # a step's syncs, at most one per two robots of every copy
        most = m * (N // 2)
        self.sync_copy, self.sync_a, self.sync_b = (np.zeros(most, dtype=np.int64) for _ in range(3))
        self.sync_kind, self.sync_nonce = np.zeros(most, dtype=np.int64), np.zeros(most, dtype=np.int64)
        self.sync_picks = np.zeros((most, self.k), dtype=np.int64)
        self.picks_drawn = np.zeros(most, dtype=bool)
        self.sync_equal = np.zeros(most, dtype=bool)
        self.sync_bits = np.zeros((most, 2), dtype=np.int64)
        self.sync_messages = np.zeros((most, 2), dtype=np.int64)
        self.found_offsets = np.zeros(most + 1, dtype=np.int64)
        self.obs = np.zeros((m, *first._obs_buf.shape), dtype=np.float32)
        self.rewards = np.zeros(m)

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
        self.counts[i, : len(_COUNT_NAMES)] = [env._counts[name] for name in _COUNT_NAMES]
        self.counts[i, kernels_numba.CORRECTED] = env._corrected
        self.counts[i, kernels_numba.TO_CORRECT] = env._to_correct
        self.counts[i, kernels_numba.LATENCY_SUM] = env._latency_sum
        self.counts[i, kernels_numba.LATENCY_COUNT] = env._latency_count
        self.recent[i] = env.recent_bits
        self.recent_max[i] = env._recent_max
        self.recent_any[i] = env._recent_any
        env._update_disagreement()  # a state changed from outside may await its disagreement
        self.dirty[i] = False
        self.column[i] = env._disagreement_column
        self.mean[i] = env._disagreement_mean
        self.errors[i] = env._errors
        self.error_mean[i] = env._error_mean
        self.sums[i] = env._sum_disagreement, env._sum_error
        self.step_count[i] = env.step_count
        self.sketch_keys[i] = seed_key(env.sketch_seed)
        pcg64_numba.state_of(env.np_random, self.rng_state[i])  # a reset with a seed makes a new generator
        self.next_session[i] = env._next_session

    def store(self, i: int) -> None:
        """Write copy ``i``'s rows into its env, which then holds the copy's episode as if it had stepped it."""
        env = self.envs[i]
        env.maps = self.maps[i].copy()
        env.stamps = self.stamps[i].copy()
        env._make_views()
        env.truth = self.truth[i].copy()
        env.pos = self.pos[i].copy()
        env.known = self.known[i].copy()
        env.new_cells = self.new_cells[i].copy()
        env.last_sync = self.last_sync[i].copy()
        env._last_sync_peers = env.last_sync.take(env._peer_flat)
        env.last_test = self.last_test[i].copy()
        env.robot_syncs = self.robot_syncs[i].copy()
        env.ledger.step_bits[:] = self.step_bits[i]
        env.ledger.total_bits[:] = self.total_bits[i]
        env.ledger.messages = int(self.messages[i])
        env._charged = bool(self.step_bits[i].any())
        env._counts = {name: int(self.counts[i, k]) for k, name in enumerate(_COUNT_NAMES)}
        env._corrected = int(self.counts[i, kernels_numba.CORRECTED])
        env._to_correct = int(self.counts[i, kernels_numba.TO_CORRECT])
        env._latency_sum = int(self.counts[i, kernels_numba.LATENCY_SUM])
        env._latency_count = int(self.counts[i, kernels_numba.LATENCY_COUNT])
        env.recent_bits = self.recent[i].copy()
        env._recent_max = float(self.recent_max[i])
        env._recent_any = bool(self.recent_any[i])
        env._dirty = False
        env._disagreement_column = self.column[i].copy()
        env._disagreement_mean = float(self.mean[i])
        env._errors = self.errors[i].copy()
        env._error_mean = float(self.error_mean[i])
        env._sum_disagreement, env._sum_error = (float(v) for v in self.sums[i])
        env.step_count = env._steps = int(self.step_count[i])
        pcg64_numba.set_state(env.np_random, self.rng_state[i])
        env._next_session = int(self.next_session[i])
        env._state_version += 1
        # the observation and infos are made anew from the state just written
        env._events += 1
        env._stale = _STALE_ALL
        env._infos_key = None
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
            self.peer_order,
            self.last_sync,
            self.next_session,
            self.sync_copy,
            self.sync_a,
            self.sync_b,
            self.sync_kind,
            self.sync_nonce,
        )
        copies, alices, bobs, kinds = (
            self.sync_copy[:count],
            self.sync_a[:count],
            self.sync_b[:count],
            self.sync_kind[:count],
        )
        equal, bits, messages = self.sync_equal[:count], self.sync_bits[:count], self.sync_messages[:count]
        picks, picks_drawn, offsets = self.sync_picks[:count], self.picks_drawn[:count], self.found_offsets[: count + 1]
        found = self._run_bisections(count)
        opened_at = self.step_count.copy() if count else None
        kernels_numba.step_copies(
            copies,
            alices,
            bobs,
            kinds,
            equal,
            bits,
            messages,
            found,
            offsets,
            picks,
            picks_drawn,
            self.sync_nonce[:count],
            self.rng_state,
            self.pick_range,
            self.sketch_keys,
            self.strings,
            self.sketch_consts,
            self.exp,
            self.log,
            self.return_table,
            self.stamp_bits,
            self.maps,
            self.stamps,
            self.truth,
            self.pos,
            self.known,
            self.new_cells,
            self.last_sync,
            self.last_test,
            self.robot_syncs,
            self.step_bits,
            self.total_bits,
            self.messages,
            self.counts,
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
            self.lww,
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
        if opened_at is not None:  # SyncSessions._verdict's list of detections: the tests that found a difference
            for s in np.flatnonzero(~equal & ((kinds == EQUALITY) | (kinds == BISECTION))).tolist():
                m = int(copies[s])
                self.envs[m].detections.append((int(opened_at[m]), int(alices[s]), int(bobs[s]), ACTIONS[kinds[s]]))
        N = self.n_agents
        infos = {  # MapSyncEnv._agent_infos, in its order
            "bits_sent": self.step_bits.copy(),
            "disagreement": self.column.copy(),
            "error_vs_truth": self.errors.copy(),
            "coverage": self.known / self.n,
            "busy": np.zeros((self.n_copies, N)),  # every sync ended in its step
            "syncs": self.robot_syncs.astype(np.float64),
        }
        rewards = np.repeat(self.rewards[:, None], N, axis=1)
        truncated = self.step_count >= self.max_cycles
        return self.obs, rewards, np.zeros(self.n_copies, dtype=bool), truncated, infos

    def _checked(self, actions: np.ndarray) -> np.ndarray:
        """The actions as int64, refusing what the env's Discrete(5) check refuses."""
        if actions.dtype.kind not in "iu":
            raise ValueError(
                f"argument 'actions' must hold integers in [0, {len(ACTIONS) - 1}] (Discrete({len(ACTIONS)})), "
                f"got dtype {actions.dtype}"
            )
        bad = (actions < 0) | (actions >= len(ACTIONS))
        if bad.any():
            copy, robot = np.argwhere(bad)[0].tolist()
            raise ValueError(
                f"action of robot_{robot} (copy {copy}) must be an integer in [0, {len(ACTIONS) - 1}], "
                f"got {actions[copy, robot].item()!r}"
            )
        return actions.astype(np.int64, copy=False)

    def _run_bisections(self, count: int) -> np.ndarray:
        """Algorithm 1 of the step's syncs that ask for it, run here (``SyncSessions._transcript``): it draws its picks
        round by round, which only the env's code does. A copy with one runs all its syncs' draws here, in their order
        (an equality test's picks too), on its env's generator brought up to the world's state and back. Writes their
        answers, bits and messages, and returns the found cells of every sync (``found_offsets``)."""
        kinds = self.sync_kind[:count]
        self.picks_drawn[:count] = False
        self.found_offsets[: count + 1] = 0
        bisections = np.flatnonzero(kinds == BISECTION)
        if not bisections.size:
            return _NO_CELLS
        found = []
        sizes = np.zeros(count, dtype=np.int64)
        copies = self.sync_copy[:count]
        for m in np.unique(copies[bisections]).tolist():  # copies run in any order: each has its own generator
            env = self.envs[m]
            maps = self.maps[m]
            pcg64_numba.set_state(env.np_random, self.rng_state[m])
            for s in np.flatnonzero(copies == m).tolist():
                a, b, kind = int(self.sync_a[s]), int(self.sync_b[s]), int(kinds[s])
                if kind == EQUALITY:
                    self.sync_picks[s] = proto._alice_picks(env.strings, 1, self.k, env.np_random)[0]
                    self.picks_drawn[s] = True
                elif kind == BISECTION:
                    nonce = int(self.sync_nonce[s])
                    outcome, transcript = env._transcript(maps[a], maps[b], a, b, ACTIONS[kind], nonce)
                    sent = [0, 0, 0, 0]  # Alice's bits and messages, Bob's
                    for who, size in transcript:
                        side = 0 if who == a else 2
                        sent[side] += size
                        sent[side + 1] += 1
                    self.sync_bits[s] = sent[0], sent[2]
                    self.sync_messages[s] = sent[1], sent[3]
                    self.sync_equal[s] = not outcome.detected
                    sizes[s] = outcome.found.size
                    found.append((s, outcome.found))
            pcg64_numba.state_of(env.np_random, self.rng_state[m])
        np.cumsum(sizes, out=self.found_offsets[1 : count + 1])
        cells = np.zeros(int(self.found_offsets[count]), dtype=np.int64)
        for s, part in found:
            cells[self.found_offsets[s] : self.found_offsets[s + 1]] = part
        return cells


_NO_CELLS = np.zeros(0, dtype=np.int64)
