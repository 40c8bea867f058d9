"""M copies of a small ChannelAssociation field stepped as arrays with a leading copy axis.

What :class:`~mrcomm_env.core.batched.BatchedEnv` steps instead of M env objects when
:meth:`ChannelAssociationEnv.copy_axis_world` allows it: a §5 field of at most ``DENSE_MAX_N`` robots on bit-set
filters (``miss_tolerance`` 0), team reward. Every copy's robots are rows of one :class:`CopyBitsetFilter`
(B = M·N observers), so Algorithm 1 and Algorithm 2's list operations run as :class:`BitsetFilter`'s own
``step`` on all copies at once; motion, ranges, observations, rewards and bits are the env's formulas with a
copy axis (``DenseFieldScene.step``, ``move_and_bounce``, ``ChannelAssociationEnv._step_world``/``_refresh``/
``_observe``), kept in the same order so that every number is the same, bit for bit
(``tests/test_batched.py`` compares whole episodes of every copy with the single env).

Each copy keeps its env object: its own ``reset_arrays`` lays the field out from its own generator, and
:meth:`adopt` copies that episode's start into the copy's rows. Random draws during the episode (missed
receptions, the labels of new visual IDs) come from the copy's own generator, in the env's order.
:meth:`store` writes a copy's rows back into its env, for its metrics and for anything read from the env.
"""

from __future__ import annotations

import numpy as np

from mrcomm_env.channel_association.filters import BitsetFilter
from mrcomm_env.channel_association.scenes import DenseFieldScene, move_and_bounce


class CopyBitsetFilter(BitsetFilter):
    """A :class:`BitsetFilter` whose rows are ``copies`` groups of ``rows_per_copy`` observers, one per env copy:
    labels are drawn from each copy's generator and conflicts are counted per copy."""

    def __init__(self, copies: int, rows_per_copy: int, n_w: int, n_v: int, drop_time: int, extra_edges: bool):
        super().__init__(copies * rows_per_copy, n_w, n_v, drop_time, extra_edges)
        self.copies, self.rows_per_copy = copies, rows_per_copy
        self.rngs: list[np.random.Generator] = []
        self.copy_conflicts = np.zeros(copies, dtype=np.int64)

    def _label_new(self, newv: np.ndarray) -> None:
        # row-major order of the (B, V) mask is copy by copy: each copy's draws are the single env's, in order
        per_copy = newv.reshape(self.copies, -1).sum(1)
        labels = [self.rngs[c].integers(0, 2**31, size=int(k)) for c, k in enumerate(per_copy.tolist()) if k]
        self.vlabel[newv] = np.concatenate(labels)

    def _count_conflicts(self, empty: np.ndarray) -> None:
        self.copy_conflicts += empty.reshape(self.copies, -1).sum(1)


