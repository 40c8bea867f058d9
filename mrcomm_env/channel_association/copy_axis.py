"""M copies of a ChannelAssociation scene stepped as arrays with a leading copy axis (copy-axis worlds).

What :class:`~mrcomm_env.core.batched.BatchedEnv` steps instead of M env objects when
:meth:`ChannelAssociationEnv.copy_axis_world` allows it: a scene on bit-set filters (``miss_tolerance`` 0) with
either reward (the team's, or each robot's own: ``reward_mode``), a §5 field of at most ``DENSE_MAX_N`` robots
(:class:`SlotFieldBatch`) or a §4 neighbourhood (:class:`NeighborhoodBatch`). Every copy's observers are rows of one
:class:`CopyBitsetFilter` (a field: B = M·N observers; a neighbourhood: B = M), so Algorithm 1 and Algorithm 2's
list operations run as :class:`BitsetFilter`'s own ``step`` on all copies at once; motion, ranges, sensing,
observations, rewards and bits are the env's formulas with a copy axis (the scenes' ``step``, ``move_and_bounce``,
``ChannelAssociationEnv._step_world``/``_refresh``/``_observe``), kept in the same order so that every number is the
same, bit for bit (``tests/channel_association/test_channel_association_world.py`` compares whole episodes of every
copy with the single env).

Each copy keeps its env object: its own ``reset_arrays`` lays the scene out from its own generator, and
:meth:`CopyAxisWorld.adopt` copies that episode's start into the copy's rows. Random draws during the episode
(missed receptions, the labels of new visual IDs) come from the copy's own generator, in the env's order.
:meth:`CopyAxisWorld.store` writes a copy's rows back into its env, for its metrics and for anything read from
the env. A neighbourhood's episodes, and a still field's, end every few steps, so both worlds also begin the next
episode of an ended copy and compute the ended episode's metrics themselves (``reset_copies``, ``final_metrics``),
with the same draws and formulas, leaving the env object to be brought up to date when it is read."""

from __future__ import annotations

import numpy as np

from mrcomm_env.channel_association.filters import BitsetFilter
from mrcomm_env.channel_association.observation import push_emission, write_istate
from mrcomm_env.channel_association.scenes import (
    DenseFieldScene,
    NeighborhoodScene,
    bitset_singled_out,
    draw_field,
    fast_coordinates,
    field_positions,
    field_shape,
    move_and_bounce,
)


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


