"""Information filters per landmark (§III) and decentralised fusion that never counts information twice.

**Filter.** Every landmark's 2-D position is held in information form, ``Y = Σ⁻¹`` and ``y = Σ⁻¹ μ``
([13], §III). Landmarks are static, so prediction is the identity, and an observation ``z = x + v``,
``v ~ N(0, R)`` adds ``Y += R⁻¹``, ``y += R⁻¹ z``. All landmarks of all holders are updated at once
(numpy, ``(..., L, 2, 2)`` arrays); ``tests/test_rendezvous_mapping.py`` checks the result against
filterpy's ``InformationFilter`` on the same observations.

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

from dataclasses import dataclass
from functools import cache

import numpy as np

from mrcomm_env.core import backend

#: bits of one float sent over the air
FLOAT_BITS = 32
#: bits of one count (an observation count or a version-vector entry)
COUNT_BITS = 16


def logdet2(Y: np.ndarray) -> np.ndarray:
    """ln det of a stack of symmetric positive-definite 2×2 matrices ``(..., 2, 2)``."""
    return np.log(Y[..., 0, 0] * Y[..., 1, 1] - Y[..., 0, 1] * Y[..., 1, 0])


def mean_of(Y: np.ndarray, y: np.ndarray) -> np.ndarray:
    """μ = Y⁻¹ y for stacks of 2×2 information matrices (closed-form inverse)."""
    if backend.compiled() and Y.dtype == y.dtype == np.float64 and Y.flags.c_contiguous and y.flags.c_contiguous:
        return _fusion_kernels().mean_of(Y.reshape(-1, 2, 2), y.reshape(-1, 2)).reshape(y.shape)
    a, b, c, d = Y[..., 0, 0], Y[..., 0, 1], Y[..., 1, 0], Y[..., 1, 1]
    det = a * d - b * c
    return np.stack([(d * y[..., 0] - b * y[..., 1]) / det, (a * y[..., 1] - c * y[..., 0]) / det], axis=-1)


def observe(Y: np.ndarray, y: np.ndarray, landmarks: np.ndarray, z: np.ndarray, R_inv: np.ndarray) -> None:
    """Information-filter update, in place, of ``(Y, y)`` (``(L, 2, 2)``, ``(L, 2)``) with observations ``z``
    (``(m, 2)``) of ``landmarks`` (``(m,)``, repeats allowed) through H = I and noise information ``R_inv``
    (``(2, 2)`` or ``(m, 2, 2)``)."""
    R_inv = np.broadcast_to(R_inv, (len(landmarks), 2, 2))
    np.add.at(Y, landmarks, R_inv)
    np.add.at(y, landmarks, np.einsum("mij,mj->mi", R_inv, z))


@dataclass(frozen=True)
class Packet:
    """Information one vehicle gathered in one window: per observed landmark the added ``dY`` and ``dy`` and
    the number of observations (which every holder adds to its count, for the sensor floor)."""

    landmarks: np.ndarray  # (m,) int
    dY: np.ndarray  # (m, 2, 2)
    dy: np.ndarray  # (m, 2)
    count: np.ndarray  # (m,) int

    def bits(self, n_landmarks: int) -> int:
        """Landmark index, the 3 distinct entries of dY, dy, and the count, per landmark (§III map update)."""
        index_bits = max(1, int(np.ceil(np.log2(max(n_landmarks, 2)))))
        return int(len(self.landmarks)) * (index_bits + 5 * FLOAT_BITS + COUNT_BITS)


class TeamMaps:
    """Every vehicle's landmark map, the packets behind them, and the fused common map."""

    def __init__(self, n_vehicles: int, Y0: np.ndarray, y0: np.ndarray):
        n, L = n_vehicles, len(Y0)
        self.n, self.L = n, L
        self.Y0, self.y0 = Y0, y0
        self.Y = np.broadcast_to(Y0, (n, L, 2, 2)).copy()
        self.y = np.broadcast_to(y0, (n, L, 2)).copy()
        self.count = np.zeros((n, L), dtype=np.int64)
        self.packets: list[list[Packet]] = [[] for _ in range(n)]
        self.packet_bits: list[list[int]] = [[0] for _ in range(n)]  # cumulative bits of u's first k packets
        self._cum_bits = np.zeros((n, 16), dtype=np.int64)  # packet_bits as an array (row u: u's list, zero padded)
        self.known = np.zeros((n, n), dtype=np.int64)  # version vectors: known[w, u] packets of u held by w
        self.common_Y, self.common_y = Y0.copy(), y0.copy()
        self.common_count = np.zeros(L, dtype=np.int64)
        self.common_known = np.zeros(n, dtype=np.int64)

    # ------------------------------------------------------------------ local information
    def add_own(self, v: int, packet: Packet) -> None:
        """Vehicle v's newly gathered information: into its own map at once, and kept for fusion."""
        if len(packet.landmarks) == 0:
            return
        self._apply(v, [packet])
        self.packets[v].append(packet)
        total = self.packet_bits[v][-1] + packet.bits(self.L)
        self.packet_bits[v].append(total)
        k = len(self.packet_bits[v]) - 1
        if k == self._cum_bits.shape[1]:  # room for twice as many packets
            self._cum_bits = np.concatenate([self._cum_bits, np.zeros_like(self._cum_bits)], axis=1)
        self._cum_bits[v, k] = total
        self.known[v, v] += 1

    def _apply(self, w: int, packets: list[Packet]) -> None:
        if packets:
            _add_packets(self.Y[w], self.y[w], self.count[w], packets)

    # ------------------------------------------------------------------ fusion
    def missing_bits(self, have: np.ndarray, want: np.ndarray) -> int:
        """Bits of the packets in ``want`` (a version vector) beyond ``have``."""
        bits = self.packet_bits
        return int(sum(bits[u][w] - bits[u][h] for u, (h, w) in enumerate(zip(have.tolist(), want.tolist())) if w > h))

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
            lack = [p for u, packets in enumerate(self.packets) for p in packets[held[u] : upto[u]]]
            self._apply(w, lack)
            self.known[w] = union
        return sent

    def _edge_bits(
        self, members: np.ndarray, parent: np.ndarray, sides: dict[int, np.ndarray]
    ) -> dict[tuple[int, int], int]:
        """Bits over each tree edge of a group, both ways: the packets one side holds beyond the other's."""
        sent: dict[tuple[int, int], int] = {}
        if backend.compiled():  # the loop below in one call (fusion_numba.edge_bits), the same whole numbers
            firsts = list(sides)
            starts = np.zeros(len(firsts) + 1, dtype=np.int64)
            np.cumsum([len(sides[a]) for a in firsts], out=starts[1:])
            per_edge = _fusion_kernels().edge_bits(
                self.known,
                np.ascontiguousarray(members, dtype=np.int64),
                starts,
                np.concatenate([sides[a] for a in firsts]).astype(np.int64, copy=False),
                self._cum_bits,
            )
            for a, (forth, back) in zip(firsts, per_edge.tolist()):
                b = int(parent[a])
                sent[(a, b)], sent[(b, a)] = forth, back
            return sent
        in_group = np.zeros(self.n, dtype=bool)
        in_group[members] = True
        for a, side_a in sides.items():
            b = int(parent[a])
            other = in_group.copy()
            other[side_a] = False
            union_a, union_b = self.known[side_a].max(0), self.known[other].max(0)
            sent[(a, b)] = self.missing_bits(union_b, union_a)
            sent[(b, a)] = self.missing_bits(union_a, union_b)
        return sent

    def update_common(self) -> bool:
        """Fold into the common map the packets every vehicle now holds; True when it grew."""
        floor = self.known.min(0)
        start, upto = self.common_known.tolist(), floor.tolist()
        new = [p for u, packets in enumerate(self.packets) for p in packets[start[u] : upto[u]]]
        self.common_known = floor
        if not new:
            return False
        _add_packets(self.common_Y, self.common_y, self.common_count, new)
        return True

    # ------------------------------------------------------------------ bookkeeping views
    def information_of(self, version: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Y, y) of the prior plus the packets named by a version vector, summed afresh (for checks)."""
        Y, y = self.Y0.copy(), self.y0.copy()
        for u in range(self.n):
            for p in self.packets[u][: version[u]]:
                np.add.at(Y, p.landmarks, p.dY)
                np.add.at(y, p.landmarks, p.dy)
        return Y, y

    def channel_information(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        """What a channel filter on link (a, b) holds: the information a and b have in common."""
        return self.information_of(np.minimum(self.known[a], self.known[b]))

    def centralized(self) -> tuple[np.ndarray, np.ndarray]:
        """Prior plus every packet ever gathered once: the centralised information sum."""
        return self.information_of(np.array([len(p) for p in self.packets]))


def _add_packets(Y: np.ndarray, y: np.ndarray, count: np.ndarray, packets: list[Packet]) -> None:
    """Add ``packets`` (in order) into one map ``Y`` (L, 2, 2), ``y`` (L, 2), ``count`` (L,), in place."""
    if len(packets) == 1:
        p = packets[0]
        idx, dY, dy, dcount = p.landmarks, p.dY, p.dy, p.count
    else:
        idx = np.concatenate([p.landmarks for p in packets])
        dY = np.concatenate([p.dY for p in packets])
        dy = np.concatenate([p.dy for p in packets])
        dcount = np.concatenate([p.count for p in packets])
    if backend.compiled():  # the same additions in the same order, in one call (fusion_numba)
        _fusion_kernels().add_packets(
            Y, y, count, _plain(idx, np.int64), _plain(dY, np.float64), _plain(dy, np.float64), _plain(dcount, np.int64)
        )
        return
    np.add.at(Y, idx, dY)
    np.add.at(y, idx, dy)
    np.add.at(count, idx, dcount)


def _plain(array, dtype) -> np.ndarray:
    """``array`` as a C-contiguous array of ``dtype`` (a copy only when it is not one): one compiled signature."""
    return np.ascontiguousarray(array, dtype=dtype)


@cache
def _fusion_kernels():
    """The compiled fusion (``fusion_numba``), imported on first use: numba is optional."""
    from mrcomm_env.rendezvous import fusion_numba

    return fusion_numba


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
