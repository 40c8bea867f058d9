"""The robots' association filters: Algorithm 1 (stationary) and Algorithm 2 (mobile) of Ivanov & Shell.

Each observer keeps an *i-state* (Def. 6): a bipartite graph between the wireless IDs it tracks and
the visual IDs it tracks, stored as a w×v 0/1 matrix. Every step it multiplies the i-state element-wise
by the observation matrix (cell [h][s] is 1 when wireless ID h and visual ID s had the same activity,
Algorithm 1 line 15–16). In mobile scenes the list operations of Algorithm 2 run first: visual IDs that
left the range are removed, wireless IDs silent for ``drop_time`` steps are dropped, new (active) IDs
are added and edges are added between every new wireless and every new visual ID — plus, when the
wireless range exceeds the visual range, between every new visual ID and every old, active, not yet
associated wireless ID (§5.2).

Two storage backends with identical semantics (the tests check they agree step by step):

* :class:`DenseFilter` — a batch of observers with fixed slots, arrays of shape ``(B, W, V)``. The
  environment uses it for small populations (slot = robot index) and the reproduction uses it for
  thousands of independent neighbourhood trials at once (slot = position in the neighbourhood).
* :class:`SparseFilter` — an edge list keyed by ``observer * n + robot`` for large fields, so memory
  and time scale with the number of edges rather than with N³.

Both see only what the observer senses: which wireless IDs were received and which visual tracks lit
up. The robot index behind a visual track is the tracker's handle (the observer's own label for it is
drawn locally); the filter never compares it with a wireless ID.

Noisy channels (§6.3, ``miss_probability``): with misses a *true* edge can be eliminated. Two things
keep that from going wrong silently. (1) ``tolerance`` k: an edge is eliminated only after more than k
disagreeing observations (k = 0 is Algorithm 1's element-wise product exactly). (2) Conflict repair:
a tracked visual ID left with no candidate is a detected contradiction; the next time its light is
seen it is re-opened with an edge to every tracked wireless ID received in that step, and the
``conflicts`` counter grows. Besides misses, this also repairs two cases Algorithm 2 leaves open even
on a perfect channel: a robot that re-enters range before its wireless ID was dropped (its visual ID
is new, its wireless ID is old, so no new×new edge can be true) and a wireless ID dropped while its
robot is still in range (silent for ``drop_time`` steps). A wrong *unique* match cannot be detected locally; the environment measures it against the
ground truth (metric ``fraction_wrong``).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class AssociationFilter(Protocol):
    """What the environment (and the batch drivers) need from a store of observers' i-states.

    A filter keeps B observers' i-states. It addresses wireless and visual IDs by *slot*: an index the
    caller chose (the robot index in a field, the position in a neighbourhood); the scene that drives
    the filter knows which robot a slot is. Sensed data is passed in the filter's own representation:
    (B, W) / (B, V) 0/1 masks for the slot-per-robot filters (:class:`DenseFilter`,
    :class:`BitsetFilter`, which also takes its native packed rows), sorted keys ``observer * n + robot``
    for :class:`SparseFilter`. Implementations may accept further keyword-only arguments that only save
    time and must agree with the positional ones.
    """

    drop_time: int
    tolerance: int
    extra_edges: bool
    #: draws the observers' local visual labels (the environment passes its own generator)
    rng: np.random.Generator
    #: tracked visual IDs found with no candidate and re-opened, so far
    conflicts: int
    #: wireless + visual IDs added in the last step, per observer (Algorithm 2's addNew…IDs)
    new_ids: np.ndarray

    def init_known(self, wireless: Any, visual: Any) -> None:
        """Algorithm 1's start: the neighbourhood is known, every wireless × visual pair is an edge."""

    def step(self, recv: Any, vact: Any, v_in: Any = None, lists: bool = False) -> None:
        """One time step: ``recv`` wireless messages received, ``vact`` lights seen, ``v_in`` visual IDs
        still in range (needed only for Algorithm 2's list operations, ``lists``)."""

    def stats(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(matched, visual IDs, edges, unresolved) per observer; matched = visual IDs with one candidate."""

    def stats_key(self) -> Any:
        """A value equal between two calls iff :meth:`stats` and ``new_ids`` may not have changed, or
        None when the filter offers no such shortcut."""

    def edges(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(observer, wireless slot, visual slot) of every edge of the i-states."""

    def matches(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(observer, wireless slot, visual slot) of every unique match (a visual ID with one candidate)."""

    def candidates(self, observer: int) -> dict[int, list[int]]:
        """One observer's i-state: its own visual label → candidate wireless slots (ascending)."""


class FilterBase:
    """Settings every filter shares (Algorithm 2's ``drop_time``, §6.3's ``tolerance``, §5.2's extra
    edges) and the generator of local visual labels."""

    def __init__(self, drop_time: int = 20, tolerance: int = 0, extra_edges: bool = False):
        self.drop_time = int(drop_time)
        self.tolerance = int(tolerance)
        self.extra_edges = bool(extra_edges)
        self._rng: np.random.Generator | None = None

    @property
    def rng(self) -> np.random.Generator:
        """The generator of local visual labels: its owner's (a scene hands in the env's), else one seeded 0, made on
        first use (a scene's new filter every episode would otherwise make one for nothing)."""
        if self._rng is None:
            self._rng = np.random.default_rng(0)
        return self._rng

    @rng.setter
    def rng(self, generator: np.random.Generator) -> None:
        self._rng = generator


class DenseFilter(FilterBase):
    """A batch of B observers, each with W wireless and V visual slots (i-state ``E[b, h, s]``)."""

    def __init__(
        self, batch: int, n_w: int, n_v: int, drop_time: int = 20, tolerance: int = 0, extra_edges: bool = False
    ):
        super().__init__(drop_time, tolerance, extra_edges)
        self.shape = (batch, n_w, n_v)
        self.reset()

    def pack(self, mask: np.ndarray) -> np.ndarray:
        """A (…, W) mask of wireless slots in the representation :meth:`step` takes (the mask itself)."""
        return mask

    def reset(self) -> None:
        b, w, v = self.shape
        self.E = np.zeros(self.shape, dtype=bool)  # alive edges (the 0/1 i-state)
        self.D = np.zeros(self.shape, dtype=np.uint8) if self.tolerance else None  # disagreements
        self.wt = np.zeros((b, w), dtype=bool)  # tracked wireless IDs
        self.idle = np.zeros((b, w), dtype=np.int32)  # steps since last reception
        self.vt = np.zeros((b, v), dtype=bool)  # tracked visual IDs
        self.deg = np.zeros((b, v), dtype=np.int32)  # candidates per visual ID
        self.vlabel = np.full((b, v), -1, dtype=np.int64)  # the observer's own label of each visual ID
        self.new_ids = np.zeros(b, dtype=np.int32)  # IDs added this step
        self.conflicts = 0

    def init_known(self, w_mask: np.ndarray, v_mask: np.ndarray) -> None:
        """Algorithm 1's start: the neighbourhood is known, every wireless–visual pair is an edge."""
        self.reset()
        self.wt[:] = w_mask
        self.vt[:] = v_mask
        self.vlabel[v_mask] = self.rng.integers(0, 2**31, size=int(v_mask.sum()))
        np.logical_and(w_mask[:, :, None], v_mask[:, None, :], out=self.E)
        self.deg = self.E.sum(1, dtype=np.int32)

    def step(self, recv: np.ndarray, vact: np.ndarray, v_in: np.ndarray | None = None, lists: bool = False) -> None:
        """One time step. ``recv`` (B, W): wireless message received; ``vact`` (B, V): light seen;
        ``v_in`` (B, V): visual ID in range (needed for Algorithm 2's list operations)."""
        E = self.E
        if lists:
            self.new_ids[:] = 0
            lost = self.vt & ~v_in
            if lost.any():  # removeVisIDs (Alg. 2 line 20)
                self.vt &= ~lost
                E &= ~lost[:, None, :]
            self.idle += 1
            self.idle[recv] = 0
            np.minimum(self.idle, self.drop_time, out=self.idle)  # bounded counters
            drop = self.wt & (self.idle >= self.drop_time)
            if drop.any():  # removeWifiIDs (line 21)
                self.wt &= ~drop
                E &= ~drop[:, :, None]
            newv = vact & ~self.vt  # addNewVisIDs: only once active (§5.2)
            neww = recv & ~self.wt  # addNewWifiIDs
            anyv = newv.any()
            if anyv or neww.any():
                self.new_ids[:] = newv.sum(1) + neww.sum(1)
            if anyv:
                add = neww[:, :, None] & newv[:, None, :]  # new W × new V (line 27)
                if self.extra_edges:  # §5.2: wireless range > visual range
                    deg_now = E.sum(1, dtype=np.int32)
                    assoc = (E & (deg_now == 1)[:, None, :]).any(2)
                    old_free = recv & self.wt & ~assoc
                    add |= old_free[:, :, None] & newv[:, None, :]
                E |= add
                if self.D is not None:
                    self.D[add] = 0
                self.vt |= newv
                self.vlabel[newv] = self.rng.integers(0, 2**31, size=int(newv.sum()))
            self.wt |= neww
        # observation update (Alg. 1 lines 15–16): keep edges whose two IDs agree
        mismatch = recv[:, :, None] != vact[:, None, :]
        if self.D is None:
            E &= ~mismatch
        else:
            D = self.D
            D += mismatch & E
            E &= D <= self.tolerance
        deg = E.sum(1, dtype=np.int32)
        empty = self.vt & (deg == 0) & vact
        if empty.any():  # detected contradiction: re-open when lit
            cand = (self.wt & recv)[:, :, None] & empty[:, None, :]
            E |= cand
            if self.D is not None:
                self.D[cand] = 0
            self.conflicts += int(empty.sum())
            deg = E.sum(1, dtype=np.int32)
        self.deg = deg

    # ------------------------------------------------------------------ statistics per observer
    def stats(self):
        """(matched, n_visual, n_edges, unresolved) per observer; matched = visual IDs with one candidate."""
        one = (self.deg == 1) & self.vt
        matched = one.sum(1)
        nv = self.vt.sum(1)
        ne = self.deg.sum(1)
        return matched, nv, ne, nv - matched

    def stats_key(self):
        # the statistics are functions of (candidates per visual ID, tracked visual IDs, new IDs)
        return self.deg.tobytes(), self.vt.tobytes(), self.new_ids.tobytes()

    def edges(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.nonzero(self.E)

    def matches(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(observer, wireless slot, visual slot) of every unique match."""
        one = (self.deg == 1) & self.vt
        b, h, s = np.nonzero(self.E & one[:, None, :])
        return b, h, s

    def candidates(self, observer: int) -> dict[int, list[int]]:
        E = self.E[observer]
        return {
            int(self.vlabel[observer, s]): np.nonzero(E[:, s])[0].tolist() for s in np.nonzero(self.vt[observer])[0]
        }


# ====================================================================== sparse backend
def _isin_sorted(sorted_keys: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Membership of ``queries`` in the sorted array ``sorted_keys`` (binary search)."""
    if len(sorted_keys) == 0:
        return np.zeros(len(queries), dtype=bool)
    idx = np.searchsorted(sorted_keys, queries)
    idx[idx == len(sorted_keys)] = 0
    return sorted_keys[idx] == queries


def _search_grouped(sorted_keys: np.ndarray, queries: np.ndarray, side: str = "left") -> np.ndarray:
    """``np.searchsorted(sorted_keys, queries, side)`` for sorted ``queries`` with long runs of equal
    values (edges grouped by visual key): each distinct value is searched once and its index repeated."""
    if len(queries) == 0:
        return np.searchsorted(sorted_keys, queries, side)
    first = np.empty(len(queries), dtype=bool)
    first[0] = True
    np.not_equal(queries[1:], queries[:-1], out=first[1:])
    start = np.flatnonzero(first)
    idx = np.searchsorted(sorted_keys, queries[start], side)
    return np.repeat(idx, np.diff(np.append(start, len(queries))))


def _cross_by_group(gid_a: np.ndarray, gid_b: np.ndarray, n_groups: int):
    """All pairs (i, j) with gid_a[i] == gid_b[j]; both inputs sorted by group id."""
    if len(gid_a) == 0 or len(gid_b) == 0:
        e = np.zeros(0, dtype=np.int64)
        return e, e
    cnt_b = np.bincount(gid_b, minlength=n_groups)
    start_b = np.concatenate(([0], np.cumsum(cnt_b)[:-1]))
    reps = cnt_b[gid_a]
    total = int(reps.sum())
    if total == 0:
        e = np.zeros(0, dtype=np.int64)
        return e, e
    i = np.repeat(np.arange(len(gid_a)), reps)
    first = np.cumsum(reps) - reps  # ragged arange: offset within each run
    j = np.arange(total) + np.repeat(start_b[gid_a] - first, reps)  # start_b[gid_a[i]] + (k − first[i])
    return i, j


class SparseFilter(FilterBase):
    """Edge-list filter for many observers in a population of ``n`` robots (keys ``o * n + x``).

    Slots are robot indices: observer o's wireless and visual slot x is robot x."""

    def __init__(self, n: int, drop_time: int = 20, tolerance: int = 0, extra_edges: bool = False):
        super().__init__(drop_time, tolerance, extra_edges)
        self.n = int(n)
        self.reset()

    def reset(self) -> None:
        z = np.zeros(0, dtype=np.int64)
        self.vlab = z.copy()  # local labels, aligned with vk
        self.wk, self.idle = z.copy(), np.zeros(0, dtype=np.int32)  # tracked wireless keys (sorted)
        self.vk = z.copy()  # tracked visual keys (sorted)
        self.ew, self.ev = z.copy(), z.copy()  # edges: wireless key, visual key
        self.ed = np.zeros(0, dtype=np.uint8)  # disagreements per edge
        self.vdeg = np.zeros(0, dtype=np.int64)
        self.vidx = z.copy()  # edge → index of its visual key
        self.new_ids = np.zeros(self.n, dtype=np.int64)
        self.new_vk = z.copy()
        self.conflicts = 0

    def init_known(self, w_keys: np.ndarray, v_keys: np.ndarray) -> None:
        """Algorithm 1's start for every observer: all wireless × all visual IDs in range."""
        self.reset()
        n = self.n
        self.wk = np.unique(w_keys)
        self.idle = np.zeros(len(self.wk), dtype=np.int32)
        self.vk = np.unique(v_keys)
        self.vlab = self.rng.integers(0, 2**31, size=len(self.vk))
        i, j = _cross_by_group(self.vk // n, self.wk // n, n)
        self._set_edges(self.wk[j], self.vk[i])

    def _set_edges(self, ew, ev):
        # _cross_by_group over the sorted key lists yields the edges sorted by (visual key, wireless key)
        # already: grouped by visual key as the other methods need, without a sort of N·w·v keys
        self.ew, self.ev = ew, ev
        self.ed = np.zeros(len(self.ew), dtype=np.uint8)
        self.vidx = _search_grouped(self.vk, self.ev)
        self.vdeg = np.bincount(self.vidx, minlength=len(self.vk))

    def _keep_edges(self, keep):
        self.ew, self.ev, self.ed = self.ew[keep], self.ev[keep], self.ed[keep]

    def step(
        self,
        recv_keys: np.ndarray,
        vact_keys: np.ndarray,
        v_in=None,
        lists: bool = False,
        *,
        w_active=None,
        v_active=None,
    ) -> None:
        """``recv_keys``: sorted keys o*n+a of received wireless messages; ``vact_keys``: sorted keys o*n+b
        of visual IDs whose light was seen; ``v_in(keys) -> bool``: visual IDs still in range.
        ``w_active(keys) -> bool`` may answer "was this wireless message received?" for any keys faster
        than a search in ``recv_keys`` (it must agree with ``recv_keys``); ``v_active`` likewise for
        tracked, in-range visual IDs and ``vact_keys``."""
        n = self.n
        if w_active is None:
            w_active = lambda k: _isin_sorted(recv_keys, k)  # noqa: E731
        if lists:
            self.new_ids[:] = 0
            if len(self.vk):  # removeVisIDs
                inside = v_in(self.vk)
                if not inside.all():
                    self.vk, self.vlab = self.vk[inside], self.vlab[inside]
                    self._keep_edges(inside[self.vidx])  # vidx: edge → visual entry
            wact = w_active(self.wk)  # removeWifiIDs after drop_time silence
            self.idle += 1
            self.idle[wact] = 0
            keep = self.idle < self.drop_time
            if not keep.all():
                gone = self.wk[~keep]
                self.wk, self.idle, wact = self.wk[keep], self.idle[keep], wact[keep]
                self._keep_edges(~_isin_sorted(gone, self.ew))  # few dropped keys: a cheap search
            newv = vact_keys[~_isin_sorted(self.vk, vact_keys)]
            neww = recv_keys[~_isin_sorted(self.wk, recv_keys)]
            self.new_vk = newv
            if len(newv) or len(neww):
                self.new_ids += np.bincount(newv // n, minlength=n) + np.bincount(neww // n, minlength=n)
            if len(newv):
                i, j = _cross_by_group(newv // n, neww // n, n)  # new W × new V
                add_v, add_w = [newv[i]], [neww[j]]
                if self.extra_edges and len(self.wk):
                    # §5.2: old, active, not yet associated wireless IDs also get an edge to new visual IDs
                    vidx = _search_grouped(self.vk, self.ev)
                    deg_now = np.bincount(vidx, minlength=len(self.vk))
                    sole = self.ew[deg_now[vidx] == 1]
                    free = wact & ~_isin_sorted(np.unique(sole), self.wk)
                    old = self.wk[free]
                    i2, j2 = _cross_by_group(newv // n, old // n, n)
                    add_v.append(newv[i2])
                    add_w.append(old[j2])
                # merge the tracked visual list, then the edge list (kept grouped by visual key)
                at = np.searchsorted(self.vk, newv)
                self.vk = np.insert(self.vk, at, newv)
                self.vlab = np.insert(self.vlab, at, self.rng.integers(0, 2**31, size=len(newv)))
                self._append_edges(np.concatenate(add_w), np.concatenate(add_v))
            if len(neww):
                at = np.searchsorted(self.wk, neww)
                self.wk = np.insert(self.wk, at, neww)
                self.idle = np.insert(self.idle, at, np.zeros(len(neww), dtype=np.int32))
        # observation update: keep edges whose wireless and visual IDs had the same activity
        vidx = _search_grouped(self.vk, self.ev)
        v_on = _isin_sorted(vact_keys, self.vk) if v_active is None else v_active(self.vk)
        mismatch = w_active(self.ew) != v_on[vidx]
        if self.tolerance == 0:
            keep = ~mismatch
        else:
            self.ed = self.ed + mismatch.astype(np.uint8)
            keep = self.ed <= self.tolerance
        self._keep_edges(keep)
        vidx = vidx[keep]
        deg = np.bincount(vidx, minlength=len(self.vk))
        empty = (deg == 0) & v_on
        if empty.any():  # detected contradiction: re-open when lit
            ek = self.vk[empty]
            i, j = _cross_by_group(ek // n, self.wk // n, n)
            ok = w_active(self.wk[j])
            self.conflicts += int(empty.sum())
            self._append_edges(self.wk[j[ok]], ek[i[ok]])
            vidx = _search_grouped(self.vk, self.ev)
            deg = np.bincount(vidx, minlength=len(self.vk))
        self.vidx = vidx
        self.vdeg = deg

    def _append_edges(self, ew, ev):
        """Insert new edges keeping the list grouped (sorted) by visual key — a merge, not a re-sort."""
        if len(ev) > 1 and not (ev[1:] >= ev[:-1]).all():  # often sorted already (new W × new V)
            order = np.argsort(ev, kind="stable")
            ew, ev = ew[order], ev[order]
        # each new edge goes after the old edges of its visual key and the new ones before it (what
        # np.insert at searchsorted(side="right") does); the positions serve all three arrays
        at = _search_grouped(self.ev, ev, side="right") + np.arange(len(ev))
        old = np.ones(len(self.ev) + len(ev), dtype=bool)
        old[at] = False
        self.ew = _merged(self.ew, old, at, ew)
        self.ev = _merged(self.ev, old, at, ev)
        self.ed = _merged(self.ed, old, at, 0)

    # ------------------------------------------------------------------ statistics per observer
    def stats(self):
        n = self.n
        vo = self.vk // n
        matched = np.bincount(vo[self.vdeg == 1], minlength=n)
        nv = np.bincount(vo, minlength=n)
        ne = np.bincount(vo, weights=self.vdeg, minlength=n).astype(np.int64)
        return matched, nv, ne, nv - matched

    def stats_key(self):
        return None  # the statistics are cheap next to a step

    def edges(self):
        n = self.n
        return self.ev // n, self.ew % n, self.ev % n

    def matches(self):
        """(observer, wireless robot, visual robot) of every unique match."""
        n = self.n
        vidx = _search_grouped(self.vk, self.ev)
        sel = self.vdeg[vidx] == 1
        return self.ev[sel] // n, self.ew[sel] % n, self.ev[sel] % n

    def candidates(self, observer: int) -> dict[int, list[int]]:
        n = self.n
        lo, hi = np.searchsorted(self.vk, [observer * n, (observer + 1) * n])
        out = {}
        for key, lab in zip(self.vk[lo:hi], self.vlab[lo:hi], strict=True):
            a, b = np.searchsorted(self.ev, [key, key + 1])
            out[int(lab)] = sorted((self.ew[a:b] % n).tolist())
        return out


def _merged(old_values: np.ndarray, old: np.ndarray, at: np.ndarray, new_values) -> np.ndarray:
    """The array with ``old_values`` where ``old`` is set and ``new_values`` at positions ``at``."""
    out = np.empty(len(old), dtype=old_values.dtype)
    out[old] = old_values
    out[at] = new_values
    return out


# ====================================================================== bit-set backend
_ONE = np.uint64(1)
_ZERO = np.uint64(0)
_U64 = np.dtype(np.uint64)


#: the most wireless slots a bit set holds (one ``uint64`` per visual ID)
BITSET_MAX_W = 64
_POW2 = _ONE << np.arange(BITSET_MAX_W, dtype=np.uint64)


def pack_rows(mask: np.ndarray) -> np.ndarray:
    """(B, W ≤ 64) bool → (B,) uint64 with bit h set when ``mask[:, h]``."""
    return mask @ _POW2[: mask.shape[-1]]


class BitsetFilter(FilterBase):
    """:class:`DenseFilter` with each visual ID's candidate column packed into one ``uint64``.

    The i-state of observer b is ``C[b, s]`` — bit h set when wireless slot h is still a candidate for
    visual slot s — so the element-wise product of Algorithm 1 is one AND per visual ID and counting
    candidates is a popcount. Requires W ≤ 64 and ``tolerance`` 0 (the counts of a tolerant filter
    do not fit in one bit); the environment falls back to :class:`DenseFilter` otherwise.
    """

    def __init__(self, batch: int, n_w: int, n_v: int, drop_time: int = 20, extra_edges: bool = False):
        if n_w > BITSET_MAX_W:
            raise ValueError(f"BitsetFilter holds at most {BITSET_MAX_W} wireless slots, got {n_w}")
        super().__init__(drop_time, 0, extra_edges)
        self.shape = (batch, n_w, n_v)
        self._bits = np.arange(n_w, dtype=np.uint64)
        #: 2^k of slot k: ``mask @ powers`` packs a (…, n_w) boolean mask into the bit sets the rows hold
        self.powers = _POW2[:n_w]
        self._ones8, self._ones16 = np.ones(n_v, dtype=np.uint8), np.ones(n_v, dtype=np.uint16)
        self.reset()

    def reset(self) -> None:
        b, w, v = self.shape
        self.C = np.zeros((b, v), dtype=np.uint64)  # candidate wireless slots per visual ID
        self.wt = np.zeros(b, dtype=np.uint64)  # tracked wireless slots (bit set)
        # receptions of the last drop_time steps (a ring of bit sets): silent that long → dropped
        self.heard = np.zeros((self.drop_time, b), dtype=np.uint64)
        self.t = 0
        self.vt = np.zeros((b, v), dtype=bool)
        self.deg = np.zeros((b, v), dtype=np.uint8)
        self.vlabel = np.full((b, v), -1, dtype=np.int64)
        self.new_ids = np.zeros(b, dtype=np.int64)
        self.conflicts = 0

    def pack(self, mask: np.ndarray) -> np.ndarray:
        """A (…, W) mask of wireless slots as the bit sets :meth:`step` takes natively (``pack_rows``)."""
        return mask @ self.powers

    @property
    def E(self) -> np.ndarray:
        """The i-state as the paper's (B, W, V) 0/1 matrix."""
        return ((self.C[:, None, :] >> self._bits[None, :, None]) & _ONE).astype(bool)

    def init_known(self, w_mask: np.ndarray, v_mask: np.ndarray) -> None:
        self.reset()
        self.wt = pack_rows(w_mask)
        self.vt[:] = v_mask
        self.C[:] = np.where(v_mask, self.wt[:, None], 0)
        self.vlabel[v_mask] = self.rng.integers(0, 2**31, size=int(v_mask.sum()))
        self.deg = np.bitwise_count(self.C)

    def step(self, recv: np.ndarray, vact: np.ndarray, v_in: np.ndarray | None = None, lists: bool = False) -> None:
        """As :meth:`DenseFilter.step`; ``recv`` may also be given packed, as the (B,) ``uint64`` bit
        sets of :meth:`pack`.

        The arrays are tiny in the environment (N ≤ 64), so the cost is the number of numpy calls:
        the code keeps that low (one-call comparisons, tests that skip rare work). Invariant: the
        column of an untracked visual ID is 0."""
        R = recv if recv.dtype == _U64 else recv @ self.powers
        C, vt = self.C, self.vt
        if lists:
            lost = np.greater(vt, v_in)  # tracked but out of range
            if np.count_nonzero(lost):  # removeVisIDs: the column goes
                vt &= v_in
                C[lost] = 0
            self.heard[self.t % self.drop_time] = R
            self.t += 1
            D = self.wt & ~np.bitwise_or.reduce(self.heard, axis=0)
            if np.count_nonzero(D):  # removeWifiIDs
                self.wt &= ~D
                C &= ~D[:, None]
            newv = np.greater(vact, vt)  # lit, not tracked: addNewVisIDs
            NW = R & ~self.wt
            if np.count_nonzero(newv):
                add = NW
                if self.extra_edges:  # §5.2: + old, active, unassociated wireless IDs
                    deg = np.bitwise_count(C)
                    assoc = np.bitwise_or.reduce(np.where((deg == 1) & vt, C, _ZERO), axis=1)
                    add = add | (R & self.wt & ~assoc)
                C |= np.where(newv, add[:, None], 0)
                vt |= newv
                self._label_new(newv)
                self.new_ids = newv.sum(1) + np.bitwise_count(NW)
            else:
                self.new_ids = np.bitwise_count(NW)
            self.wt |= NW
        # Algorithm 1: element-wise product. Untracked columns are 0 and stay 0; a tracked one keeps the
        # received wireless IDs if it was lit, the silent ones if it was dark.
        C &= np.where(vact, R[:, None], ~R[:, None])
        deg = np.bitwise_count(C)
        # a tracked visual ID without candidates is rare: while every tracked one has some (untracked
        # ones have none), the two counts agree and there is nothing to look for
        if np.count_nonzero(deg) < np.count_nonzero(vt):
            empty = (deg == 0) & vact  # lit ⇒ tracked, so no vt term needed
            if np.count_nonzero(empty):  # detected contradiction: re-open when lit
                C |= np.where(empty, (self.wt & R)[:, None], 0)
                self._count_conflicts(empty)
                deg = np.bitwise_count(C)
        self.deg = deg

    # the two places where observers are not independent rows: one generator draws the labels, one counter
    # sums the conflicts. A batch of copies (copy_axis.py) overrides them per copy; the rows stay the same code.
    def _label_new(self, newv: np.ndarray) -> None:
        """The observer's own random labels of the visual IDs ``newv`` (B, V) it starts tracking."""
        self.vlabel[newv] = self.rng.integers(0, 2**31, size=int(newv.sum()))

    def _count_conflicts(self, empty: np.ndarray) -> None:
        self.conflicts += int(empty.sum())

    def stats(self):
        # row sums as small unsigned mat-vec products (fast for the tiny arrays of the hot path):
        # counts ≤ 64 fit in uint8, edges ≤ 64·64 in uint16; matched ≤ nv (untracked columns are empty)
        deg = self.deg
        matched = (deg == 1).view(np.uint8) @ self._ones8
        nv = self.vt.view(np.uint8) @ self._ones8
        ne = deg @ self._ones16
        return matched, nv, ne, nv - matched

    def stats_key(self):
        return self.deg.tobytes(), self.vt.tobytes(), self.new_ids.tobytes()

    def edges(self):
        return np.nonzero(self.E)

    def matches(self):
        one = (self.deg == 1) & self.vt
        b, s = np.nonzero(one)
        h = np.log2(self.C[b, s].astype(np.float64)).astype(np.int64) if len(b) else np.zeros(0, np.int64)
        return b, h, s

    def candidates(self, observer: int) -> dict[int, list[int]]:
        column_bits = (self.C[observer][None, :] >> self._bits[:, None]) & _ONE  # (W, V), as E[observer]
        return {
            int(self.vlabel[observer, s]): np.nonzero(column_bits[:, s])[0].tolist()
            for s in np.nonzero(self.vt[observer])[0]
        }
