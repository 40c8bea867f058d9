"""Many trials at once: the environment's own filters driven directly, without the PettingZoo API.

The reproduction needs tens of thousands of neighbourhood trials (Fig. 5) and long mobile runs
(Figs 10–25). Going through ``env.step`` would spend its time on per-agent dictionaries, so these
drivers feed the *same* filter classes the environment runs (:mod:`.filters`) with batched inputs:

* :func:`neighborhood_trials` — B independent neighbourhoods as one ``(B, w, v)`` bit-set filter
  (Algorithm 1); wireless slot h is robot h, visual slot s is robot s (labels are arbitrary, the
  filter is symmetric under relabelling).
* :class:`MobileField` — a §5.4 field in which only the measured (mobile) robots run Algorithm 2 on
  the edge-list filter, with k-d tree neighbour queries; the other robots just emit.

``tests/channel_association/test_channel_association.py`` checks that these drivers reproduce the environment's
i-states.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from mrcomm_env.channel_association.filters import BitsetFilter, DenseFilter, SparseFilter
from mrcomm_env.channel_association.scenes import fast_coordinates, layout_field, move_and_bounce


def neighborhood_trials(
    w: int,
    v: int,
    trials: int,
    rng: np.random.Generator,
    p: float = 0.5,
    max_cycles: int = 400,
    track_fraction: int = 0,
):
    """Completion times of ``trials`` neighbourhoods (−1 if not final within ``max_cycles``).

    With ``track_fraction`` = T > 0 also returns the mean fraction matched at steps 0 … T.
    """
    f = BitsetFilter(trials, w, v) if w <= 64 else DenseFilter(trials, w, v)
    f.init_known(np.ones((trials, w), bool), np.ones((trials, v), bool))
    done = np.full(trials, -1, dtype=np.int64)
    frac = []
    matched, nv = f.stats()[:2]
    if v == w == 1:
        done[:] = 0
    if track_fraction:
        frac.append(float((matched / nv).mean()))
    t = 0
    while t < max(max_cycles if (done < 0).any() else 0, track_fraction):
        emit = rng.random((trials, w)) < p
        f.step(emit, emit[:, :v])
        t += 1
        matched, nv, ne, unres = f.stats()
        done[(done < 0) & (unres == 0)] = t
        if track_fraction and t <= track_fraction:
            frac.append(float((matched / nv).mean()))
    return (done, np.array(frac)) if track_fraction else done


class MobileField:
    """A §5.4 field where the robots in ``observers`` (default: the mobile ones) run Algorithm 2."""

    def __init__(
        self,
        rng: np.random.Generator,
        n: int,
        separation: float,
        mobile_fraction: float,
        speed: float,
        wireless_range: float,
        visual_range: float | None = None,
        drop_time: int = 20,
        p: float = 0.5,
        observers: np.ndarray | None = None,
    ):
        self.rng, self.n, self.p = rng, n, p
        self.pos, self.moving, self.size = layout_field(rng, n, separation, mobile_fraction)
        self.n_stat = n - int(self.moving.sum())
        heading = rng.uniform(0.0, 2.0 * np.pi, size=n - self.n_stat)
        self.vel = speed * np.stack((np.cos(heading), np.sin(heading)), axis=1)
        self.wr = float(wireless_range)
        self.vr = float(wireless_range if visual_range is None else visual_range)
        self.obs = np.nonzero(self.moving)[0] if observers is None else np.asarray(observers)
        self.filter = SparseFilter(n, drop_time, 0, self.wr > self.vr)
        self.filter.rng = rng

    def _move(self):
        move_and_bounce(self.pos[self.n_stat :], self.vel, self.size, fast_coordinates(self.vel, self.size))

    def _keys(self):
        """Sorted keys o*n + x of robots x within wireless range of each observer o (k-d tree)."""
        n = self.n
        lists = cKDTree(self.pos).query_ball_point(self.pos[self.obs], self.wr)
        cnt = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
        src = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists]) if len(lists) else np.zeros(0, np.int64)
        o = np.repeat(self.obs, cnt)
        keep = src != o
        keys = np.sort(o[keep] * n + src[keep])
        if self.vr < self.wr:
            d = self.pos[keys // n] - self.pos[keys % n]
            vkeys = keys[np.einsum("ij,ij->i", d, d) <= self.vr**2]
        else:
            vkeys = keys
        return keys, vkeys

    def in_visual_range(self, keys):
        d = self.pos[keys // self.n] - self.pos[keys % self.n]
        return np.einsum("ij,ij->i", d, d) <= self.vr**2

    def step(self, emit: np.ndarray | None = None) -> dict:
        """Move, emit (coin flips unless ``emit`` is given), filter; return measurements over the observers."""
        n = self.n
        self._move()
        if emit is None:
            emit = self.rng.random(n) < self.p
        wk, vk = self._keys()
        self.filter.step(wk[emit[wk % n]], vk[emit[vk % n]], self.in_visual_range, lists=True)
        f = self.filter
        matched, nv, ne, _ = f.stats()
        true = np.bincount(f.ev[f.ew % n == f.ev % n] // n, minlength=n)
        o = self.obs
        sel = nv[o] > 0
        new_v = np.bincount(f.new_vk // n, minlength=n)[o]
        in_range = np.bincount(vk // n, minlength=n)[o]
        return {
            "fraction_matched": float((matched[o][sel] / nv[o][sel]).mean()) if sel.any() else 0.0,
            "edge_ratio": float((ne[o][sel] / np.maximum(true[o][sel], 1)).mean()) if sel.any() else 1.0,
            "new_v": new_v,
            "in_range": float(in_range.mean()),
        }
