"""MultiHop's frame written slot by slot in numpy: the oracle its copy-axis world is checked against.

The env steps every scene as the world of its one copy (``mrcomm_env/multihop/copy_axis.py``, compiled); this is
the frame as the paper states it (§2.1, Algorithm 1's selection at each robot's slot, eq. (1)'s weighted age),
kept here and not in the package (#44: one implementation in the package, the reference under tests/), with the
env's action semantics for one sender (``priority_select``: own estimate first, then the highest priorities among
the *known* estimates, at most ``m`` in all, priorities ``<= 0`` withheld), all senders' candidate lists at once
(``priority_ranking``) and a broadcast for one run (``deliver_one``, ``protocol.deliver`` unbatched). It reads
and writes the env's own state, so a ``ReferenceMultiHop`` and a ``MultiHopEnv`` seeded alike can be compared
whole episodes at a time (``tests/multihop/test_multihop_world.py``, ``test_multihop.py``)."""

from __future__ import annotations

import numpy as np

from mrcomm_env.multihop import coverage as cov
from mrcomm_env.multihop import protocol as proto
from mrcomm_env.multihop.env import MultiHopEnv


def priority_select(priority: np.ndarray, known: np.ndarray, own: int, m: int) -> np.ndarray:
    """The env's action semantics for one sender: own estimate, then the ``m-1`` highest priorities
    among known estimates (ties: lower index first); priorities ``<= 0`` are withheld. Returns indices."""
    p = np.where(known, priority, 0.0)
    p[own] = np.inf
    cand = np.flatnonzero(p > 0.0)
    if cand.size > m:
        cand = cand[np.argsort(-p[cand], kind="stable")[:m]]
    return cand


