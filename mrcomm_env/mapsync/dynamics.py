"""MapSync's world as it changes over a step: links, obstacles that appear and vanish, the robots' walk and
sensing (§V-C), and how far the robots' maps disagree (the reward's term and Fig. 7's measure).

A mixin of :class:`mrcomm_env.mapsync.env.MapSyncEnv`, which owns the state; the attributes it reads and writes
are declared below. The numba twins of the walk and the sensing are chosen by the env at reset (``backend``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mrcomm_env.core import bernoulli_links, disk_links
from mrcomm_env.mapsync import world
from mrcomm_env.mapsync.sessions import _STALE_KNOWN, _STALE_NEW


class WorldDynamics:
    """Links, world changes, walking and sensing, and the maps' disagreement."""

    _change_world_compiled: Any
    _dirty: Any
    _disagreement_compiled: Any
    _disagreement_column: Any
    _disagreement_mean: Any
    _error_mean: Any
    _errors: Any
    _events: Any
    _eye: Any
    _map_version: Any
    _maps_flat: Any
    _neighbour_table: Any
    _neighbours: Any
    _no_keys: Any
    _pairs: Any
    _row_offsets: Any
    _sensed: Any
    _sensed_distinct: Any
    _stale: Any
    _stamps_flat: Any
    _static_links: Any
    _walk_and_sense: Any
    cfg: Any
    known: Any
    linked: Any
    maps: Any
    n: Any
    n_agents: Any
    new_cells: Any
    np_random: Any
    pos: Any
    size: Any
    stamps: Any
    truth: Any

    def _links(self) -> None:
        c, N = self.cfg, self.n_agents
        if self._static_links:
            return
        if c.comm_range is None:
            adj = ~self._eye
        else:
            ys, xs = np.divmod(self.pos, self.size)
            adj = disk_links(np.column_stack([xs, ys]).astype(np.float64), c.comm_range)
        if c.link_prob < 1.0:
            adj = adj & bernoulli_links(self.np_random, N, c.link_prob)
        self.linked = adj

    def _change_world(self) -> bool:
        """Obstacles appear on free, unoccupied cells and vanish, each cell independently (§I); returns whether
        any cell changed (the maps' errors against the world are recomputed only then)."""
        c, rng, truth = self.cfg, self.np_random, self.truth
        if self._change_world_compiled is not None:  # the same keys, drawn in one call (one stream)
            draws = rng.random(2 * self.n)
            return bool(self._change_world_compiled(truth, self.pos, draws, c.appear_rate, c.vanish_rate))
        occupied = np.zeros(self.n, dtype=bool)
        occupied[self.pos] = True
        appear = (~truth) & (~occupied) & (rng.random(self.n) < c.appear_rate)
        vanish = truth & (rng.random(self.n) < c.vanish_rate)
        truth[appear] = True
        truth[vanish] = False
        return bool(appear.any() or vanish.any())

    def _move_and_sense(self, stamp: int, walk: bool) -> None:
        """Every robot moves one step (when ``walk``), then senses its cell and the 4-neighbours (§V-C)."""
        if self._walk_and_sense is None:
            if walk:
                self.pos = world.random_walk(self.np_random, self.pos, self._neighbours, self.truth)
            self._sense(stamp)
            return
        keys = self.np_random.random((self.n_agents, 4)) if walk else self._no_keys  # as random_walk draws them
        self.pos, flags = self._walk_and_sense(
            walk,
            keys,
            self.pos,
            self._neighbour_table,
            self.truth,
            self._sensed,
            self._sensed_distinct,
            self.maps,
            self.stamps,
            self.known,
            self.new_cells,
            stamp,
        )
        if flags & 1:  # as _sense: a cell observed for the first time
            self._events += 1
            self._stale |= _STALE_KNOWN
        if flags & 2:  # a bit of a map changed
            self._dirty = True
            self._events += 1
            self._stale |= _STALE_NEW

    def _sense(self, stamp: int) -> None:
        """Numpy reference of the sensing (compiled twin: ``kernels_numba.walk_and_sense``)."""
        cells = self._sensed.take(self.pos, axis=0)  # (N, 5): off-grid neighbours repeat the own cell
        flat = cells + self._row_offsets  # into the flattened (N, n) maps and stamps
        seen = self.truth.take(cells)
        maps, stamps = self._maps_flat, self._stamps_flat
        changed = maps.take(flat) != seen
        before = stamps.take(flat)
        if before.min() < 0:  # a cell never observed before
            unseen = before < 0
            self.known += np.count_nonzero(unseen & self._sensed_distinct.take(self.pos, axis=0), axis=1)
            self._events += 1
            self._stale |= _STALE_KNOWN
        if changed.any():
            # own sensing changed these cells: new since the last sync with every peer
            self.new_cells += np.count_nonzero(changed & self._sensed_distinct.take(self.pos, axis=0), axis=1)[:, None]
            np.fill_diagonal(self.new_cells, 0)
            maps.put(flat, seen)
            self._dirty = True
            self._events += 1
            self._stale |= _STALE_NEW
        stamps.put(flat, stamp)

    def _update_disagreement(self) -> None:
        if not self._dirty:
            return
        self._dirty = False
        self._map_version += 1
        if self._disagreement_compiled is not None:
            rows, cols = self._pairs
            column, mean, errors, error_mean = self._disagreement_compiled(self.maps, self.truth, rows, cols)
            self._disagreement_column, self._disagreement_mean = column, float(mean)
            self._errors, self._error_mean = errors, float(error_mean)
            return
        maps = self.maps.astype(np.float64)
        ones = maps.sum(axis=1)
        ham = (ones[:, None] + ones[None, :] - 2.0 * (maps @ maps.T)) / self.n
        self._disagreement_column = ham.sum(axis=1) / (self.n_agents - 1)
        pairs = ham[self._pairs]
        self._disagreement_mean = float(pairs.sum()) / pairs.size  # what .mean() computes, without its overhead
        self._errors = (self.maps != self.truth).sum(axis=1) / self.n
        self._error_mean = float(self._errors.sum()) / self.n_agents