class CopyAxisWorld:
    """What the copy-axis worlds of both scenes share: the env's observation, bits, reward and episode end with a
    copy axis; a scene adds its sensing (:meth:`_sense_and_filter`) and its per-robot statistics.

    :param envs: the M ``ChannelAssociationEnv`` copies (same arguments, ``copy_axis_world`` allows them), each
        reset before :meth:`adopt` reads it. The world reads the env's constants from the first copy, and imports
        nothing of the env module (which builds it).
    :param rows_per_copy: observers per copy (filter rows), ``n_w``, ``n_v``: the filter's slots.
    """

    #: the filter arrays of one observer row each (``heard`` has the ring axis first)
    _FILTER_ROWS = ("C", "wt", "vt", "deg", "vlabel", "new_ids")
    #: whether any robot moves (a stationary scene ends when every i-state is final)
    mobile = False

    def __init__(self, envs: list, rows_per_copy: int, n_w: int, n_v: int, extra_edges: bool = False):
        first = envs[0]
        c, n = first.cfg, first.n_agents
        self.envs, self.m, self.n, self.rows_per_copy = envs, len(envs), n, rows_per_copy
        self.cfg = c
        self.q = float(c.miss_probability)
        self.filter = CopyBitsetFilter(self.m, rows_per_copy, n_w, n_v, c.drop_time, extra_edges)
        self.filter.rngs = [env.np_random for env in envs]
        m = self.m
        # the env's constants of observation and reward (the same in every copy)
        constants = first.world_constants()
        self.msg_bits = constants["msg_bits"]
        self.id_bits, self.n_static, self.clock = constants["id_bits"], constants["n_static"], constants["clock"]
        self.phase_col, self.clock_codes = constants["phase_col"], constants["clock_codes"]
        self.squash8, self.squash4 = constants["squash8"], constants["squash4"]
        self.static_obs = constants["static_obs"]  # each robot's own ID bits and observer flag, written at every reset
        self.max_cycles, self.cost = c.max_cycles, c.emission_cost
        self.individual = c.reward_mode == "individual"
        #: copies whose episode the world began itself (``reset_copies``) since their env object was last written
        self.restarted = np.zeros(self.m, dtype=bool)
        # the copies' state
        self.obs = np.zeros((m, n, constants["obs_dim"]), dtype=np.float32)
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
        return slice(i * self.rows_per_copy, (i + 1) * self.rows_per_copy)

    def adopt(self, i: int) -> None:
        """Copy ``i``'s env has just been reset: take its episode's start into the copy's rows."""
        env = self.envs[i]
        scene = env.scene
        f, rows = scene.filter, self._rows(i)
        self._adopt_scene(i, scene)
        for name in self._FILTER_ROWS:
            getattr(self.filter, name)[rows] = getattr(f, name)
        # the ring of receptions starts empty, as the env's (stale bits could not change a drop anyway: an ID is
        # dropped drop_time steps after it was last heard, when the ring holds only this episode)
        self.filter.heard[:, rows] = 0
        self.filter.copy_conflicts[i] = f.conflicts
        self.filter.rngs[i] = env.np_random  # reset(seed=…) replaces the generator
        self.restarted[i] = False
        obs, emit, completion, stats = env.episode_arrays()
        self.obs[i] = obs
        self.emit[i] = emit
        self.step_count[i] = env.step_count
        self.completion[i] = completion
        self.step_bits[i] = env.ledger.step_bits
        self.total_bits[i] = env.ledger.total_bits
        self.messages[i] = env.ledger.messages
        for column, value in zip(self.stats, stats):
            column[i] = value

    def store(self, i: int) -> None:
        """Write copy ``i``'s rows into its env, which then holds the copy's episode as if it had stepped it."""
        env = self.envs[i]
        scene = env.scene
        f, rows = scene.filter, self._rows(i)
        self._store_scene(i, scene)
        for name in self._FILTER_ROWS:
            setattr(f, name, getattr(self.filter, name)[rows].copy())
        f.heard = self.filter.heard[:, rows].copy()
        f.t = self.filter.t
        f.conflicts = int(self.filter.copy_conflicts[i])
        # the world began this episode (``restarted``): the env also takes what its reset would have set
        env.load_episode(
            self.obs[i].copy(),
            self.emit[i].copy(),
            int(self.completion[i]),
            tuple(column[i].copy() for column in self.stats),
            self.frac[i].copy(),
            float(self.team_score[i]),
            began=bool(self.restarted[i]),
        )
        self.restarted[i] = False
        env.step_count = int(self.step_count[i])
        env.ledger.step_bits[:] = self.step_bits[i]
        env.ledger.total_bits[:] = self.total_bits[i]
        env.ledger.messages = int(self.messages[i])
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
        push_emission(self.obs[..., self.n_static :], emit)
        n_emit = np.count_nonzero(emit, axis=1)
        np.multiply(emit, self.msg_bits, out=self.step_bits)  # BitLedger.record
        self.total_bits += self.step_bits
        self.messages += n_emit
        self._sense_and_filter(emit, n_emit)
        self._refresh()
        if self.individual:  # ChannelAssociationEnv._step_world's reward of each robot, every copy at once
            singled, seen = self._singled_out()
            rewards = np.where(seen > 0, singled / np.maximum(seen, 1), 1.0) - 1.0 - self.cost * emit
        else:
            reward = self.team_score - 1.0 - self.cost * n_emit / n
            rewards = np.repeat(reward[:, None], n, axis=1)
        if not self.mobile:
            final = (self.completion < 0) & ~self.stats[3].any(axis=1)
            self.completion[final] = self.step_count[final] + 1
        self.step_count += 1
        terminated = self.completion >= 0
        truncated = (self.step_count >= self.max_cycles) & ~terminated
        self._observe()
        return self.obs.copy(), rewards, terminated, truncated, {"bits_sent": self.step_bits.copy()}

    def _begin_episodes(self, copies: list[int]) -> tuple[np.ndarray, list[dict[str, np.ndarray]]]:
        """The rest of ``ChannelAssociationEnv._reset_world`` for the copies ``copies``, whose scene and filter rows a
        world's ``reset_copies`` has just laid out: the bits, counters and observation rows begin again, then
        ``_refresh`` and ``_observe`` (the same values for the other copies: their filters did not change since their
        step). Returns the observations of every copy and each reset copy's info columns."""
        for i in copies:
            self.obs[i] = 0.0
            self.obs[i, :, : self.n_static] = self.static_obs
            self.emit[i] = False
            self.step_count[i] = 0
            self.completion[i] = -1
            self.step_bits[i] = 0.0
            self.total_bits[i] = 0.0
            self.messages[i] = 0
            self.restarted[i] = True
        self._refresh()
        self._observe()
        return self.obs, [{"bits_sent": self.step_bits[i].copy()} for i in copies]

    # ------------------------------------------------------------------ what a scene adds
    def _adopt_scene(self, i: int, scene) -> None:
        """Take the scene state of copy ``i`` that changes during an episode (beyond the filter)."""

    def _store_scene(self, i: int, scene) -> None:
        """Write it back."""

    def _sense_and_filter(self, emit: np.ndarray, n_emit: np.ndarray) -> None:
        """The scene's ``step`` of every copy."""
        raise NotImplementedError

    def _singled_out(self) -> tuple[np.ndarray, np.ndarray]:
        """The scene's ``singled_out`` of every copy, (M, N) each."""
        raise NotImplementedError

    def _robot_stats(self) -> tuple[np.ndarray, ...]:
        """The scene's ``robot_stats`` of every copy: (matched, visual IDs, edges, unresolved, new IDs), (M, N)."""
        m, n, f = self.m, self.n, self.filter
        return (*(column.reshape(m, n) for column in f.stats()), f.new_ids.reshape(m, n))

    def _team_score(self, frac: np.ndarray) -> np.ndarray:
        """The scene's ``team_score`` of every copy: the mean fraction matched over the robots."""
        return np.add.reduce(frac, axis=1) / self.n

    def _refresh(self) -> None:
        """``ChannelAssociationEnv._refresh`` of every copy (computed every step: the values are the same)."""
        matched, nv, ne, unres, new = self.stats = self._robot_stats()
        self.frac = matched / np.maximum(nv, 1)
        self.team_score = self._team_score(self.frac)
        write_istate(self.obs[..., self.n_static :], self.frac, nv, ne, unres, new, self.squash8, self.squash4)

    def _observe(self) -> None:
        """``ChannelAssociationEnv._observe`` of every copy, in place."""
        obs, steps = self.obs, self.step_count
        phase = steps % self.clock
        obs[:, :, : self.id_bits] = self.clock_codes[phase]
        obs[:, :, self.n_static] = np.minimum(steps / self.max_cycles, 1.0)[:, None]
        obs[:, :, self.phase_col :] = 0.0
        obs[np.arange(self.m), :, self.phase_col + phase] = 1.0


