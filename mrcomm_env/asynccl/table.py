"""The information tables T_k^i of every robot and the transfer schemes of §III, vectorised over robots.

Representation. Every transfer scheme moves a robot's row as a contiguous run of time steps, oldest
first, and a receiver only ever gets data at or after its own discard frontier, so each row of every
robot's table is a *prefix*: robot i holds ``M_k^v`` for every non-discarded ``k ≤ latest[i, v]``.
The whole table of the team is therefore the ``(N, N)`` integer matrix ``latest`` (this is exactly the
list ``L_i = {(v, k_v^i)}`` of the q = ∞ book-keeping, §III-B.1) plus the discard frontier ``disc[i]``.
The packets themselves live once in a shared ring buffer (their contents are identical everywhere);
a table only says *which* packets a robot holds.

* complete frontier ``c[i] = min_v latest[i, v]``: robot i can compute x̂_{k|k} for every k ≤ c[i]
  (Lemma 1 / Lemma 2), i.e. its delayed centralized estimate is x̂_{c|c}^{t}.
* what a sender j puts on a link (eq. (4)-(5): from T_t^{j-}, no multi-hop within one step):
  Scheme 1 (§III-A) its own row; Scheme 2 with q (§III-B) all rows restricted to its q oldest
  non-discarded columns ``disc[j]+1 … disc[j]+q``; q = ∞ everything. Only what the receiver lacks is sent
  (for q = ∞ this is the L_i exchange and the sets D1 (rows both have: ``k_v^i+1 … k_v^j``) and D2
  (rows the receiver lacks: from the oldest held step); for q = 1 it is what Fig. 5 shows, and for
  Scheme 1 it equals "since they last communicated").
* a per-link bit budget truncates the payload oldest column first (rows in id order inside a column),
  so rows stay prefixes.
* discard (§III-A.3, §III-B.3): robot i drops column k once (i) k ≤ c[i] and (ii) it knows every other
  robot has column k complete. It learns that from the headers it receives (the sender's complete
  frontier), from what it delivered itself ("communicating this information to all robots
  personally") and from a sender's discard frontier ("communicating with another robot that has
  satisfied (i) and (ii)"). Discarded columns are complete at every robot, which keeps rows prefixes.
* bounded memory: the shared ring keeps ``history`` steps; a robot still missing a column that falls
  out of it abandons that column (it is counted, never in the delay statistics).
"""

from __future__ import annotations

import numpy as np

from mrcomm_env.asynccl.table_numba import exchange_dense
from mrcomm_env.asynccl.world import HEADER_BITS, LIST_ENTRY_BITS

SILENT, SCHEME1, QINF = -1, 0, 1 << 40  # mode codes: -1 silent, 0 Scheme 1, q ≥ 1 Scheme 2 (QINF = ∞)
DENSE_MAX_N = 24  # up to this team size the exchange runs on dense (sender, receiver, row) arrays
# ufunc reductions called directly: ndarray.sum/min/max/any add two Python frames per call, as much as the
# reduction itself on these tiny arrays (same numpy routine, same result)
_sum, _min, _any = np.add.reduce, np.minimum.reduce, np.logical_or.reduce


