"""Information filters per landmark (§III) and decentralised fusion that never counts information twice.

**Filter.** Every landmark's 2-D position is held in information form, ``Y = Σ⁻¹`` and ``y = Σ⁻¹ μ``
([13], §III). Landmarks are static, so prediction is the identity, and an observation ``z = x + v``,
``v ~ N(0, R)`` adds ``Y += R⁻¹``, ``y += R⁻¹ z``. All landmarks of all holders are updated at once
(numpy, ``(..., L, 2, 2)`` arrays); ``tests/rendezvous_mapping/test_rendezvous_fusion.py`` checks the result against
filterpy's ``InformationFilter`` on the same observations. The sums of packets into maps, the means and the bits of
each tree edge are compiled (``fusion_numba``); their numpy oracles are ``tests/helpers/rendezvous_reference.py``.

**Fusion.** Information is additive, so a vehicle's map is the common prior plus the sum of the
*packets* it holds: packet k of vehicle u is the information u gathered in its k-th observing window
(only non-empty windows make packets). Fusion moves whole packets, and a vehicle's own packets reach
others only through fusion, which always passes on everything the sender holds. Hence the packets of u
held by any vehicle are a *prefix* of u's sequence, and what vehicle w holds is described exactly by a
version vector ``known[w, u]`` = how many of u's packets w holds. This is the channel-filter
bookkeeping of [2] made exact: the information two vehicles hold in common (what a channel filter on
their link would store) is the prior plus u's first ``min(known[a, u], known[b, u])`` packets for every
u; a vehicle sends on a link only its information minus that common part, i.e. exactly the packets the
other side lacks, and nothing is ever added twice. A vehicle cut off from the team keeps its own
information and, on reconnecting, sends only the packets the others lack.

Over a group's spanning tree the edge (a, b) splits the group in two sides A and B; in the two passes of
tree fusion (towards the root, then back) the edge carries, a → b, the packets some vehicle in A holds
and no vehicle in B holds, and the reverse b → a: the least any scheme can send. Every vehicle of the
group ends with the union of the group's packets.

The **fused global map** is the information every vehicle of the team holds, prior plus
``min_w known[w, u]`` packets of every u: information counts only once it is fused into the common map.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from mrcomm_env.core.backend import kernel_array
from mrcomm_env.rendezvous import fusion_numba

#: bits of one float sent over the air
FLOAT_BITS = 32
#: bits of one count (an observation count or a version-vector entry)
COUNT_BITS = 16


def logdet2(Y: np.ndarray) -> np.ndarray:
    """ln det of a stack of symmetric positive-definite 2×2 matrices ``(..., 2, 2)``."""
    return np.log(Y[..., 0, 0] * Y[..., 1, 1] - Y[..., 0, 1] * Y[..., 1, 0])


def mean_of(Y: np.ndarray, y: np.ndarray) -> np.ndarray:
    """μ = Y⁻¹ y for stacks of 2×2 information matrices (closed-form inverse), in float64."""
    Y, y = kernel_array(Y, np.float64), kernel_array(y, np.float64)
    return fusion_numba.mean_of(Y.reshape(-1, 2, 2), y.reshape(-1, 2)).reshape(y.shape)


def observe(Y: np.ndarray, y: np.ndarray, landmarks: np.ndarray, z: np.ndarray, R_inv: np.ndarray) -> None:
    """Information-filter update, in place, of ``(Y, y)`` (``(L, 2, 2)``, ``(L, 2)``) with observations ``z``
    (``(m, 2)``) of ``landmarks`` (``(m,)``, repeats allowed) through H = I and noise information ``R_inv``
    (``(2, 2)`` or ``(m, 2, 2)``)."""
    R_inv = np.broadcast_to(R_inv, (len(landmarks), 2, 2))
    np.add.at(Y, landmarks, R_inv)
    np.add.at(y, landmarks, np.einsum("mij,mj->mi", R_inv, z))


@dataclass(frozen=True)
class Packet:
    """Information one vehicle gathered in one window: per observed landmark the added ``dy`` and the number of
    observations (which every holder adds to its count, for the sensor floor). The added information matrix is
    ``count · R⁻¹`` (H = I and one noise model, eq. (3)), which every holder computes from the count
    (:class:`TeamMaps` knows R⁻¹): it is sent (3 entries) but not stored."""

    landmarks: np.ndarray  # (m,) int
    dy: np.ndarray  # (m, 2)
    count: np.ndarray  # (m,) int

    def bits(self, n_landmarks: int) -> int:
        """Landmark index, the 3 distinct entries of dY, dy, and the count, per landmark (§III map update)."""
        return packet_bits(len(self.landmarks), n_landmarks)


def packet_bits(entries: int, n_landmarks: int) -> int:
    """Bits of a map update of ``entries`` landmarks: index, the 3 distinct entries of dY, dy, and the count each."""
    index_bits = max(1, int(np.ceil(np.log2(max(n_landmarks, 2)))))
    return int(entries) * (index_bits + 5 * FLOAT_BITS + COUNT_BITS)


#: entries added to a map in one call at most: the packets of a fusion after a long split are added piece by piece,
#: in order (the same sums), so that its working memory stays a few MB whatever the logs hold
PIECE_ENTRIES = 1 << 16

#: bytes a stored packet entry takes at most: landmark and count (int32), dy (2 float64), and, when the entry is a
#: packet of its own, its bounds and cumulative bits (int64 each); arrays grow by half, so times 1.5
STORED_ENTRY_BYTES = 1.5 * (4 + 4 + 16 + 8 + 8)


def _room(array: np.ndarray, needed: int) -> np.ndarray:
    """``array`` with room for ``needed`` rows: itself, or a copy half again as long (amortised appends)."""
    if needed <= len(array):
        return array
    grown = np.zeros((max(needed, len(array) + len(array) // 2 + 8),) + array.shape[1:], dtype=array.dtype)
    grown[: len(array)] = array
    return grown


class PacketLog:
    """One vehicle's packets, in flat arrays (their entries one after another, as gathered), with the cumulative
    bits of its first k packets.

    Packet numbers are absolute (version vectors count them from the episode's start), but the log keeps only
    those from ``first`` on: packets every vehicle holds are never sent again, so :meth:`drop_before` lets them
    go (the common map holds their sum). Memory then follows the packets some vehicle still lacks, not the
    episode's length."""

    def __init__(self) -> None:
        self.first = 0  # absolute number of the first packet kept
        self.kept = 0  # packets kept
        self.bounds = np.zeros(8, dtype=np.int64)  # packet first + j spans entries bounds[j] … bounds[j + 1]
        self.cum_bits = np.zeros(8, dtype=np.int64)  # bits of packets 0 … first + j − 1
        self.landmarks = np.zeros(8, dtype=np.int32)
        self.dy = np.zeros((8, 2))
        self.count = np.zeros(8, dtype=np.int32)

    @property
    def made(self) -> int:
        """Packets this vehicle made so far (kept or dropped)."""
        return self.first + self.kept

    @property
    def entries(self) -> int:
        """Entries of the kept packets."""
        return int(self.bounds[self.kept])

    def append(self, packet: Packet, bits: int) -> slice:
        """Keep ``packet`` (of ``bits`` bits) as the next one; returns the span of its entries."""
        m, e, k = len(packet.landmarks), self.entries, self.kept
        if e + m > len(self.landmarks):
            self.landmarks, self.dy, self.count = (_room(a, e + m) for a in (self.landmarks, self.dy, self.count))
        if k + 2 > len(self.bounds):
            self.bounds, self.cum_bits = _room(self.bounds, k + 2), _room(self.cum_bits, k + 2)
        self.landmarks[e : e + m] = packet.landmarks
        self.dy[e : e + m] = packet.dy
        self.count[e : e + m] = packet.count
        self.bounds[k + 1] = e + m
        self.cum_bits[k + 1] = self.cum_bits[k] + bits
        self.kept = k + 1
        return slice(e, e + m)

    def bits_before(self, k: int) -> int:
        """Bits of this vehicle's first ``k`` packets (``first ≤ k ≤ made``)."""
        return int(self.cum_bits[k - self.first])

    def span(self, start: int, stop: int) -> slice:
        """The entries of packets ``start … stop − 1`` (absolute numbers, ``first ≤ start ≤ stop ≤ made``)."""
        if not self.first <= start <= stop <= self.made:
            raise ValueError(f"packets {start} … {stop} are not all kept (kept: {self.first} … {self.made})")
        return slice(int(self.bounds[start - self.first]), int(self.bounds[stop - self.first]))

    def packets(self) -> list[Packet]:
        """The kept packets, in order (views of the log)."""
        spans = [self.span(k, k + 1) for k in range(self.first, self.made)]
        return [Packet(self.landmarks[s], self.dy[s], self.count[s]) for s in spans]

    def drop_before(self, k: int) -> None:
        """Let packets before ``k`` go (every vehicle holds them). The arrays are moved down only once at least as
        many packets are to go as stay, so each packet is moved a bounded number of times."""
        drop = k - self.first
        if drop <= 0 or drop < self.kept - drop:
            return
        e0, e1, keep = int(self.bounds[drop]), self.entries, self.kept - drop
        for name in ("landmarks", "dy", "count"):
            array = getattr(self, name)
            array[: e1 - e0] = array[e0:e1].copy()
        self.bounds[: keep + 1] = self.bounds[drop : self.kept + 1] - e0
        self.cum_bits[: keep + 1] = self.cum_bits[drop : self.kept + 1].copy()
        self.first, self.kept = k, keep


class TeamMaps:
    """Every vehicle's landmark map, the packets behind them (one :class:`PacketLog` per vehicle), and the fused
    common map. ``R_inv``: the information of one observation (2, 2); an entry of ``count`` observations adds
    ``count · R_inv`` to Y."""

    def __init__(self, n_vehicles: int, Y0: np.ndarray, y0: np.ndarray, R_inv: np.ndarray):
        n, L = n_vehicles, len(Y0)
        self.n, self.L = n, L
        self.Y0, self.y0 = Y0, y0
        self.R_inv = np.array(R_inv, dtype=np.float64).reshape(2, 2)
        self.Y = np.broadcast_to(Y0, (n, L, 2, 2)).copy()
        self.y = np.broadcast_to(y0, (n, L, 2)).copy()
        self.count = np.zeros((n, L), dtype=np.int64)
        self.logs = [PacketLog() for _ in range(n)]
        self.known = np.zeros((n, n), dtype=np.int64)  # version vectors: known[w, u] packets of u held by w
        self.common_Y, self.common_y = Y0.copy(), y0.copy()
        self.common_count = np.zeros(L, dtype=np.int64)
        self.common_known = np.zeros(n, dtype=np.int64)
        self._bits_table: tuple[np.ndarray, np.ndarray] | None = None  # the logs' cumulative bits, flat (compiled)
        self._entry_bits = packet_bits(1, L)

    # ------------------------------------------------------------------ local information
    def add_own(self, v: int, packet: Packet) -> None:
        """Vehicle v's newly gathered information: into its own map at once, and kept for fusion."""
        if len(packet.landmarks) == 0:
            return
        log = self.logs[v]
        new = log.append(packet, self._entry_bits * len(packet.landmarks))
        self._add(v, log.landmarks[new], log.dy[new], log.count[new])
        self._bits_table = None
        self.known[v, v] += 1

    def packets(self, u: int) -> list[Packet]:
        """The packets of vehicle u still kept: those some vehicle lacks, and any not yet let go."""
        return self.logs[u].packets()

    def _pieces(self, start: list[int], stop: list[int]) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """The entries of every vehicle u's packets ``start[u] … stop[u] − 1``, u in increasing order (the order
        they are added), as ``(landmarks, dy, count)`` pieces of at most :data:`PIECE_ENTRIES` entries."""
        parts: list[tuple[PacketLog, int, int]] = []
        size = 0
        for log, a, b in zip(self.logs, start, stop):
            if b <= a:
                continue
            span = log.span(a, b)
            for lo in range(span.start, span.stop, PIECE_ENTRIES):
                hi = min(span.stop, lo + PIECE_ENTRIES)
                if parts and size + hi - lo > PIECE_ENTRIES:
                    yield _joined(parts)
                    parts, size = [], 0
                parts.append((log, lo, hi))
                size += hi - lo
        if parts:
            yield _joined(parts)

    def _add(self, w: int, landmarks: np.ndarray, dy: np.ndarray, count: np.ndarray) -> None:
        _add_entries(self.Y[w], self.y[w], self.count[w], landmarks, dy, count, self.R_inv)

    # ------------------------------------------------------------------ fusion
    def fuse_group(
        self, members: np.ndarray, parent: np.ndarray, sides: dict[int, np.ndarray] | None = None
    ) -> dict[tuple[int, int], int]:
        """Fuse one connected group over its tree (``parent[i]``: i's tree parent, −1 at the root; ``sides``:
        its ``subtree_sides``, when the caller has them).

        Returns the map-update bits sent on each directed tree edge ``(sender, receiver)``. Afterwards every
        member holds the union of the members' packets.
        """
        members = np.asarray(members)
        sent: dict[tuple[int, int], int] = {}
        if len(members) > 1:
            if sides is None:
                sides = subtree_sides(members, parent)
            sent = self._edge_bits(members, parent, sides)
        union = self.known[members].max(0)
        upto = union.tolist()
        for w in members.tolist():
            held = self.known[w].tolist()
            if held != upto:
                for piece in self._pieces(held, upto):
                    self._add(w, *piece)
                self.known[w] = union
        return sent

    def _edge_bits(
        self, members: np.ndarray, parent: np.ndarray, sides: dict[int, np.ndarray]
    ) -> dict[tuple[int, int], int]:
        """Bits over each tree edge of a group, both ways: the packets one side holds beyond the other's (the
        logs' cumulative bits between the two sides' version vectors, in one call: ``fusion_numba.edge_bits``)."""
        sent: dict[tuple[int, int], int] = {}
        if self._bits_table is None:
            origin, at = [], 0
            for log in self.logs:
                origin.append(at - log.first)
                at += log.kept + 1
            kept = np.concatenate([log.cum_bits[: log.kept + 1] for log in self.logs])
            self._bits_table = (kept, np.array(origin, dtype=np.int64))
        firsts = list(sides)
        side_starts = np.zeros(len(firsts) + 1, dtype=np.int64)
        np.cumsum([len(sides[a]) for a in firsts], out=side_starts[1:])
        per_edge = fusion_numba.edge_bits(
            self.known,
            np.ascontiguousarray(members, dtype=np.int64),
            side_starts,
            np.concatenate([sides[a] for a in firsts]).astype(np.int64, copy=False),
            *self._bits_table,
        )
        for a, (forth, back) in zip(firsts, per_edge.tolist()):
            b = int(parent[a])
            sent[(a, b)], sent[(b, a)] = forth, back
        return sent

    def update_common(self) -> bool:
        """Fold into the common map the packets every vehicle now holds, and let them go from the logs (nobody
        lacks them any more); True when the common map grew."""
        floor = self.known.min(0)
        start, upto = self.common_known.tolist(), floor.tolist()
        grew = False
        for landmarks, dy, count in self._pieces(start, upto):
            _add_entries(self.common_Y, self.common_y, self.common_count, landmarks, dy, count, self.R_inv)
            grew = True
        self.common_known = floor
        if grew:
            for log, k in zip(self.logs, upto):
                log.drop_before(k)
            self._bits_table = None
        return grew

    # ------------------------------------------------------------------ bookkeeping views
    def information_of(self, version: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Y, y) of the common map plus the packets beyond it that a version vector names, summed afresh (for
        checks; ``version`` must hold at least the common map's packets, as every vehicle's does)."""
        if (np.asarray(version) < self.common_known).any():
            raise ValueError(
                f"argument 'version' must hold at least the common map's packets {self.common_known.tolist()}, "
                f"got {np.asarray(version).tolist()}"
            )
        Y, y = self.common_Y.copy(), self.common_y.copy()
        for landmarks, dy, count in self._pieces(self.common_known.tolist(), [int(k) for k in version]):
            np.add.at(Y, landmarks, count[:, None, None] * self.R_inv)
            np.add.at(y, landmarks, dy)
        return Y, y

    def channel_information(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        """What a channel filter on link (a, b) holds: the information a and b have in common."""
        return self.information_of(np.minimum(self.known[a], self.known[b]))

    def centralized(self) -> tuple[np.ndarray, np.ndarray]:
        """Prior plus every packet ever gathered once: the centralised information sum."""
        return self.information_of(np.array([log.made for log in self.logs]))


def _joined(parts: list[tuple[PacketLog, int, int]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The entries ``lo … hi − 1`` of each ``(log, lo, hi)``, one after another: views when there is one part."""
    if len(parts) == 1:
        log, lo, hi = parts[0]
        return log.landmarks[lo:hi], log.dy[lo:hi], log.count[lo:hi]
    return (
        np.concatenate([log.landmarks[lo:hi] for log, lo, hi in parts]),
        np.concatenate([log.dy[lo:hi] for log, lo, hi in parts]),
        np.concatenate([log.count[lo:hi] for log, lo, hi in parts]),
    )


def _add_entries(
    Y: np.ndarray,
    y: np.ndarray,
    count: np.ndarray,
    landmarks: np.ndarray,
    dy: np.ndarray,
    dcount: np.ndarray,
    R_inv: np.ndarray,
) -> None:
    """Add entries (in order: a landmark may repeat) into one map ``Y`` (L, 2, 2), ``y`` (L, 2), ``count`` (L,),
    in place: ``dcount · R_inv`` (``R_inv`` (2, 2)), ``dy`` (m, 2) and ``dcount`` (m,) at ``landmarks`` (m,), in
    order, as ``np.add.at`` adds them (``fusion_numba.add_counted``). A landmark outside the map raises
    ``IndexError``."""
    fusion_numba.add_counted(
        Y,
        y,
        count,
        kernel_array(landmarks, np.int32),
        kernel_array(dy, np.float64),
        kernel_array(dcount, np.int32),
        kernel_array(R_inv, np.float64),
    )


def subtree_sides(members: np.ndarray, parent: np.ndarray) -> dict[int, np.ndarray]:
    """For every non-root member a: the members on a's side of the tree edge (a, parent[a]) (a's subtree)."""
    members = [int(m) for m in members]
    children: dict[int, list[int]] = {m: [] for m in members}
    for m in members:
        if parent[m] >= 0:
            children[int(parent[m])].append(m)
    sides = {}
    for a in members:
        if parent[a] < 0:
            continue
        stack, side = [a], []
        while stack:
            x = stack.pop()
            side.append(x)
            stack.extend(children[x])
        sides[a] = np.array(sorted(side), dtype=np.int64)
    return sides
