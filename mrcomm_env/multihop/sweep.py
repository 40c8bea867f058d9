"""Monte-Carlo propagation-time sweeps on the stationary grid (Fig. 2), batched over random slot orders.

The per-slot loop drives the same :mod:`protocol` functions the env and the baselines use, with a batch
axis over ``B`` independent runs (each its own random TDMA order, §4). Selection happens *at the slot*,
exactly as in Algorithm 1 (the env's policies plan at the frame start, see ``env.py``).

Two readings of "propagation time" (the paper does not say which it measured):

* **cold start** — every robot starts knowing only itself; the time (s) from the start until every
  member of the subgraph holds *an* estimate of every other member;
* **fresh stamp, steady state** — after the cold start plus ``warm_frames`` frames, at a frame boundary
  ``t0``: the time (s) until every member holds an estimate of every other member stamped ``>= t0``.

Each reading is reported as the paper's "all members" time (max over the subgraph's ordered pairs) and
as the mean over pairs. Times are seconds for ``b`` bits at ``r_b`` baud (one estimate takes ``b / r_b`` s; 64 ms at 192 bits
and 3000 baud). Both readings scale with ``b / r_b``, so percentages do not depend on them.
"""

from __future__ import annotations

import numpy as np

from mrcomm_env.core.comm import grid_links
from mrcomm_env.multihop import protocol as proto
from mrcomm_env.multihop import theory

SELECTORS = ("text", "listing", "probabilistic", "age_aware")


def _neighbour_table(adj: np.ndarray) -> np.ndarray:
    """(n, K) receivers of each sender, padded with the dummy row index n."""
    n = len(adj)
    k = int(adj.sum(axis=1).max())
    table = np.full((n, k), n, dtype=np.int64)
    for i in range(n):
        nb = np.flatnonzero(adj[i])
        table[i, : nb.size] = nb
    return table


class GridSim:
    """B runs of the stationary grid, each with its own random slot order, advanced slot by slot."""

    def __init__(
        self,
        side: int,
        m: int,
        runs: int,
        seed: int,
        selector: str = "text",
        alpha: float = 1.0,
        bits: float = 192,
        baud: float = 3000.0,
    ):
        if selector not in SELECTORS:
            raise ValueError(f"selector must be one of {SELECTORS}, got {selector!r}")
        n = side * side
        self.n, self.m, self.runs, self.selector = n, m, runs, selector
        self.nbr = _neighbour_table(grid_links(side))
        r = np.arange(n)
        pos = np.column_stack([r % side, r // side]).astype(np.float64)
        dist = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
        self.fmat = proto.importance(dist, np.ones((n, n), dtype=bool), alpha)
        self.rng = np.random.default_rng(seed)
        self.orders = np.stack([self.rng.permutation(n) for _ in range(runs)])
        self.bi = np.arange(runs)
        self.stamps = np.full((runs, n + 1, n), proto.UNKNOWN)  # row n: dummy receiver (padding)
        self.stamps[:, r, r] = 0.0
        self.counters = np.ones((runs, n, n))
        self.sent = np.full((runs, n, n), -n * self.slot_len(m, bits, baud))  # as the env: never sent = stamp -T_frame
        self.slot = self.slot_len(m, bits, baud)
        self.t = 0.0

    @staticmethod
    def slot_len(m, bits, baud) -> float:
        return theory.slot_duration(m, bits, baud)

    def select(self, s: np.ndarray) -> np.ndarray:
        """Selection mask (B, n) of the senders ``s`` (B,), at the slot (Algorithm 1 / eq. 2 / ours)."""
        bi, m = self.bi, self.m
        row = self.stamps[bi, s]
        known = row > proto.UNKNOWN
        f = np.where(known, self.fmat[s], 0.0)
        if self.selector == "probabilistic":
            order = proto.probabilistic_select(self.rng, f, known, s, m)
        elif self.selector == "age_aware":
            order = proto.age_aware_select(f, row, self.sent[bi, s], known, s, m)
        else:
            c = self.counters[bi, s]
            order = proto.location_based_select(c, f, known, s, m, self.selector)
            self.counters[bi, s] = c
        sel = proto.order_to_mask(order, self.n)
        if self.selector == "age_aware":
            self.sent[bi, s] = np.where(sel, row, self.sent[bi, s])
        return sel

    def frame(self, arrival: np.ndarray | None = None, threshold: float = 0.0) -> None:
        """One TDMA frame; ``arrival`` (B, n+1, n) records first holding of a stamp ``>= threshold``."""
        bi = self.bi
        for k in range(self.n):
            s = self.orders[:, k]
            self.stamps[bi, s, s] = self.t  # own state is current at the slot
            sel = self.select(s)
            rcv = self.nbr[s]
            proto.deliver(self.stamps, bi, s, rcv, sel)
            self.t += self.slot
            if arrival is not None:
                proto.record_arrivals(arrival, self.stamps, bi, rcv, threshold, self.t)

    def propagate(self, blocks: dict[int, np.ndarray], threshold: float, max_frames: int) -> dict[int, np.ndarray]:
        """Frames until every block is complete in every run. Per block ``(max, mean)`` over its ordered pairs
        of the delay (s from now) until the pair holds the stamp, one value per run (``inf``: not in time)."""
        n, t0 = self.n, self.t
        r = np.arange(n)
        arrival = np.full((self.runs, n + 1, n), np.inf)
        arrival[:, r, r] = t0
        big = blocks[max(blocks, key=lambda k: blocks[k].size)]
        for _ in range(max_frames):
            self.frame(arrival, threshold)
            if np.isfinite(arrival[:, big][:, :, big]).all():
                break
        out = {}
        for k, b in blocks.items():
            a = arrival[:, b][:, :, b] - t0
            off = ~np.eye(b.size, dtype=bool)
            out[k] = (a.reshape(self.runs, -1).max(axis=1), a[:, off].mean(axis=1))
        return out


def grid_propagation(
    side: int,
    m: int,
    runs: int,
    seed: int,
    blocks: dict[int, np.ndarray],
    selector: str = "text",
    alpha: float = 1.0,
    bits: float = 192,
    baud: float = 3000.0,
    warm_frames: int = 5,
    max_frames: int = 2000,
    steady: bool = True,
) -> dict:
    """Propagation times (s) per subgraph size for ``runs`` random slot orders.

    Returns ``{"cold": {k: (max, mean)}, "steady": {k: (max, mean)}}``, arrays over runs of the
    all-pairs time (max over pairs: the paper's "all subgraph members exchanged") and the mean pair
    delay, with ``inf`` for runs that did not
    complete within ``max_frames`` frames (always the case for m = 1: only neighbours ever hear a robot).
    """
    sim = GridSim(side, m, runs, seed, selector, alpha, bits, baud)
    out = {"cold": sim.propagate(blocks, 0.0, max_frames)}  # stamps >= 0 means "known"
    if steady:
        for _ in range(warm_frames):
            sim.frame()
        out["steady"] = sim.propagate(blocks, sim.t, max_frames)
    return out
