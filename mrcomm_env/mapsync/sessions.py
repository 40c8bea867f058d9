"""MapSync's sync protocol as a state machine over the links: a robot's action opens a session with a peer
(Protocol 1's equality test, Algorithm 1's bisection, a full map, or a PinSketch), the session's messages cross
the link at its bit budget over the following steps, and when the last one arrives the maps are merged (or the
equality test's verdict recorded). Bits are charged to each sender through the env's ``BitLedger``.

A mixin of :class:`mrcomm_env.mapsync.env.MapSyncEnv`, which owns the state; the attributes it reads and writes
are declared below.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mrcomm_env.mapsync import protocol as proto
from mrcomm_env.mapsync.actions import ACTIONS, IDLE

#: detections kept in ``MapSyncEnv.detections`` (the most recent; ``metrics()["detections"]`` counts them all): a
#: list of every one would grow with the episode without bound
DETECTIONS_KEPT = 10_000
TEST_NONE, TEST_SAME, TEST_DIFFERENT = -1, 1, 0  # last_test: Protocol 1's return values, −1 = no test yet


def choose_peer(peers: list[int], session_of, linked_row, last_sync_row) -> int:
    """Of ``peers`` (in peer order), the one not in a sync (``session_of`` < 0) and linked that this robot synced
    with least recently (``last_sync_row``, the step of each pair's last sync); the first on ties, −1 if none."""
    best, best_age = -1, -(2**62)
    for j in peers:
        if session_of[j] < 0 and linked_row[j] and -last_sync_row[j] > best_age:
            best, best_age = j, int(-last_sync_row[j])
    return best


@dataclass
class Session:
    """One sync between Alice (the requester) and Bob, in flight over their link."""

    alice: int
    bob: int
    protocol: str
    start_step: int
    messages: list  #: [(sender, bits)] in the order they are sent
    outcome: Any  #: EqualityResult or Reconciliation, computed on the maps at the start
    snapshot: dict[str, Any] = field(default_factory=dict)
    sent: int = 0  #: bits delivered so far
    total: int = 0


class SyncSessions:
    """Opening, carrying and closing sync sessions, and merging maps at their end."""

    _charged: Any
    _corrected: Any
    _counts: Any
    _dirty: Any
    _events: Any
    _latency_sum: Any
    _latency_count: Any
    _cap: Any
    _k: Any
    _lww: Any
    _next_session: Any
    _res: Any
    _peer_lists: Any
    _peer_order: Any
    _stamp_bits: Any
    _to_correct: Any
    cfg: Any
    detections: Any
    known: Any
    last_sync: Any
    last_test: Any
    ledger: Any
    linked: Any
    maps: Any
    new_cells: Any
    np_random: Any
    robot_syncs: Any
    session_of: Any
    sessions: Any
    sketch_seed: Any
    stamps: Any
    strings: Any

    # ----------------------------------------------------------------- syncs
    def _choose_peer(self, i: int) -> int:
        """The linked, free peer that robot i synced with least recently (the first in peer order on ties)."""
        return choose_peer(self._peer_lists[i], self.session_of, self.linked[i], self.last_sync[i])

    def _start_sessions(self, actions: list, t: int) -> None:
        for i, act in enumerate(actions):
            if act == IDLE or self.session_of[i] >= 0:
                continue
            j = self._choose_peer(i)
            if j < 0:
                continue
            # both ends asking: j's request is served by this one sync (j is busy from now on)
            self._open_session(i, j, ACTIONS[act], t)

    def _open_session(self, a: int, b: int, name: str, t: int) -> None:
        nonce = self._next_session
        self._next_session += 1
        outcome, messages, snapshot = self._run_protocol(a, b, name, nonce)
        session = Session(a, b, name, t, messages, outcome, snapshot, 0, sum(bits for _, bits in messages))
        self.sessions[nonce] = session
        self.session_of[a] = self.session_of[b] = nonce
        self._events += 1  # the infos' busy column is made from session_of when they are next read

    def _run_protocol(self, a: int, b: int, name: str, nonce: int) -> tuple[Any, list, dict[str, Any]]:
        """Alice ``a`` runs ``name`` with Bob ``b`` on their maps as they are now: the outcome (EqualityResult or
        Reconciliation), the transcript [(sender, bits)] of its non-empty messages in order, and the snapshot
        that the sync's end needs (which cells to merge and what each side sent about them)."""
        x, y = self.maps[a], self.maps[b]
        outcome, messages = self._transcript(x, y, a, b, name, nonce)
        snapshot: dict[str, Any]
        differ = int(np.count_nonzero(x != y))  # cells that differ at the start (the metrics' denominators)
        if name == "equality":
            snapshot = {"differ": differ > 0}
        else:
            found = outcome.found
            snapshot = {"found": found, "differ": differ, "right": 0}
            if found.size:  # what each sent about the found cells (nothing to merge otherwise, see _merge)
                snapshot["x"], snapshot["y"] = x[found], y[found]  # fancy indexing copies
                snapshot["sa"], snapshot["sb"] = self.stamps[a][found], self.stamps[b][found]
                snapshot["right"] = int(np.count_nonzero(snapshot["x"] != snapshot["y"]))
        return outcome, messages, snapshot

    def _transcript(self, x, y, a: int, b: int, name: str, nonce: int) -> tuple[Any, list]:
        """Alice ``a`` (map ``x``) runs ``name`` with Bob ``b`` (map ``y``): the outcome (EqualityResult or
        Reconciliation) and the transcript [(sender, bits)] of its non-empty messages in the order they are sent,
        Bob's way back (the found cells, and their stamps both ways under last-writer-wins) included."""
        outcome: Any
        if name == "equality":
            outcome = proto.equality(x, y, self.strings, self._k, self.np_random)
            messages = [(a, outcome.alice_bits), (b, outcome.bob_bits)]
        else:
            if name == "bisection":
                outcome = proto.bisection(x, y, self.strings, self._k, self._res, self.np_random)
                messages = [(a if who == "alice" else b, bits) for who, bits in outcome.extra["messages"]]
            elif name == "full":
                outcome = proto.full(x, y)
                messages = [(a, outcome.alice_bits)]
            else:
                outcome = proto.sketch(x, y, self.sketch_seed, nonce)
                messages = [(a, outcome.alice_bits), (b, outcome.bob_bits)]
            found = outcome.found
            messages.append((b, proto.return_bits(outcome.candidates, found.size)))
            if self._lww and found.size:
                messages += [(b, found.size * self._stamp_bits), (a, found.size * self._stamp_bits)]
        return outcome, [(who, int(bits)) for who, bits in messages if bits > 0]

    def _sync_within_step(self, actions: list, t: int) -> None:
        """``_start_sessions`` then ``_progress_sessions`` when a link carries any transcript within one step (no
        ``bits_per_step``), so that every sync opens, completes and closes in the step it is asked for.

        The same syncs in the same order, with the same charges, counts and merges: every requested sync first
        runs its protocol on the maps as the step found them (a robot busy with an earlier one is skipped, as
        ``_start_sessions`` skips it), then each completes in the order it opened. None can be aborted, since a
        peer is chosen among the linked ones and the links do not change within a step. What it leaves out is the
        ``Session`` objects and the transcript's delivery bit by bit, which only a limited link needs."""
        session_of = self.session_of
        opened = []
        for i, act in enumerate(actions):
            if act == IDLE or session_of[i] >= 0:
                continue
            j = self._choose_peer(i)
            if j < 0:
                continue
            nonce = self._next_session
            self._next_session += 1
            outcome, messages, snapshot = self._run_protocol(i, j, ACTIONS[act], nonce)
            session_of[i] = session_of[j] = nonce  # j's own request is served by this sync
            opened.append((i, j, ACTIONS[act], outcome, messages, snapshot))
        if not opened:
            return
        for a, b, name, outcome, messages, snapshot in opened:
            self._charge(messages)
            self._finish(a, b, name, t, outcome, snapshot, t)
            session_of[a] = session_of[b] = -1
        self._events += 2 * len(opened)  # each sync opens and closes (the infos are made anew)

    def _charge(self, messages: list) -> None:
        """Charge (sender, bits) ``messages`` (a whole transcript, or the parts a step delivers), one ledger entry of
        their bits and number per sender, in the order the senders first appear."""
        charged: dict[int, list[int]] = {}
        for who, bits in messages:
            entry = charged.get(who)
            if entry is None:
                charged[who] = [bits, 1]
            else:
                entry[0] += bits
                entry[1] += 1
        for who, (bits, count) in charged.items():  # whole bits: the float sums are exact in any grouping
            self.ledger.add(who, bits, messages=count)
            self._charged = True

    def _progress_sessions(self, t: int) -> None:
        cap = self._cap
        for key in list(self.sessions):
            s = self.sessions[key]
            if not self.linked[s.alice, s.bob]:
                self._close(key)
                self._counts["aborted_syncs"] += 1
                continue
            budget = s.total - s.sent if cap is None else min(cap, s.total - s.sent)
            self._deliver(s, budget)
            if s.sent >= s.total:
                self._complete(s, t)
                self._close(key)

    def _deliver(self, s: Session, budget: int) -> None:
        """Charge the next ``budget`` bits of the transcript to their senders, in order."""
        parts = []  # (sender, bits) of every message, or message part, that crosses the link this step
        skip, left = s.sent, budget  # bits of the transcript already delivered; bits this step may carry
        for who, bits in s.messages:
            if left <= 0:
                break
            if skip >= bits:  # delivered at an earlier step
                skip -= bits
                continue
            part = bits - skip if bits - skip < left else left
            skip = 0
            parts.append((who, part))
            left -= part
        s.sent += budget - left
        self._charge(parts)

    def _close(self, key: int) -> None:
        s = self.sessions.pop(key)
        self.session_of[s.alice] = self.session_of[s.bob] = -1
        self._events += 1

    def _complete(self, s: Session, t: int) -> None:
        self._finish(s.alice, s.bob, s.protocol, s.start_step, s.outcome, s.snapshot, t)

    def _finish(self, a: int, b: int, name: str, start_step: int, outcome: Any, snapshot: dict, t: int) -> None:
        """The last bit of Alice ``a``'s ``name`` sync with Bob ``b`` (opened at ``start_step``) arrived at step t:
        record the verdict, merge the maps, count it."""
        self._counts["syncs"] += 1
        self.robot_syncs[a] += 1  # a ≠ b
        self.robot_syncs[b] += 1
        self._latency_sum += t - start_step + 1
        self._latency_count += 1
        synced = True
        if name == "equality":
            synced = self._verdict(a, b, name, start_step, snapshot, outcome.equal)
        else:
            if name == "bisection":
                self._verdict(a, b, name, start_step, snapshot, not outcome.detected)
            self._merge(a, b, snapshot)
            self._to_correct += snapshot["differ"]
            self._corrected += snapshot["right"]
        if synced:
            self.last_sync[a, b] = self.last_sync[b, a] = t + 1
            self.new_cells[a, b] = self.new_cells[b, a] = 0

    def _verdict(self, a: int, b: int, name: str, start_step: int, snapshot: dict, equal: bool) -> bool:
        self._counts["equality_tests"] += 1
        if equal and snapshot["differ"]:
            self._counts["false_equal"] += 1
        if not equal:
            self._counts["detections"] += 1
            self.detections.append((start_step, a, b, name))
        self.last_test[a, b] = self.last_test[b, a] = TEST_SAME if equal else TEST_DIFFERENT
        return equal

    def _merge(self, alice: int, bob: int, snap: dict) -> None:
        """Last-writer-wins on the cells Bob found (OR when nothing vanishes), into the maps as they are now.

        Each robot believes the other holds the opposite bit on every found cell (true unless a sketch was
        wrongly accepted); it adopts that bit where the other's stamp is newer than its own current stamp.
        """
        found = snap["found"]
        if found.size == 0:
            return
        for me, other_bit, other_stamp in ((alice, ~snap["x"], snap["sb"]), (bob, ~snap["y"], snap["sa"])):
            my_map, my_stamps = self.maps[me], self.stamps[me]  # row views: 1-d indexing below
            if self._lww:
                adopt = other_stamp > my_stamps[found]
            else:  # only appearances: a 1 is never stale, so the merge is OR
                adopt = other_bit & ~my_map[found]
            cells = found[adopt]
            if cells.size == 0:
                continue
            stamps_now = my_stamps[cells]
            self.known[me] += int(np.count_nonzero(stamps_now < 0))
            my_map[cells] = other_bit[adopt]
            my_stamps[cells] = np.maximum(stamps_now, other_stamp[adopt])
        self._dirty = True

    # ----------------------------------------------------------------- views
