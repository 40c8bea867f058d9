"""The scenes of ChannelAssociation-v0 as strategy objects: who senses whom, and which filter keeps it.

A scene owns the world (positions, motion, ranges), turns one step's emissions into what each observer
senses, runs its :class:`~mrcomm_env.channel_association.filters.AssociationFilter` and knows the
ground truth behind the filter's slots (which robot a wireless or visual slot is). The environment
picks one scene at construction and never branches on it again:

* :class:`NeighborhoodScene` — §4: one observer (robot_0), a known neighbourhood of ``w`` wireless and
  ``v`` visual IDs; bit-set filter (``DenseFilter`` with ``miss_tolerance`` > 0 or w > 64).
* :class:`DenseFieldScene` — §5 field of at most ``DENSE_MAX_N`` robots: (N, N) in-range matrices and a
  slot-per-robot filter (bit sets, or the literal 0/1 matrix with ``miss_tolerance`` > 0).
* :class:`SparseFieldScene` — §5 field of any size: k-d tree neighbour pairs as sorted keys
  ``observer * n + robot`` and the edge-list :class:`SparseFilter`, so memory and time grow with the
  number of neighbours, not with N².
"""

from __future__ import annotations

import math
from itertools import chain

import numpy as np
from scipy.spatial import cKDTree

from mrcomm_env.channel_association.filters import (
    BITSET_MAX_W,
    AssociationFilter,
    BitsetFilter,
    DenseFilter,
    SparseFilter,
)
from mrcomm_env.core.comm import disk_pairs


def layout_field(rng: np.random.Generator, n: int, separation: float, mobile_fraction: float):
    """§5.4: grid robots (perturbed within half a spacing) plus uniformly placed mobile robots.

    The arena is the ⌈√n⌉-column grid of spacing ``separation``; stationary robots take randomly chosen
    cells so the density (1/separation²) is the same for any mix. Returns positions, mobile mask, size.
    """
    n_mob, cols, cells, size = field_shape(n, separation, mobile_fraction)
    chosen, offsets, places = draw_field(rng, n, n_mob, cells)
    pos = field_positions(chosen, offsets, places, cols, separation, size)
    mobile = np.zeros(n, dtype=bool)
    mobile[n - n_mob :] = True
    return pos, mobile, size


def field_shape(n: int, separation: float, mobile_fraction: float) -> tuple[int, int, int, np.ndarray]:
    """:func:`layout_field`'s mobile robots, grid columns, grid cells and arena size (the same every episode)."""
    cols = int(math.ceil(math.sqrt(n)))
    rows = int(math.ceil(n / cols))
    return int(round(mobile_fraction * n)), cols, cols * rows, np.array([cols * separation, rows * separation])


def draw_field(rng: np.random.Generator, n: int, n_mob: int, cells: int):
    """:func:`layout_field`'s draws, in its order: the stationary robots' cells and offsets, the mobile robots'
    places (each as fractions of a spacing or of the arena)."""
    chosen = rng.permutation(cells)[: n - n_mob]
    offsets = rng.uniform(-0.5, 0.5, size=(n - n_mob, 2))
    places = rng.uniform(0.0, 1.0, size=(n_mob, 2))
    return chosen, offsets, places


