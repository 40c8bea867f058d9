"""MapSync's walk, sensing, changing world, disagreement, observation and Protocol 1's inner products written in
numpy: the oracles of their compiled kernels.

The env computes each in one compiled call (``WorldDynamics._move_and_sense``, ``_change_world``,
``_update_disagreement``, ``MapSyncEnv._observe``, ``protocol.segment_inner_products``: ``kernels_numba``); these are the same steps (§I, §III, §V-C and
the module's observation table), kept here and not in the package (#44: one implementation in the package, the
reference under tests/). ``ReferenceMapSync`` steps whole episodes with them, and ``tests/mapsync/test_mapsync.py``
compares those, and each kernel, with the env's byte for byte."""

from __future__ import annotations

import numpy as np

from mrcomm_env.mapsync.env import MapSyncEnv
from mrcomm_env.mapsync.protocol import _FROM_BIT, _TO_BIT

#: the observation of last_test + 1: no test yet 0, different 1, same ½
TEST_CODE = np.array([0.0, 1.0, 0.5])


def random_walk(rng: np.random.Generator, pos: np.ndarray, neighbours: np.ndarray, blocked: np.ndarray) -> np.ndarray:
    """One step of every robot to a uniformly drawn free neighbour (stays when boxed in): one uniform key per
    (robot, direction), and the free neighbour with the largest key is taken, a uniform choice among the free ones.
    ``neighbours``: ``world.neighbour_table``."""
    keys = rng.random((pos.size, 4)).tolist()
    out = pos.copy()
    for i, here in enumerate(pos.tolist()):
        best, best_key = here, -1.0
        for cell, key in zip(neighbours[here].tolist(), keys[i]):
            if cell >= 0 and key > best_key and not blocked[cell]:
                best, best_key = cell, key
        out[i] = best
    return out


def reference_sense(env: MapSyncEnv, stamp: int) -> int:
    """Every robot senses its cell and its 4-neighbours (§V-C) into its map, stamps, coverage and new-cell counts, in
    place. Returns the kernel's flags: 1 = a cell observed for the first time, 2 = a bit of a map changed."""
    n_robots, n = env.maps.shape
    cells = env._sensed.take(env.pos, axis=0)  # (N, 5): off-grid neighbours repeat the own cell
    distinct = env._sensed_distinct.take(env.pos, axis=0)
    flat = cells + np.arange(n_robots)[:, None] * n  # into the flattened (N, n) maps and stamps
    seen = env.truth.take(cells)
    maps, stamps = env.maps.reshape(-1), env.stamps.reshape(-1)
    changed = maps.take(flat) != seen
    before = stamps.take(flat)
    flags = 0
    if before.min() < 0:  # a cell never observed before
        env.known += np.count_nonzero((before < 0) & distinct, axis=1)
        flags |= 1
    if changed.any():
        # own sensing changed these cells: new since the last sync with every peer
        env.new_cells += np.count_nonzero(changed & distinct, axis=1)[:, None]
        np.fill_diagonal(env.new_cells, 0)
        maps.put(flat, seen)
        flags |= 2
    stamps.put(flat, stamp)
    return flags


def reference_change_world(env: MapSyncEnv) -> bool:
    """Obstacles appear on free, unoccupied cells and vanish, each cell independently (§I): n appearance keys, then
    n vanishing keys from the env's generator. Returns whether any cell changed."""
    c, rng, truth = env.cfg, env.np_random, env.truth
    occupied = np.zeros(env.n, dtype=bool)
    occupied[env.pos] = True
    appear = (~truth) & (~occupied) & (rng.random(env.n) < c.appear_rate)
    vanish = truth & (rng.random(env.n) < c.vanish_rate)
    truth[appear] = True
    truth[vanish] = False
    return bool(appear.any() or vanish.any())