class SlotFieldBatch(CopyAxisWorld):
    """The copy-axis world of a field of at most 64 robots (``DenseFieldScene``): every robot observes, so each
    copy has N filter rows, and the mobile robots move and change the in-range matrices."""

    def __init__(self, envs: list):
        c, n = envs[0].cfg, envs[0].n_agents
        super().__init__(envs, n, n, n, c.wireless_range > c.visual_range)
        m = self.m
        n_mob, self.cols, self.cells, self.size = field_shape(n, c.separation, c.mobile_fraction)  # every copy's
        self.n_stat = n - n_mob
        self.mobile = self.n_stat < n
        k = n - self.n_stat
        self.wrange, self.vrange = float(c.wireless_range), float(c.visual_range)
        self.same_ranges = not self.vrange < self.wrange
        self.self_inf_all = np.where(np.eye(n, dtype=bool), np.inf, 0.0)
        self.self_inf = self.self_inf_all[self.n_stat :]
        self.pos = np.zeros((m, n, 2))
        self.vel = np.zeros((m, k, 2))
        self.fast = np.zeros((m, k, 2), dtype=bool)
        self.wr = np.zeros((m, n, n), dtype=bool)
        self.vr = self.wr if self.same_ranges else np.zeros((m, n, n), dtype=bool)
        self.wr_packed = np.zeros((m, n), dtype=np.uint64)

    def _singled_out(self) -> tuple[np.ndarray, np.ndarray]:
        f, shape = self.filter, (self.m, self.n, self.n)  # each copy's N observer rows
        # a slot per robot, the same in every copy: the scene's own truth (its copies were reset before any step)
        robots, true_bits = self.envs[0].scene.slot_truth()
        return bitset_singled_out(f.C.reshape(shape), f.vt.reshape(shape), robots, true_bits, self.n)

    def _adopt_scene(self, i: int, scene) -> None:
        assert isinstance(scene, DenseFieldScene)
        self.pos[i] = scene.positions
        self.size = scene.size
        if self.mobile:
            self.vel[i] = scene.vel
            self.fast[i] = False if scene.fast is None else scene.fast
        self.wr[i] = scene.wr
        if not self.same_ranges:
            self.vr[i] = scene.vr
        self.wr_packed[i] = scene.wr_packed

    def _store_scene(self, i: int, scene) -> None:
        scene.positions = self.pos[i].copy()
        if self.mobile:
            scene.vel = self.vel[i].copy()
            scene.fast = self.fast[i].copy() if self.fast[i].any() else None
        scene.wr = self.wr[i].copy()
        scene.vr = scene.wr if self.same_ranges else self.vr[i].copy()
        scene.wr_packed = self.wr_packed[i].copy()
        scene.rows_key = None

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
            lit = (emit @ f.powers[:n])[:, None]  # f.pack(emit) of every copy
            f.step(
                (self.wr_packed & lit).reshape(-1),
                (self.vr & emit[:, None, :]).reshape(-1, n),
                self.vr.reshape(-1, n),
                self.mobile,
            )

    def reset_copies(self, copies: list[int]) -> tuple[np.ndarray, list[dict[str, np.ndarray]]]:
        """Begin the next episode of each copy in ``copies`` (ended, reset without a seed) in the world itself:
        ``ChannelAssociationEnv.reset_arrays()`` of a dense field, with the same draws from the copy's generator
        (``FieldScene.reset``'s layout and headings, then the labels of ``BitsetFilter.init_known`` in a still
        field), without its env object, which :meth:`store` brings up to date when it is read. A still field ends as
        soon as every i-state is final: about every ten steps as shipped for training (25 robots, random actions),
        often enough that resets through the env objects were a large part of a batch's time. Returns the
        observations of every copy and each reset copy's info columns."""
        c, f, n, k = self.cfg, self.filter, self.n, self.n - self.n_stat
        draws = []
        for i in copies:  # FieldScene.reset: each copy draws from its own generator, so copies may go in any order
            rng = f.rngs[i]
            draws.append(draw_field(rng, n, k, self.cells))  # layout_field's draws
            heading = rng.uniform(0.0, 2.0 * np.pi, size=k)
            if self.mobile:
                vel = c.speed * np.stack((np.cos(heading), np.sin(heading)), axis=1)
                fast = fast_coordinates(vel, self.size)
                self.vel[i] = vel
                self.fast[i] = False if fast is None else fast
        chosen, offsets, places = (np.stack(column) for column in zip(*draws))
        self.pos[copies] = field_positions(chosen, offsets, places, self.cols, c.separation, self.size)
        # DenseFieldScene._update_ranges() of the reset copies: every pair, elementwise as the scene computes it
        z = np.ascontiguousarray(self.pos[copies]).view(np.complex128)[..., 0]
        d = np.abs(z[:, :, None] - z[:, None, :])
        d += self.self_inf_all
        w = d <= self.wrange
        self.wr[copies] = w
        if not self.same_ranges:
            self.vr[copies] = d <= self.vrange
        self.wr_packed[copies] = w @ f.powers[:n]
        rows = np.concatenate([np.arange(i * n, (i + 1) * n) for i in copies])
        # BitsetFilter.reset of the copies' rows; a still field then knows its neighbourhoods (init_known)
        f.C[rows] = 0
        f.wt[rows] = 0
        f.heard[:, rows] = 0
        f.vt[rows] = False
        f.vlabel[rows] = -1
        f.new_ids[rows] = 0
        f.copy_conflicts[copies] = 0
        if not self.mobile:
            vr = self.vr[copies].reshape(-1, n)
            wt = self.wr_packed[copies].reshape(-1)
            f.wt[rows] = wt
            f.vt[rows] = vr
            f.C[rows] = np.where(vr, wt[:, None], np.uint64(0))
            for j, i in enumerate(copies):  # the labels, after the layout's draws, from each copy's generator
                seen = vr[j * n : (j + 1) * n]  # row-major, as the env's vlabel[v_mask] = …
                f.vlabel[self._rows(i)][seen] = f.rngs[i].integers(0, 2**31, size=int(np.count_nonzero(seen)))
        f.deg[rows] = np.bitwise_count(f.C[rows])
        return self._begin_episodes(copies)

    def final_metrics(self, copies: list[int]) -> list[dict[str, float]]:
        """``ChannelAssociationEnv.metrics()`` of the copies ``copies`` (whose episodes just ended), computed on their
        rows without writing them into the env objects. Robot j is wireless and visual slot j of every observer, so
        an edge is true when its wireless slot is its visual slot (``Scene.true_edges``, ``Scene.wrong_matches``).
        The means run over each copy's measured observers with the env's own expressions (numpy's mean of the
        selected entries), so that they round alike."""
        f, n = self.filter, self.n
        measured = np.arange(n) >= (self.n_stat if self.mobile else 0)  # the mobile robots (last), or every one
        true_bits = f.powers[:n]
        out = []
        for i in copies:
            rows = self._rows(i)
            C, deg, vt = f.C[rows], f.deg[rows], f.vt[rows]
            matched, nv, ne = (column[i] for column in self.stats[:3])
            sel = measured & (nv > 0)
            frac = float((matched[sel] / nv[sel]).mean()) if sel.any() else 0.0
            true = np.count_nonzero(C & true_bits, axis=-1).astype(np.int64)  # scenes.bitset_true_edges
            ratio = float((ne[sel] / np.maximum(true[sel], 1)).mean()) if sel.any() else 1.0
            unique = (deg == 1) & vt
            total = int(np.count_nonzero(unique))
            wrong = int(np.count_nonzero(unique & (C != true_bits)))
            out.append(
                {
                    "completion_time": float(self.completion[i]),
                    "fraction_matched": frac,
                    "edge_ratio": ratio,
                    "fraction_wrong": wrong / total if total else 0.0,
                    "conflicts": float(f.copy_conflicts[i]),
                    "messages_sent": float(self.messages[i]),
                    "bits_sent": float(self.total_bits[i].sum()),
                }
            )
        return out

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
        np.matmul(self.wr, self.filter.powers[: self.n], out=self.wr_packed)