def field_positions(chosen, offsets, places, cols: int, separation: float, size: np.ndarray) -> np.ndarray:
    """Positions (…, N, 2) from :func:`draw_field`'s draws (a leading copy axis allowed: elementwise, so each copy
    gets what it would alone)."""
    grid = np.stack((chosen % cols, chosen // cols), axis=-1).astype(np.float64)
    stat = (grid + 0.5) * separation + offsets * separation
    return np.concatenate((stat, places * size), axis=-2)


def move_and_bounce(p: np.ndarray, vel: np.ndarray, size: np.ndarray, fast: np.ndarray | None = None) -> None:
    """Advance positions ``p`` (K, 2) by ``vel`` in place, bouncing off the walls of [0, size] (§5.4).

    ``fast`` marks the coordinates whose speed exceeds the arena (see :func:`fast_coordinates`): a step
    then crosses the arena more than once, and adding the velocity first would round the position away.
    With a leading copy axis, ``p`` and ``vel`` (M, K, 2) (``copy_axis.py``), each copy moves as it would
    alone: the reflection, which rounds, touches the coordinates of the copies in which a robot left the arena.
    """
    if fast is not None:
        side = np.broadcast_to(size, p.shape)[fast]
        v0 = vel[fast]
        # position on the unfolded line modulo the period 2·size, without losing the start to rounding
        u = np.mod(p[fast] + np.mod(v0, 2.0 * side), 2.0 * side)
    p += vel
    out = p < 0.0
    out |= p > size
    if np.count_nonzero(out):  # one reflection at either wall
        if p.ndim == 2:
            np.abs(p, out=p)
            np.subtract(size, np.abs(size - p), out=p)
        else:
            hit = out.any(axis=(1, 2))
            q = np.abs(p[hit])
            p[hit] = np.subtract(size, np.abs(size - q), out=q)
        vel[out] *= -1.0
    if fast is not None:
        back = u > side  # the second half of the period runs backwards
        p[fast] = np.where(back, 2.0 * side - u, u)
        vel[fast] = np.where(back, -v0, v0)


def fast_coordinates(vel: np.ndarray, size: np.ndarray) -> np.ndarray | None:
    """Mask of velocity components longer than the arena (speeds only flip sign), or None if there is none."""
    fast = np.abs(vel) > size
    return fast if np.count_nonzero(fast) else None


def make_slot_filter(batch: int, n_w: int, n_v: int, drop_time: int, tolerance: int, extra_edges: bool):
    """A slot-per-robot filter: bit sets when they can hold the i-state (W ≤ 64, no disagreement counts)."""
    if tolerance == 0 and n_w <= BITSET_MAX_W:
        return BitsetFilter(batch, n_w, n_v, drop_time, extra_edges)
    return DenseFilter(batch, n_w, n_v, drop_time, tolerance, extra_edges)


def bitset_singled_out(C, vt, robots, true_bits, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``Scene.singled_out`` on bit-set i-states ``C`` (…, B, V) with tracked visual IDs ``vt``, robot ``robots[s]``
    behind visual slot s and ``true_bits[s]`` its wireless slot's bit: per robot (…, n) int64, the observers
    whose only candidate for its visual ID is its own wireless ID, and the observers holding its visual ID with
    candidates (an edge). A leading copy axis (the copy-axis world) is summed per copy. Each robot is behind at
    most one visual slot (a slot per robot, or the neighbourhood's labelling), so counting observers per slot is
    counting them per robot, as the edge list's distinct (observer, robot) pairs are."""
    bits = true_bits[..., None, :]  # the same for every observer row
    right = C == bits
    right &= vt
    if not true_bits.all():  # a robot without a wireless slot is never singled out (an empty set is no match)
        right &= bits != 0
    lead = C.shape[:-2]
    singled = np.zeros((*lead, n), dtype=np.int64)
    seen = np.zeros((*lead, n), dtype=np.int64)
    at = (robots,) if not lead else (np.arange(lead[0])[:, None], robots)
    singled[at] = np.add.reduce(right, axis=-2, dtype=np.int64)
    seen[at] = np.add.reduce(C != 0, axis=-2, dtype=np.int64)
    return singled, seen


def bitset_true_edges(C, true_bits) -> np.ndarray:
    """``Scene.true_edges`` on bit-set i-states ``C`` (B, V): per observer, the visual slots whose candidates hold the
    wireless bit ``true_bits[s]`` of the robot behind the slot (0 when it has none). An edge (h, s) is true when h is
    that robot's wireless slot, and a slot's candidate set holds each bit once, so these are the true edges."""
    return np.count_nonzero(C & true_bits, axis=-1).astype(np.int64)


def backend_name(f: AssociationFilter) -> str:
    return {BitsetFilter: "bitset", DenseFilter: "dense", SparseFilter: "sparse"}[type(f)]


class Scene:
    """Interface of a scene (see the module docstring). Attributes read by the environment:

    ``filter``, ``positions`` (N, 2), ``moving`` (N,) bool, ``mobile`` (any robot moves),
    ``observer`` (robots that run a filter), ``measured`` (robots the metrics average over),
    ``render_radius``.
    """

    filter: AssociationFilter
    mobile: bool

    def __init__(self, cfg, n_agents: int):
        self.cfg, self.n = cfg, n_agents
        self.q = cfg.miss_probability

    @property
    def backend(self) -> str:
        return backend_name(self.filter)

    def reset(self, rng: np.random.Generator) -> None:
        raise NotImplementedError

    def step(self, emit: np.ndarray, n_emit: int) -> None:
        """Move, sense the emissions ``emit`` (N,) bool (``n_emit`` of them), run the filter."""
        raise NotImplementedError

    def robot_stats(self, matched, nv, ne, unres, new):
        """The filter's per-observer statistics as per-robot columns (N,)."""
        return matched, nv, ne, unres, new

    def team_score(self, frac: np.ndarray) -> float:
        """Mean fraction matched over the observers."""
        return float(np.add.reduce(frac)) / self.n

    # ground truth: which robot is behind a filter's slot
    def wireless_robot(self, h: np.ndarray) -> np.ndarray:
        return h

    def visual_robot(self, s: np.ndarray) -> np.ndarray:
        return s

    def true_edges(self) -> np.ndarray:
        """Number of true edges (wireless and visual ID of the same robot) per robot."""
        if isinstance(self.filter, BitsetFilter):  # on the bit sets themselves, without listing every edge
            counts = np.zeros(self.n, dtype=np.int64)
            counts[: self.filter.C.shape[0]] = bitset_true_edges(self.filter.C, self.slot_truth()[1])
            return counts
        return self.true_edges_from_edges()

    def true_edges_from_edges(self) -> np.ndarray:
        """:meth:`true_edges` from the filter's list of edges (any filter)."""
        o, h, s = self.filter.edges()
        return np.bincount(o[self.wireless_robot(h) == self.visual_robot(s)], minlength=self.n)

    def singled_out(self) -> tuple[np.ndarray, np.ndarray]:
        """Per robot j: how many observers hold j's visual ID with j's wireless ID as its one candidate, and how
        many hold j's visual ID at all (with candidates left). What robot j's own emissions decide."""
        if isinstance(self.filter, BitsetFilter):  # on the bit sets themselves, without listing every edge
            return bitset_singled_out(self.filter.C, self.filter.vt, *self.slot_truth(), self.n)
        return self.singled_out_from_edges()

    def singled_out_from_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`singled_out` from the filter's lists of edges and unique matches (any filter)."""
        n = self.n
        o, h, s = self.filter.edges()
        seen_pairs = np.unique(o.astype(np.int64) * n + self.visual_robot(s))
        seen = np.bincount(seen_pairs % n, minlength=n)
        mo, mh, ms = self.filter.matches()
        right = self.wireless_robot(mh) == self.visual_robot(ms)
        singled = np.bincount(self.visual_robot(ms)[right], minlength=n)
        return singled, seen

    def slot_truth(self) -> tuple[np.ndarray, np.ndarray]:
        """(V,) the robot behind each visual slot, and (V,) uint64 the bit of that robot's wireless slot (0 when
        it has none): the one candidate set that singles the robot out. Kept while the labelling it was made
        from is the scene's (a neighbourhood's ``vis_robot`` is a new array every episode)."""
        key = getattr(self, "vis_robot", None)
        cached = self.__dict__.get("_slot_truth")
        if cached is None or cached[0] is not key or cached[1] is not self.filter:
            cached = self._slot_truth = (key, self.filter, self._make_slot_truth())
        robots, true_bits = cached[2]
        return robots, true_bits

    def _make_slot_truth(self) -> tuple[np.ndarray, np.ndarray]:
        f = self.filter
        assert isinstance(f, BitsetFilter)  # a slot per wireless and per visual ID
        n_w, n_v = f.shape[1], f.shape[2]
        robots = np.asarray(self.visual_robot(np.arange(n_v)), dtype=np.int64)
        slot_of = np.full(self.n, -1, dtype=np.int64)
        slot_of[self.wireless_robot(np.arange(n_w))] = np.arange(n_w)
        slots = slot_of[robots]
        bits = np.where(slots >= 0, np.left_shift(np.uint64(1), np.maximum(slots, 0).astype(np.uint64)), 0)
        return robots, bits.astype(np.uint64)

    def wrong_matches(self) -> tuple[int, int]:
        """(wrong, all) unique matches, against the ground truth."""
        o, h, s = self.filter.matches()
        return int(np.count_nonzero(self.wireless_robot(h) != self.visual_robot(s))), len(o)

    def associations(self, i: int) -> dict[int, list[int]]:
        return self.filter.candidates(i)


class NeighborhoodScene(Scene):
    """§4: robot_0 observes its neighbours robot_1 … robot_w, of which ``v`` are visible; all static.

    Wireless slot h is robot h + 1, visual slot s is robot ``vis_robot[s]``."""

    mobile = False
    render_radius = 1.0

    def __init__(self, cfg, n_agents: int):
        super().__init__(cfg, n_agents)
        self.moving = np.zeros(n_agents, dtype=bool)
        self.observer = np.zeros(n_agents, dtype=bool)
        self.observer[0] = True
        self.measured = self.observer

    def reset(self, rng: np.random.Generator) -> None:
        c = self.cfg
        self.rng = rng
        # the observer's own labelling: visual slot s is robot vis_robot[s] (a random subset, random order)
        self.vis_robot = 1 + rng.permutation(c.w)[: c.v]
        self.filter = make_slot_filter(1, c.w, c.v, c.drop_time, c.miss_tolerance, False)
        self.filter.rng = rng
        self.filter.init_known(np.ones((1, c.w), bool), np.ones((1, c.v), bool))

    @property
    def positions(self) -> np.ndarray:
        """Where the robots are drawn (rendering only): computed when read, from the visual labelling."""
        return ring_positions(self.cfg.w, self.vis_robot)

    def step(self, emit: np.ndarray, n_emit: int) -> None:
        recv = emit[None, 1:]
        vact = emit[self.vis_robot][None, :]
        q = self.q
        if q > 0.0:
            recv = recv & (self.rng.random(recv.shape) >= q)
            vact = vact & (self.rng.random(vact.shape) >= q)
        self.filter.step(recv, vact)

    def robot_stats(self, matched, nv, ne, unres, new):
        cols = np.zeros((5, self.n), dtype=np.int64)  # only robot_0 runs a filter
        cols[:, 0] = (matched[0], nv[0], ne[0], unres[0], new[0])
        return tuple(cols)

    def team_score(self, frac: np.ndarray) -> float:
        return float(frac[0])

    def wireless_robot(self, h):
        return h + 1

    def visual_robot(self, s):
        return self.vis_robot[s]

    def associations(self, i: int) -> dict[int, list[int]]:
        if i != 0:
            return {}
        return {label: [h + 1 for h in slots] for label, slots in self.filter.candidates(0).items()}


class FieldScene(Scene):
    """§5 field: stationary robots on a perturbed grid, the mobile ones (stored last) bouncing around.

    Every robot observes. With mobile robots every robot runs Algorithm 2's list operations and the
    metrics are measured on the mobile robots (§5.4)."""

    def __init__(self, cfg, n_agents: int):
        super().__init__(cfg, n_agents)
        self.wrange, self.vrange = cfg.wireless_range, cfg.visual_range
        self.render_radius = cfg.visual_range
        self.observer = np.ones(n_agents, dtype=bool)
        # §5.2: a wireless range beyond the visual range adds new visual × old unassociated wireless edges
        self.extra = cfg.wireless_range > cfg.visual_range

    def reset(self, rng: np.random.Generator) -> None:
        c, n = self.cfg, self.n
        self.rng = rng
        self.positions, self.moving, self.size = layout_field(rng, n, c.separation, c.mobile_fraction)
        self.n_stat = n - int(self.moving.sum())
        heading = rng.uniform(0.0, 2.0 * np.pi, size=n - self.n_stat)
        self.vel = c.speed * np.stack((np.cos(heading), np.sin(heading)), axis=1)
        self.fast = fast_coordinates(self.vel, self.size)
        self.mobile = self.n_stat < n
        self.measured = self.moving if self.mobile else self.observer

    def _move(self) -> None:
        move_and_bounce(self.positions[self.n_stat :], self.vel, self.size, self.fast)  # mobile robots are last


class DenseFieldScene(FieldScene):
    """A field of at most 64 robots with (N, N) in-range matrices and a slot-per-robot filter."""

    def __init__(self, cfg, n_agents: int):
        super().__init__(cfg, n_agents)
        self.self_inf = np.where(np.eye(n_agents, dtype=bool), np.inf, 0.0)  # a robot is not its own neighbour

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        c, n = self.cfg, self.n
        self.rows_key = None  # mobile robots' in-range rows not yet known
        self.filter = make_slot_filter(n, n, n, c.drop_time, c.miss_tolerance, self.extra)
        self.filter.rng = rng
        self._update_ranges()
        if not self.mobile:
            self.filter.init_known(self.wr, self.vr)

    def _update_ranges(self, first: int = 0) -> None:
        """In-range matrices ``wr``, ``vr`` (and ``wr_packed``, ``wr`` as the filter takes it).

        ``first`` > 0 recomputes only the rows of robots ``first`` … N−1 (the mobile ones, stored last)
        and mirrors them into their columns: distances between stationary robots never change, and
        |a − b| equals |b − a| exactly in floating point, so the result is the full computation's.
        """
        z = self.positions.view(np.complex128).ravel()  # positions viewed as complex numbers
        d = np.abs(z[first:, None] - z)
        d += self.self_inf[first:]
        wr, vr = self.wrange, self.vrange
        if first == 0:
            self.wr = d <= wr
            self.vr = d <= vr if vr < wr else self.wr  # the same array when the ranges are equal
        else:
            w = d <= wr
            v = d <= vr if vr < wr else None
            # a robot moves a small part of the range per step: usually nobody entered or left it
            key = w.tobytes() if v is None else w.tobytes() + v.tobytes()
            if key == self.rows_key:
                return
            self.rows_key = key
            self.wr[first:] = w
            self.wr[:, first:] = w.T
            if v is not None:
                self.vr[first:] = v
                self.vr[:, first:] = v.T
        self.wr_packed = self.filter.pack(self.wr)

    def step(self, emit: np.ndarray, n_emit: int) -> None:
        mobile, f = self.mobile, self.filter
        if mobile:
            self._move()
            self._update_ranges(self.n_stat)  # only the mobile robots' rows and columns
        q = self.q
        if q > 0.0:
            n, rng = self.n, self.rng
            recv = self.wr & emit & (rng.random((n, n)) >= q)
            vact = self.vr & emit & (rng.random((n, n)) >= q)
            f.step(recv, vact, self.vr, mobile)
        elif n_emit or mobile:  # else: known neighbourhoods, nobody lit, no change
            f.step(self.wr_packed & f.pack(emit), self.vr & emit, self.vr, mobile)


class SparseFieldScene(FieldScene):
    """A field of any size: k-d tree pairs as sorted keys ``o * n + x`` and the edge-list filter."""

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        c, n = self.cfg, self.n
        self.filter = SparseFilter(n, c.drop_time, c.miss_tolerance, self.extra)
        self.filter.rng = rng
        self._static_keys = None
        self._update_pairs()
        if not self.mobile:
            self.filter.init_known(self.wkeys, self.vkeys)

    def _update_pairs(self) -> None:
        """Directed in-range pairs as sorted keys o*n + x (k-d tree).

        Pairs between stationary robots never change, so they are found once per episode; each step
        only the mobile robots are queried against a tree of all positions and merged in.
        """
        n, pos, ns = self.n, self.positions, self.n_stat
        if self._static_keys is None:
            pairs = disk_pairs(pos[:ns], self.wrange).astype(np.int64)
            a, b = pairs[:, 0], pairs[:, 1]
            self._static_keys = np.sort(np.concatenate((a * n + b, b * n + a)))
        keys = self._static_keys
        if ns < n:
            lists = cKDTree(pos).query_ball_point(pos[ns:], self.wrange)
            cnt = np.fromiter(map(len, lists), dtype=np.int64, count=len(lists))
            x = np.fromiter(chain.from_iterable(lists), dtype=np.int64, count=int(cnt.sum()))
            m = np.repeat(np.arange(ns, n), cnt)
            keep = x != m
            m, x = m[keep], x[keep]
            st = x < ns  # mobile–stationary pairs also go the other way
            dyn = np.sort(np.concatenate((m * n + x, x[st] * n + m[st])))
            keys = np.sort(np.concatenate((keys, dyn)), kind="stable")  # merge of two sorted runs
        self.wkeys = keys
        if self.vrange < self.wrange:
            d = pos[keys // n] - pos[keys % n]
            self.vkeys = keys[np.einsum("ij,ij->i", d, d) <= self.vrange**2]
        else:
            self.vkeys = keys

    def _visual_in_range(self, keys: np.ndarray) -> np.ndarray:
        """Still in visual range? Only pairs involving a mobile robot can have left."""
        o, x = np.divmod(keys, self.n)
        inside = np.ones(len(keys), dtype=bool)
        mov = np.nonzero(self.moving[o] | self.moving[x])[0]
        d = self.positions[o[mov]] - self.positions[x[mov]]
        inside[mov] = np.einsum("ij,ij->i", d, d) <= self.vrange**2
        return inside

    def step(self, emit: np.ndarray, n_emit: int) -> None:
        n, q = self.n, self.q
        if self.mobile:
            self._move()
            self._update_pairs()
        wk, vk = self.wkeys, self.vkeys
        recv = wk[emit[wk % n]]
        vact = vk[emit[vk % n]]
        salt = None
        if q > 0.0:
            # counter-based miss draws, so that "was key k received?" has one answer per step
            salt = self.rng.integers(0, 2**63, size=2, dtype=np.uint64)
            recv = recv[_uniform_hash(recv, salt[0]) >= q]
            vact = vact[_uniform_hash(vact, salt[1]) >= q]

        def w_active(keys):
            o, x = np.divmod(keys, n)
            on = emit[x]
            mov = np.nonzero(on & (self.moving[o] | self.moving[x]))[0]
            if len(mov):  # stationary pairs tracked ⇒ in range
                d = self.positions[o[mov]] - self.positions[x[mov]]
                on[mov] = np.einsum("ij,ij->i", d, d) <= self.wrange**2
            if salt is not None:
                on &= _uniform_hash(keys, salt[0]) >= q
            return on

        def v_active(keys):  # tracked visual IDs are in range
            on = emit[keys % n]
            if salt is not None:
                on &= _uniform_hash(keys, salt[1]) >= q
            return on

        self.filter.step(recv, vact, self._visual_in_range, self.mobile, w_active=w_active, v_active=v_active)


_M1, _M2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)


def _uniform_hash(keys: np.ndarray, salt) -> np.ndarray:
    """Uniform [0, 1) numbers from (key, salt) by the splitmix64 finaliser (vectorised, wrapping)."""
    z = keys.astype(np.uint64) + np.uint64(salt)
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    z ^= z >> np.uint64(31)
    return (z >> np.uint64(11)).astype(np.float64) * (1.0 / 2**53)


def ring_positions(w: int, vis_robot: np.ndarray) -> np.ndarray:
    """Observer at the origin, visible neighbours inside the unit circle, the rest outside (render)."""
    ang = np.linspace(0.0, 2.0 * np.pi, w, endpoint=False)
    rad = np.where(np.isin(np.arange(1, w + 1), vis_robot), 0.7, 1.4)
    return np.concatenate(([[0.0, 0.0]], np.stack((rad * np.cos(ang), rad * np.sin(ang)), axis=1)))
