"""MapSync's world as it changes over a step: links, obstacles that appear and vanish, the robots' walk and
sensing (§V-C), and how far the robots' maps disagree (the reward's term and Fig. 7's measure).

A mixin of :class:`mrcomm_env.mapsync.env.MapSyncEnv`, which owns the state; the attributes it reads and writes
are declared below. The world's changes, the walk with the sensing and the disagreement are compiled
(``kernels_numba``); their numpy oracles are ``tests/helpers/mapsync_reference.py``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mrcomm_env.core import bernoulli_links, disk_links
from mrcomm_env.mapsync import kernels_numba


class WorldDynamics:
    """Links, world changes, walking and sensing, and the maps' disagreement."""

    _dirty: Any
    _disagreement_column: Any
    _disagreement_mean: Any
    _error_mean: Any
    _errors: Any
    _events: Any
    _eye: Any
    _map_version: Any
    _neighbour_table: Any
    _no_keys: Any
    _pairs: Any
    _sensed: Any
    _sensed_distinct: Any
    _static_links: Any
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
        any cell changed (the maps' errors against the world are recomputed only then). The keys are drawn in one
        call, 2n uniforms: n for appearing, then n for vanishing."""
        c = self.cfg
        draws = self.np_random.random(2 * self.n)
        return bool(kernels_numba.change_world(self.truth, self.pos, draws, c.appear_rate, c.vanish_rate))

    def _move_and_sense(self, stamp: int, walk: bool) -> None:
        """Every robot moves one step (when ``walk``) to a uniformly drawn free 4-neighbour (one uniform key per robot
        and direction, the largest key among the free ones wins; a boxed-in robot stays), then senses its cell and
        the 4-neighbours (§V-C)."""
        keys = self.np_random.random((self.n_agents, 4)) if walk else self._no_keys
        self.pos, flags = kernels_numba.walk_and_sense(
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
        if flags & 1:  # a cell observed for the first time
            self._events += 1
        if flags & 2:  # a bit of a map changed
            self._dirty = True
            self._events += 1

    def _update_disagreement(self) -> None:
        if not self._dirty:
            return
        self._dirty = False
        self._map_version += 1
        rows, cols = self._pairs
        column, mean, errors, error_mean = kernels_numba.disagreement(self.maps, self.truth, rows, cols)
        self._disagreement_column, self._disagreement_mean = column, float(mean)
        self._errors, self._error_mean = errors, float(error_mean)