class NeighborhoodBatch(CopyAxisWorld):
    """The copy-axis world of the §4 neighbourhood (``NeighborhoodScene``): robot_0 of each copy observes, so each
    copy has one filter row of ``w`` wireless and ``v`` visual slots; visual slot s of copy i is robot
    ``vis_robot[i, s]``. Nothing moves: the scene's state during an episode is the filter's."""

    def __init__(self, envs: list):
        first = envs[0]
        c = first.cfg
        super().__init__(envs, 1, c.w, c.v)
        self.vis_robot = np.zeros((self.m, c.v), dtype=np.int64)
        f = self.filter
        self.all_wireless = f.pack(np.ones(c.w, dtype=bool))  # the known neighbourhood: every wireless slot

    def _true_bits(self, copies) -> np.ndarray:
        """(len(copies), v): the bit of each visual slot's own wireless ID; wireless slot h is robot h + 1."""
        return np.left_shift(np.uint64(1), (self.vis_robot[copies] - 1).astype(np.uint64))

    def _singled_out(self) -> tuple[np.ndarray, np.ndarray]:
        f, shape = self.filter, (self.m, 1, self.filter.C.shape[1])  # each copy's one observer row
        true_bits = self._true_bits(slice(None))
        return bitset_singled_out(f.C.reshape(shape), f.vt.reshape(shape), self.vis_robot, true_bits, self.n)

    def _adopt_scene(self, i: int, scene) -> None:
        assert isinstance(scene, NeighborhoodScene)
        self.vis_robot[i] = scene.vis_robot

    def _store_scene(self, i: int, scene) -> None:
        scene.vis_robot = self.vis_robot[i].copy()  # new when the world began this episode (reset_copies)

    def reset_copies(self, copies: list[int]) -> tuple[np.ndarray, list[dict[str, np.ndarray]]]:
        """Begin the next episode of each copy in ``copies`` (ended, reset without a seed) in the world itself:
        ``ChannelAssociationEnv.reset_arrays()`` of a neighbourhood, with the same draws from the copy's generator
        (the observer's visual labelling, then the labels of Algorithm 1's start), without its env object, which
        :meth:`store` brings up to date when it is read. Episodes end every few steps here, so resets through the
        env objects would cost more than the steps. Returns the observations of every copy and each reset
        copy's info columns."""
        c, f = self.cfg, self.filter
        for i in copies:
            rng = f.rngs[i]
            self.vis_robot[i] = 1 + rng.permutation(c.w)[: c.v]  # NeighborhoodScene.reset
            # BitsetFilter.init_known of the all-ones w × v i-state (one row per copy)
            f.C[i] = self.all_wireless
            f.wt[i] = self.all_wireless
            f.vt[i] = True
            f.vlabel[i] = rng.integers(0, 2**31, size=c.v)
            f.new_ids[i] = 0
            f.heard[:, i] = 0
            f.copy_conflicts[i] = 0
        f.deg[copies] = np.bitwise_count(f.C[copies])
        return self._begin_episodes(copies)

    def _sense_and_filter(self, emit: np.ndarray, n_emit: np.ndarray) -> None:
        """``NeighborhoodScene.step`` of every copy: wireless slot h is robot h + 1."""
        recv = emit[:, 1:]
        vact = np.take_along_axis(emit, self.vis_robot, axis=1)
        if self.q > 0.0:
            recv, vact = recv.copy(), vact.copy()
            for i, rng in enumerate(self.filter.rngs):  # each copy's draws from its generator, in the env's order
                recv[i] &= rng.random(recv.shape[1]) >= self.q
                vact[i] &= rng.random(vact.shape[1]) >= self.q
        self.filter.step(recv, vact)

    def final_metrics(self, copies: list[int]) -> list[dict[str, float]]:
        """``ChannelAssociationEnv.metrics()`` of the copies ``copies`` (whose episodes just ended), computed on their
        rows without writing them into the env objects: the observer's statistics, and against the ground truth
        (wireless slot h is robot h + 1, visual slot s robot ``vis_robot[s]``) its true edges and unique matches
        (``Scene.true_edges``, ``Scene.wrong_matches``)."""
        f = self.filter
        C, deg, vt = f.C[copies], f.deg[copies], f.vt[copies]
        holds_true = (C & self._true_bits(copies)) != 0
        true = np.count_nonzero(holds_true & vt, axis=1)
        unique = (deg == 1) & vt
        total = np.count_nonzero(unique, axis=1)
        wrong = np.count_nonzero(unique & ~holds_true, axis=1)
        matched, nv, ne = (column[copies, 0] for column in self.stats[:3])
        seen = nv > 0  # the env's mean over measured observers with visual IDs: robot_0, or none
        frac = np.where(seen, matched / np.maximum(nv, 1), 0.0)
        ratio = np.where(seen, ne / np.maximum(true, 1), 1.0)
        fraction_wrong = np.where(total > 0, wrong / np.maximum(total, 1), 0.0)
        bits = self.total_bits[copies].sum(1)  # whole bits: exact in any order of summation
        columns = zip(
            self.completion[copies].tolist(),
            frac.tolist(),
            ratio.tolist(),
            fraction_wrong.tolist(),
            f.copy_conflicts[copies].tolist(),
            self.messages[copies].tolist(),
            bits.tolist(),
        )
        keys = (
            "completion_time",
            "fraction_matched",
            "edge_ratio",
            "fraction_wrong",
            "conflicts",
            "messages_sent",
            "bits_sent",
        )
        return [dict(zip(keys, map(float, row))) for row in columns]

    def _robot_stats(self) -> tuple[np.ndarray, ...]:
        """Only robot_0 runs a filter: its statistics in column 0, zeros for the others (int64, as the scene's)."""
        f = self.filter
        cols = np.zeros((5, self.m, self.n), dtype=np.int64)
        for column, values in zip(cols, (*f.stats(), f.new_ids)):
            column[:, 0] = values
        return tuple(cols)

    def _team_score(self, frac: np.ndarray) -> np.ndarray:
        return frac[:, 0].copy()