def reference_disagreement(env: MapSyncEnv) -> tuple[np.ndarray, float, np.ndarray, float]:
    """Each robot's mean Hamming distance to the others, the mean over pairs, each robot's error against the world
    and their mean: ``(column, mean, errors, error_mean)``."""
    maps = env.maps.astype(np.float64)
    ones = maps.sum(axis=1)
    ham = (ones[:, None] + ones[None, :] - 2.0 * (maps @ maps.T)) / env.n
    column = ham.sum(axis=1) / (env.n_agents - 1)
    pairs = ham[env._pairs]
    errors = (env.maps != env.truth).sum(axis=1) / env.n
    return column, float(pairs.sum()) / pairs.size, errors, float(errors.sum()) / env.n_agents


def reference_observation(env: MapSyncEnv) -> np.ndarray:
    """The module's observation table, every column: per peer j = i+1, i+2, … (mod N) the age of the last sync
    s/(s+10), new cells c/(c+10), the link and the last verdict; then recent bits b/(b+n), coverage, busy, the session's
    progress and the clock."""
    N, t = env.n_agents, env.step_count
    peers = env._peer_order
    rows = np.arange(N)[:, None]
    ages = t - env.last_sync[rows, peers]
    new = env.new_cells[rows, peers]
    per_peer = np.stack(
        [ages / (ages + 10.0), new / (new + 10.0), env.linked[rows, peers], TEST_CODE[env.last_test[rows, peers] + 1]],
        axis=-1,
    )
    progress = np.zeros(N)
    for s in env.sessions.values():
        progress[[s.alice, s.bob]] = s.sent / max(s.total, 1)
    own = np.column_stack(
        [
            env.recent_bits / (env.recent_bits + env.n),
            env.known / env.n,
            env.session_of >= 0,
            progress,
            np.full(N, min(t / env._horizon, 1.0)),
        ]
    )
    return np.concatenate([per_peer.reshape(N, -1), own], axis=1).astype(np.float32)


class ReferenceMapSync(MapSyncEnv):
    """MapSync whose walk, sensing, changing world, disagreement and observation are the numpy oracles above."""

    def _change_world(self) -> bool:
        return reference_change_world(self)

    def _move_and_sense(self, stamp: int, walk: bool) -> None:
        if walk:
            self.pos = random_walk(self.np_random, self.pos, self._neighbour_table, self.truth)
        flags = reference_sense(self, stamp)
        if flags & 1:
            self._events += 1
        if flags & 2:
            self._dirty = True
            self._events += 1

    def _update_disagreement(self) -> None:
        if not self._dirty:
            return
        self._dirty = False
        self._map_version += 1
        column, mean, errors, error_mean = reference_disagreement(self)
        self._disagreement_column, self._disagreement_mean = column, mean
        self._errors, self._error_mean = errors, error_mean

    def _observe(self) -> np.ndarray:
        return reference_observation(self)


def reference_inner_products(maps, strings, index, lo, hi) -> list[np.ndarray]:
    """``protocol.segment_inner_products`` in numpy: ``X[lo..hi] · r_i[lo..hi] mod 2`` for every packed map X, every
    segment s and each of its indices ``index[s, :]``, from the strings' words (``SharedStrings.words``)."""
    first, last = lo >> 5, hi >> 5
    span = last - first
    n_words = int(span.max()) + 1
    S, k = index.shape
    stacked = np.stack(maps)  # (M, W)
    if S == 1 and lo[0] == 0 and hi[0] == 32 * stacked.shape[1] - 1:
        seg = stacked[:, None, :]  # the whole map, a whole number of words: nothing to mask
    else:
        cols = first[:, None] + np.arange(n_words)[None, :]
        mask = np.where(cols <= last[:, None], np.uint32(0xFFFFFFFF), np.uint32(0))
        mask[:, 0] &= _FROM_BIT[lo & 31]
        mask[np.arange(S), span] &= _TO_BIT[hi & 31]
        seg = stacked[:, np.minimum(cols, stacked.shape[1] - 1)] & mask  # (M, S, n_words)
    r = strings.words(index.reshape(-1), np.repeat(first, k), n_words).reshape(S, k, n_words)
    counts = np.bitwise_count(r[None, :, :, :] & seg[:, :, None, :]).sum(axis=-1, dtype=np.int64)
    return list((counts & 1).astype(np.uint8))