class InfoTables:
    def __init__(self, n: int, history: int, q_rule: str = "paper"):
        self.n, self.history, self.q_rule = n, history, q_rule
        self._rows = np.arange(n)[None, :]  # row index for gathers of cumulative bits
        self._diag = np.arange(n) * (n + 1)  # flat index of the diagonal of an (N, N) matrix
        self.W = history + 3  # ring of cumulative packet bits, indexed by step + 1 (step -1 ↦ 0 bits)

    def reset(self, first_bits: np.ndarray) -> None:
        n = self.n
        self.t = 0
        self.latest = np.full((n, n), -1, dtype=np.int64)
        np.fill_diagonal(self.latest, 0)  # T_0^{i-} = M_0^i, eq. (5)
        self.c = np.full(n, -1, dtype=np.int64)
        self.disc = np.full(n, -1, dtype=np.int64)
        self.known = np.full((n, n), -1, dtype=np.int64)
        self.pkt_bits = np.zeros((n, self.W))
        self.cum_bits = np.zeros((n, self.W))
        self._push_bits(0, first_bits)
        self.delay_sum = 0.0
        self.delay_count = 0
        self._hist_diff = np.zeros(self.history + 3, dtype=np.int64)
        self.abandoned = 0

    def _push_bits(self, t: int, bits: np.ndarray) -> None:
        col = (t + 1) % self.W
        self.pkt_bits[:, col] = bits
        self.cum_bits[:, col] = self.cum_bits[:, t % self.W] + bits if t > 0 else bits

    def new_step(self, bits: np.ndarray) -> np.ndarray:
        """Step t+1 starts: every robot adds its own packet (eq. (5)); returns robots abandoning columns."""
        self.t += 1
        t = self.t
        self._push_bits(t, bits)
        self.latest.reshape(-1)[self._diag] = t
        # bounded memory: columns older than the ring are gone for everyone
        floor = t - self.history
        lagging = np.nonzero(self.c < floor)[0]
        if lagging.size:
            self.abandoned += int(np.sum(floor - self.c[lagging]))
            self.latest[lagging] = np.maximum(self.latest[lagging], floor)
            self.c[lagging] = floor
            self.known[lagging, lagging] = floor
        # what left the ring is gone for everyone (and complete everywhere): it counts as discarded
        np.maximum(self.disc, floor - 1, out=self.disc)
        return lagging

    # ------------------------------------------------------------------ one exchange, eq. (4)
    def exchange(self, modes: np.ndarray, adj: np.ndarray, delivered: np.ndarray, budget: float | None):
        """Robots transmit with ``modes`` over ``adj`` (j → i); ``delivered`` ⊆ adj after packet loss.

        Returns (bits sent per robot, number of links used per robot).
        """
        if self.n <= DENSE_MAX_N and budget is None and self.q_rule != "receiver":
            return self._exchange_dense(modes, adj, delivered)
        return self._exchange_pairs(modes, adj, delivered, budget)

    def _offers(self, modes: np.ndarray) -> np.ndarray:
        """Upper end of each row a sender offers, from T_t^{j-} (eq. (4)-(5)): (N senders, N rows)."""
        latest, t = self.latest, self.t
        hi_s = latest.copy()
        s1 = modes == SCHEME1
        if s1.any():
            hi_s[s1] = -1
            hi_s[s1, np.nonzero(s1)[0]] = t
        fin = (modes >= 1) & (modes < QINF)
        if fin.any():
            hi_s[fin] = np.minimum(latest[fin], (self.disc[fin] + modes[fin])[:, None])
        return hi_s

    def _exchange_dense(self, modes, adj, delivered):
        """The exchange of ``_exchange_pairs`` for a small team without a budget, in one compiled call on dense
        (sender, receiver, row) arrays (``table_numba.exchange_dense``); ``_exchange_pairs``, which handles every
        case, is its oracle in the tests."""
        bits, links, latest, known, c, disc, self.delay_sum, added, any_link = exchange_dense(
            np.asarray(modes, dtype=np.int64),
            adj,
            delivered,
            self.latest,
            self.disc,
            self.known,
            self.c,
            self.cum_bits,
            self.W,
            SILENT,
            SCHEME1,
            QINF,
            float(HEADER_BITS),
            float(LIST_ENTRY_BITS),
            self.t,
            self._hist_diff,
            self.delay_sum,
            self.q_rule == "oracle",
        )
        if any_link:  # (with no link nothing changes: the frontiers settle only after an exchange)
            self.latest, self.known, self.c, self.disc = latest, known, c, disc
            self.delay_count += added
        return bits, links

    def _exchange_pairs(self, modes, adj, delivered, budget):
        """The exchange over the list of used links (any N, per-link budgets, q-rule variants)."""
        n, t = self.n, self.t
        latest, disc, c_pre = self.latest, self.disc, self.c.copy()
        sending = modes != SILENT
        recv, send = np.nonzero((adj & sending[:, None]).T)  # sorted by receiver
        bits = np.zeros(n)
        links = np.zeros(n)
        if recv.size == 0:
            return bits, links
        hi_s = self._offers(modes)
        fin = (modes >= 1) & (modes < QINF)
        lo = latest[recv]
        hi = hi_s[send]
        if self.q_rule == "receiver" and fin.any():
            # variant: the q oldest columns in which the receiver lacks something the sender holds
            e = np.nonzero(fin[send])[0]
            full_hi = latest[send[e]]
            lacks = full_hi > lo[e]
            first = np.where(lacks, lo[e] + 1, np.iinfo(np.int64).max).min(axis=1)
            hi[e] = np.where(lacks, np.minimum(full_hi, (first + modes[send[e]] - 1)[:, None]), -1)
        hdr_s = np.where(
            modes >= QINF, HEADER_BITS + LIST_ENTRY_BITS * np.sum(latest > disc[:, None], axis=1), HEADER_BITS
        ).astype(float)
        header = hdr_s[send]
        W = self.W
        if budget is not None:
            hi, _, sent = self._truncate(recv, send, lo, hi, hi > lo, header, budget)
        else:
            # payload: the packets of every row strictly after what the receiver holds, up to the offer;
            # with cumulative packet bits per row that is Σ_v max(0, cum(hi) − cum(lo))
            if self.q_rule == "receiver" and fin.any():
                CHp = self.cum_bits[self._rows, (hi + 1) % W]
                CHp[hi < 0] = -np.inf
            else:
                CH = self.cum_bits[self._rows, (hi_s + 1) % W]
                CH[hi_s < 0] = -np.inf
                CHp = CH[send]
            CL = self.cum_bits[self._rows, (latest + 1) % W]
            sent = header + np.maximum(CHp - CL[recv], 0.0).sum(axis=1)
        np.add.at(bits, send, sent)
        np.add.at(links, send, 1.0)
        # receivers update from what was delivered (packet loss removes some directed deliveries);
        # an offer at or below what the receiver holds changes nothing, so no per-row mask is needed
        ok = delivered[send, recv] & (sent > 0)
        if ok.any():
            r, s, h = recv[ok], send[ok], hi[ok]
            starts = np.r_[0, np.nonzero(np.diff(r))[0] + 1]
            rows = r[starts]
            self.latest[rows] = np.maximum(latest[rows], np.maximum.reduceat(h, starts, axis=0))
            # book-keeping for the discard rule: the receiver learns the sender's frontiers, ...
            self.known[r, s] = np.maximum(self.known[r, s], c_pre[s])
            dmax = np.maximum.reduceat(disc[s], starts)
            self.known[rows] = np.maximum(self.known[rows], dmax[:, None])
            # ... and the sender knows what the receiver holds after its own delivery
            after = np.maximum(lo[ok], h).min(axis=1)
            np.maximum.at(self.known, (s, r), after)
        self._settle(t)
        return bits, links

    def _truncate(self, recv, send, lo, hi, gain, header, budget):
        """Per-link bit budget: header first, then packets oldest column first (rows by id).

        Link e offers rows v at steps lo[e, v]+1 … hi[e, v]. In (column, row) order the packets that fit are
        every packet of the columns ≤ K_e plus a prefix, by row id, of column K_e + 1, where K_e is the last
        column whose cumulative payload fits. The payload up to column K is Σ_v cum(min(hi, K)) − cum(lo)
        (cumulative bits per row), monotone in K, so K_e is found by a bisection run on all links at once:
        O(links · N · log(spread of columns)) array work instead of a Python loop over links and packets.
        A link whose header alone exceeds the budget sends nothing.
        """
        W = self.W
        rows = self._rows
        cum, pkt = self.cum_bits, self.pkt_bits
        room = budget - header  # (E,)
        fits = room >= 0.0
        top = np.where(gain, hi, lo)  # rows without gain offer nothing: their range is empty
        cum_lo = cum[rows, (lo + 1) % W]

        def payload(K):  # bits of every offered packet of columns ≤ K, per link
            upto = np.maximum(np.minimum(top, K[:, None]), lo)
            return _sum(cum[rows, (upto + 1) % W] - cum_lo, axis=1)

        big = np.iinfo(np.int64).max
        k_ok = np.where(gain, lo, big).min(axis=1, initial=big)  # all of the columns up to here: nothing, fits
        k_hi = np.where(gain, hi, -1).max(axis=1, initial=-1)
        k_ok = np.minimum(k_ok, k_hi)  # (no gain: k_ok = k_hi = -1, nothing to search)
        while True:
            open_ = k_ok < k_hi
            if not _any(open_, axis=None):
                break
            mid = k_ok + (k_hi - k_ok + 1) // 2
            ok = payload(mid) <= room
            k_ok = np.where(open_ & ok, mid, k_ok)
            k_hi = np.where(open_ & ~ok, mid - 1, k_hi)
        full = payload(k_ok)
        # column K + 1: rows in id order while they fit (packet sizes are positive, so that is a prefix)
        nxt = (k_ok + 1)[:, None]
        in_col = (lo < nxt) & (nxt <= top)
        sizes = np.where(in_col, pkt[rows, (nxt + 1) % W], 0.0)
        taken = in_col & (np.cumsum(sizes, axis=1) <= (room - full)[:, None])
        new_hi = np.where(taken, nxt, np.maximum(np.minimum(top, k_ok[:, None]), lo))
        sent = header + full + _sum(np.where(taken, sizes, 0.0), axis=1)
        new_hi = np.where(fits[:, None], new_hi, lo)
        sent = np.where(fits, sent, 0.0)
        return new_hi, new_hi > lo, sent

    def _settle(self, t: int) -> None:
        """New complete frontiers (delay bookkeeping, eq. (7)) and the discard rule."""
        c_new = np.minimum(_min(self.latest, axis=1), t)
        grew = c_new > self.c
        if _any(grew, axis=None):
            a, b = self.c[grew], c_new[grew]
            # steps a+1 … b become computable now: delays t − k; the histogram of delays gets the range
            # t-b … t-a-1, kept as a difference array
            if len(a) <= 8:  # a few robots (the usual case): plain Python beats a dozen tiny numpy calls
                hist = self._hist_diff
                for ai, bi in zip(a.tolist(), b.tolist()):
                    self.delay_sum += (bi - ai) * t - (ai + bi + 1) * (bi - ai) / 2.0  # halves: exact in any order
                    self.delay_count += bi - ai
                    hist[t - bi] += 1
                    hist[t - ai] -= 1
            else:
                cnt = b - a
                self.delay_sum += float(np.sum(cnt * t - (a + b + 1) * cnt / 2.0))
                self.delay_count += int(cnt.sum())
                np.add.at(self._hist_diff, t - b, 1)
                np.add.at(self._hist_diff, t - a, -1)
            self.c = c_new
        self.known.reshape(-1)[self._diag] = self.c  # what robot i itself has complete
        if self.q_rule == "oracle":  # variant: a column is dropped as soon as every robot has it
            self.disc[:] = self.c.min()
        else:
            self.disc = np.maximum(self.disc, _min(self.known, axis=1))

    # ------------------------------------------------------------------ views
    def packet_bits(self, step: int) -> np.ndarray:
        """Bits of every robot's packet M_step^j (N,), for a step still in the ring (the last ``history`` steps)."""
        if not self.t - self.history <= step <= self.t:
            raise ValueError(f"argument 'step' must be within the ring [{self.t - self.history}, {self.t}], got {step}")
        return self.pkt_bits[:, (step + 1) % self.W].copy()

    def table_size(self) -> np.ndarray:
        """Packets each robot holds in its non-discarded columns."""
        return _sum(np.maximum(self.latest - self.disc[:, None], 0), axis=1)

    def delay_histogram(self) -> np.ndarray:
        """counts[d]: robot-steps whose centralized estimate became computable d steps late."""
        return np.cumsum(self._hist_diff)[:-1]

    def mean_delay(self) -> float:
        return self.delay_sum / self.delay_count if self.delay_count else float("nan")