def priority_ranking(priority: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All senders' candidate lists at once (the env precomputes them once per frame): row ``i`` of
    ``rank`` lists own index first, then indices with priority ``> 0`` by descending priority (ties: lower
    index first); ``count[i]`` entries are valid. ``rank[i, :count[i]]`` filtered to known estimates and
    cut to ``m`` is exactly :func:`priority_select`."""
    n = priority.shape[1]
    p = np.where(priority > 0.0, priority, -1.0)
    p[np.arange(n), np.arange(n)] = np.inf
    rank = np.argsort(-p, axis=1, kind="stable")
    return rank, (p > 0.0).sum(axis=1)


def deliver_one(
    stamps: np.ndarray, sender: int, receivers: np.ndarray, idx: np.ndarray, positions: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`deliver` for a single run (``stamps`` (n, n)), with the selection as indices ``idx``.

    Same rule (receivers keep the newest stamp); flat indexing keeps the per-slot cost to a few numpy
    calls. Returns the flat indices touched, the receivers' old stamps there and the update mask."""
    n = stamps.shape[1]
    flat = (receivers[:, None] * n + idx[None, :]).ravel()
    sv = stamps.reshape(-1)
    old = sv[flat].reshape(receivers.size, idx.size)
    new = stamps[sender, idx]
    upd = new > old  # (K, L), broadcast over receivers
    sv[flat] = np.where(upd, new, old).ravel()
    upd = upd.ravel()
    if positions is not None and upd.any():
        pv = positions.reshape(n * n, -1)
        src = np.broadcast_to(positions[sender, idx], (receivers.size, idx.size, pv.shape[1]))
        pv[flat[upd]] = src.reshape(-1, pv.shape[1])[upd]
    return flat, old.ravel(), upd


class ReferenceMultiHop(MultiHopEnv):
    """MultiHop stepped by the numpy frame below, not as the copy-axis world of one copy."""

    @classmethod
    def copy_axis_world(cls, cfg):
        return None  # a batch of these steps its copies in turn, each through the frame below

    def _step_world(self, actions) -> float | np.ndarray:
        n, m, b = self.n_agents, self.m, self.cfg.bits_per_estimate
        stamps, est, t = self.stamps, self.est, self.t
        # a robot's priorities are fixed for the frame; its candidate list is ranked once, filtered to the
        # estimates it holds at its own slot (priority_select, vectorised over the frame)
        rank, count = priority_ranking(self._priorities(actions))
        sent_counts = np.zeros(n)
        last_sent, sent_stamp = self.last_sent, self.sent_stamp
        last_sent[:] = False
        fk = None if self._all_known else self.first_known.reshape(-1)
        all_known = self._all_known
        moving = self._moving
        neighbours = [np.flatnonzero(row) for row in self.adj]
        for s in self.tdma.order.tolist():
            row = stamps[s]
            row[s] = t  # own state is always current (t_ii = t)
            cand = rank[s, : count[s]]
            idx = cand[:m] if all_known else cand[row[cand] > proto.UNKNOWN][:m]
            sent_counts[s] = idx.size
            last_sent[s, idx] = True
            sent_stamp[s, idx] = row[idx]
            t += self.slot_dur
            # moving robots: the links of this slot, from the positions now (the sender's row only)
            rcv = self._receivers(s) if moving else neighbours[s]
            if rcv.size:
                if moving:
                    est[s, s] = self.pos[s]
                    flat, old, upd = deliver_one(stamps, s, rcv, idx, est)
                else:
                    flat, old, upd = deliver_one(stamps, s, rcv, idx)
                if fk is not None:
                    fk[flat[upd & (old == proto.UNKNOWN)]] = t  # first arrival: end of this slot
            if moving:
                self.t = t
                self._move(self.slot_dur)
        self.t = t
        stamps[self._eye] = t
        if moving:
            est[self._eye] = self.pos
            self._links()
            self._reward_weights()
            self._hops()
        if not self._all_known:
            self._all_known = bool(np.isfinite(self.first_known).all())
        self._step_bits = sent_counts * b
        self.ledger.record(self._step_bits, messages=n)
        return self._frame_end()

    def _priorities(self, actions) -> np.ndarray:
        """(N, N) priorities of the frame: the v0 action itself, or the selected candidates by rank."""
        if not self._relative:
            return np.asarray(actions, dtype=np.float64)
        n = self.n_agents
        selected = np.asarray(actions, dtype=bool)
        prio = np.zeros((n, n))
        rows = np.repeat(np.arange(n), n - 1)
        rank_priority = 1.0 - np.arange(n - 1) / (2.0 * n)  # a selected candidate's: above 0, falling with the rank
        prio[rows, self._candidates.ravel()] = np.where(selected, rank_priority, 0.0).ravel()
        return prio

    def _move(self, duration: float) -> None:
        c = self.cfg
        if c.scene == "field":
            delta = self.waypoint - self.pos
            dist = np.linalg.norm(delta, axis=1)
            step = c.speed * duration
            arrive = dist <= step
            self.pos = np.where(
                arrive[:, None], self.waypoint, self.pos + delta * (step / np.maximum(dist, 1e-12))[:, None]
            )
            if arrive.any():
                self.waypoint[arrive] = self.np_random.uniform(0.0, self.side, size=(int(arrive.sum()), 2))
        else:
            # the coverage controller's Euler steps (MultiHopEnv._control_steps: at most 0.25 s each)
            sub = self._control_steps(duration)
            known = self.stamps > proto.UNKNOWN
            for _ in range(sub):
                target = cov.centroids(self._ctrl_points, self.pos, self.est, known)
                self.pos = cov.control_step(self.pos, target, c.control_gain, c.max_speed, duration / sub, self.side)

    def _receivers(self, sender: int) -> np.ndarray:
        """Robots within ``comm_range`` of ``sender`` now: its row of ``disk_links``."""
        diff = self.pos - self.pos[sender]
        r = self.cfg.comm_range
        within = np.einsum("ij,ij->i", diff, diff) <= r * r
        within[sender] = False
        return np.flatnonzero(within)

    def _frame_end(self) -> float | np.ndarray:
        ages = np.where(self.stamps > proto.UNKNOWN, self.t - self.stamps, self.t)  # unknown: age since start
        self._ages = ages
        off = ~self._eye
        self._frames += 1
        self._sum_age += float(ages[off].mean())
        weighted = self._w * ages
        wage = float(weighted.sum()) / self._wsum
        self._sum_wage += wage
        for k, mask in enumerate(self._hop_masks):
            if mask.any():
                sel = ages[mask]
                self._max_age[k] = max(self._max_age[k], float(sel.max()))
                self._sum_age_hop[k] += float(sel.mean())
        if self.heard is not None:
            proto.hear(self.heard, self.last_sent, self.sent_stamp, self.adj)
        if self._relative:
            self._rank_candidates()
        age_unit = self._age_unit
        bit_unit = self.m * self.cfg.bits_per_estimate
        if self.cfg.reward_mode == "team":
            return -wage / age_unit - self.cfg.lam * float(self._step_bits.sum()) / self._capacity
        # neighbourhood: robot k's own weighted staleness, averaged over the neighbours i's broadcast reaches
        near = proto.neighbourhood_staleness(weighted, self._w, self.adj)
        return -near / age_unit - self.cfg.lam * self._step_bits / bit_unit