class SlotFieldBatch:
    """The copy-axis world of a small ChannelAssociation field (see the module docstring).

    :param envs: the M ``ChannelAssociationEnv`` copies (same arguments, ``copy_axis_world`` allows them), each
        reset before :meth:`adopt` reads it. The world reads the env's constants from the first copy, and imports
        nothing of the env module (which builds it).
    """

    #: the filter arrays of one observer row each (``heard`` has the ring axis first)
    _FILTER_ROWS = ("C", "wt", "vt", "deg", "vlabel", "new_ids")

    def __init__(self, envs: list):
        first = envs[0]
        c, n = first.cfg, first.n_agents
        self.envs, self.m, self.n = envs, len(envs), n
        self.cfg = c
        self.n_stat = n - int(round(c.mobile_fraction * n))  # layout_field's count: the same in every copy
        self.mobile = self.n_stat < n
        self.q = float(c.miss_probability)
        self.wrange, self.vrange = float(c.wireless_range), float(c.visual_range)
        self.same_ranges = not self.vrange < self.wrange
        self.filter = CopyBitsetFilter(self.m, n, n, n, c.drop_time, c.wireless_range > c.visual_range)
        self.filter.rngs = [env.np_random for env in envs]
        m, k = self.m, n - self.n_stat
        # the env's constants of observation and reward (the same in every copy)
        self.history = first.EMISSION_HISTORY
        self.msg_bits = first._msg_bits_f
        self.id_bits, self.n_static, self.clock = first._id_bits, first._n_static, first._clock
        self.phase_col, self.clock_codes = first._phase_col, first._clock_codes
        self.squash8, self.squash4 = first._squash8, first._squash4
        self.max_cycles, self.cost = c.max_cycles, c.emission_cost
        self.self_inf = np.where(np.eye(n, dtype=bool), np.inf, 0.0)[self.n_stat :]
        # the copies' state
        self.pos = np.zeros((m, n, 2))
        self.vel = np.zeros((m, k, 2))
        self.fast = np.zeros((m, k, 2), dtype=bool)
        self.size = np.zeros(2)
        self.wr = np.zeros((m, n, n), dtype=bool)
        self.vr = self.wr if self.same_ranges else np.zeros((m, n, n), dtype=bool)
        self.wr_packed = np.zeros((m, n), dtype=np.uint64)
        self.obs = np.zeros((m, n, first._obs_dim), dtype=np.float32)
        self.step_count = np.zeros(m, dtype=np.int64)
        self.completion = np.full(m, -1, dtype=np.int64)
        self.step_bits = np.zeros((m, n))
        self.total_bits = np.zeros((m, n))
        self.messages = np.zeros(m, dtype=np.int64)
        self.emit = np.zeros((m, n), dtype=bool)
        self.stats = tuple(np.zeros((m, n), dtype=dt) for dt in (np.uint8, np.uint8, np.uint16, np.uint8, np.int64))
        self.frac = np.zeros((m, n))
        self.team_score = np.zeros(m)

    # ------------------------------------------------------------------ copies in and out
    def _rows(self, i: int) -> slice:
        return slice(i * self.n, (i + 1) * self.n)

    def adopt(self, i: int) -> None:
        """Copy ``i``'s env has just been reset: take its episode's start into the copy's rows."""
        env = self.envs[i]
        scene = env.scene
        assert isinstance(scene, DenseFieldScene)
        f, rows = scene.filter, self._rows(i)
        self.pos[i] = scene.positions
        self.size = scene.size
        if self.mobile:
            self.vel[i] = scene.vel
            self.fast[i] = False if scene.fast is None else scene.fast
        self.wr[i] = scene.wr
        if not self.same_ranges:
            self.vr[i] = scene.vr
        self.wr_packed[i] = scene.wr_packed
        for name in self._FILTER_ROWS:
            getattr(self.filter, name)[rows] = getattr(f, name)
        # the ring of receptions starts empty, as the env's (stale bits could not change a drop anyway: an ID is
        # dropped drop_time steps after it was last heard, when the ring holds only this episode)
        self.filter.heard[:, rows] = 0
        self.filter.copy_conflicts[i] = f.conflicts
        self.filter.rngs[i] = env.np_random  # reset(seed=…) replaces the generator
        self.obs[i] = env._obs
        self.emit[i] = env._emit
        self.step_count[i] = env.step_count
        self.completion[i] = env._completion
        self.step_bits[i] = env.ledger.step_bits
        self.total_bits[i] = env.ledger.total_bits
        self.messages[i] = env.ledger.messages
        for column, value in zip(self.stats, env._stats):
            column[i] = value

    def store(self, i: int) -> None:
        """Write copy ``i``'s rows into its env, which then holds the copy's episode as if it had stepped it."""
        env = self.envs[i]
        scene = env.scene
        f, rows = scene.filter, self._rows(i)
        scene.positions = self.pos[i].copy()
        if self.mobile:
            scene.vel = self.vel[i].copy()
            scene.fast = self.fast[i].copy() if self.fast[i].any() else None
        scene.wr = self.wr[i].copy()
        scene.vr = scene.wr if self.same_ranges else self.vr[i].copy()
        scene.wr_packed = self.wr_packed[i].copy()
        scene.rows_key = None
        for name in self._FILTER_ROWS:
            setattr(f, name, getattr(self.filter, name)[rows].copy())
        f.heard = self.filter.heard[:, rows].copy()
        f.t = self.filter.t
        f.conflicts = int(self.filter.copy_conflicts[i])
        env._obs = self.obs[i].copy()
        env._emit = self.emit[i].copy()
        env.step_count = int(self.step_count[i])
        env._completion = int(self.completion[i])
        env.ledger.step_bits[:] = self.step_bits[i]
        env.ledger.total_bits[:] = self.total_bits[i]
        env.ledger.messages = int(self.messages[i])
        env._stats = tuple(column[i].copy() for column in self.stats)
        env._frac = self.frac[i].copy()
        env._team_score = float(self.team_score[i])
        env._stats_key = None
        env._state_version += 1
        if self.completion[i] >= 0 or self.step_count[i] >= self.max_cycles:
            env.agents = []

    def bits_sent(self) -> np.ndarray:
        """``(M,)``: each copy's bits since its reset (``env.bits_sent()``)."""
        return self.total_bits.sum(1)

    # ------------------------------------------------------------------ one step of every copy
    def step(self, actions: np.ndarray):
        """``actions`` ``(M, N)`` (0 or 1) → observations ``(M, N, D)``, rewards ``(M, N)``, terminated ``(M,)``,
        truncated ``(M,)``, infos (``bits_sent`` ``(M, N)``); copies that end are not reset here."""
        if actions.dtype.kind not in "iub":
            raise ValueError(
                f"argument 'actions' must hold integers in [0, 1] (Discrete(2)), got dtype {actions.dtype}"
            )
        bad = (actions < 0) | (actions > 1)
        if bad.any():
            copy, robot = np.argwhere(bad)[0].tolist()
            raise ValueError(
                f"action of robot_{robot} (copy {copy}) must be an integer in [0, 1], got {actions[copy, robot]!r}"
            )
        n = self.n
        emit = actions.astype(bool)
        self.emit = emit
        dyn = self.obs[:, :, self.n_static :]
        dyn[:, :, 2 : 1 + self.history] = dyn[:, :, 1 : self.history]  # own emission history, newest first
        dyn[:, :, 1] = emit
        n_emit = np.count_nonzero(emit, axis=1)
        np.multiply(emit, self.msg_bits, out=self.step_bits)  # BitLedger.record
        self.total_bits += self.step_bits
        self.messages += n_emit
        self._sense_and_filter(emit, n_emit)
        self._refresh()
        reward = self.team_score - 1.0 - self.cost * n_emit / n
        if not self.mobile:
            final = (self.completion < 0) & ~self.stats[3].any(axis=1)
            self.completion[final] = self.step_count[final] + 1
        self.step_count += 1
        terminated = self.completion >= 0
        truncated = (self.step_count >= self.max_cycles) & ~terminated
        self._observe()
        rewards = np.repeat(reward[:, None], n, axis=1)
        return self.obs.copy(), rewards, terminated, truncated, {"bits_sent": self.step_bits.copy()}

    def _sense_and_filter(self, emit: np.ndarray, n_emit: np.ndarray) -> None:
        """``DenseFieldScene.step`` of every copy."""
        f, n = self.filter, self.n
        if self.mobile:
            self._move()
            self._update_ranges()
        if self.q > 0.0:
            recv = np.empty((self.m, n, n), dtype=bool)
            vact = np.empty((self.m, n, n), dtype=bool)
            for i, rng in enumerate(f.rngs):  # each copy's draws from its generator, in the env's order
                recv[i] = self.wr[i] & emit[i] & (rng.random((n, n)) >= self.q)
                vact[i] = self.vr[i] & emit[i] & (rng.random((n, n)) >= self.q)
            f.step(recv.reshape(-1, n), vact.reshape(-1, n), self.vr.reshape(-1, n), self.mobile)
        elif self.mobile or n_emit.any():  # a stationary copy without emissions steps to no change
            lit = (emit @ f._pow[:n])[:, None]  # f.pack(emit) of every copy
            f.step(
                (self.wr_packed & lit).reshape(-1),
                (self.vr & emit[:, None, :]).reshape(-1, n),
                self.vr.reshape(-1, n),
                self.mobile,
            )

    def _move(self) -> None:
        """``DenseFieldScene._move`` of every copy (``move_and_bounce`` takes the copy axis)."""
        fast = self.fast if self.fast.any() else None
        move_and_bounce(self.pos[:, self.n_stat :], self.vel, self.size, fast)

    def _update_ranges(self) -> None:
        """``DenseFieldScene._update_ranges(n_stat)`` of every copy: the mobile robots' rows and columns."""
        first = self.n_stat
        z = np.ascontiguousarray(self.pos).view(np.complex128)[..., 0]  # (M, N) positions as complex numbers
        d = np.abs(z[:, first:, None] - z[:, None, :])
        d += self.self_inf
        w = d <= self.wrange
        self.wr[:, first:] = w
        self.wr[:, :, first:] = w.transpose(0, 2, 1)
        if not self.same_ranges:
            v = d <= self.vrange
            self.vr[:, first:] = v
            self.vr[:, :, first:] = v.transpose(0, 2, 1)
        np.matmul(self.wr, self.filter._pow[: self.n], out=self.wr_packed)

    def _refresh(self) -> None:
        """``ChannelAssociationEnv._refresh`` of every copy (computed every step: the values are the same)."""
        m, n, f = self.m, self.n, self.filter
        matched, nv, ne, unres = (column.reshape(m, n) for column in f.stats())
        new = f.new_ids.reshape(m, n)
        self.stats = (matched, nv, ne, unres, new)
        self.frac = matched / np.maximum(nv, 1)
        self.team_score = np.add.reduce(self.frac, axis=1) / n  # DenseFieldScene.team_score
        j, dyn = 1 + self.history, self.obs[:, :, self.n_static :]
        dyn[:, :, j] = self.frac
        dyn[:, :, j + 1] = (np.maximum(ne, nv) - nv) / np.maximum(ne, 1)
        dyn[:, :, j + 2] = self.squash8[unres]
        dyn[:, :, j + 3] = self.squash4[new]

    def _observe(self) -> None:
        """``ChannelAssociationEnv._observe`` of every copy, in place."""
        obs, steps = self.obs, self.step_count
        phase = steps % self.clock
        obs[:, :, : self.id_bits] = self.clock_codes[phase]
        obs[:, :, self.n_static] = np.minimum(steps / self.max_cycles, 1.0)[:, None]
        obs[:, :, self.phase_col :] = 0.0
        obs[np.arange(self.m), :, self.phase_col + phase] = 1.0
