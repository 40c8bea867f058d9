"""Communication mechanics shared by every environment.

Adjacency is a dense boolean ``(N, N)`` matrix with ``adj[i, j]`` meaning "a message from i reaches
j this step", and a false diagonal. Link models are symmetric (bidirectional links); packet loss
then removes directed deliveries independently, so a link can work one way only.
Large populations use :func:`disk_pairs`, which returns the edge list from a k-d tree instead of a
dense matrix.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.spatial import cKDTree


@lru_cache(maxsize=32)
def _strict_upper(n: int) -> np.ndarray:
    mask = np.triu(np.ones((n, n), dtype=bool), k=1)
    mask.flags.writeable = False
    return mask


def bernoulli_links(rng: np.random.Generator, n: int, p: float) -> np.ndarray:
    """Independent bidirectional links, each pair up with probability ``p`` this step.

    One ``(n, n)`` draw per step whose strict upper triangle decides each pair (the mask is cached: this
    runs every step of every env that uses it).
    """
    upper = rng.random((n, n)) < p
    upper &= _strict_upper(n)
    return upper | upper.T


def disk_links(positions: np.ndarray, radius: float) -> np.ndarray:
    """Bidirectional links between every pair closer than ``radius`` (inclusive)."""
    n = len(positions)
    adj = np.zeros((n, n), dtype=bool)
    if n > 64:
        pairs = disk_pairs(positions, radius)
        adj[pairs[:, 0], pairs[:, 1]] = True
        adj[pairs[:, 1], pairs[:, 0]] = True
        return adj
    diff = positions[:, None, :] - positions[None, :, :]
    adj = np.einsum("ijk,ijk->ij", diff, diff) <= radius * radius
    np.fill_diagonal(adj, False)
    return adj


def disk_pairs(positions: np.ndarray, radius: float) -> np.ndarray:
    """Pairs ``(i, j)`` with ``i < j`` within ``radius``, as an ``(E, 2)`` int array (k-d tree)."""
    return cKDTree(positions).query_pairs(radius, output_type="ndarray")


def grid_links(side: int, cols: int | None = None) -> np.ndarray:
    """4-neighbour adjacency of a ``side × cols`` grid; robot ``r * cols + c`` sits at row r, column c."""
    cols = side if cols is None else cols
    n = side * cols
    adj = np.zeros((n, n), dtype=bool)
    idx = np.arange(n).reshape(side, cols)
    right = (idx[:, :-1].ravel(), idx[:, 1:].ravel())
    down = (idx[:-1, :].ravel(), idx[1:, :].ravel())
    for a, b in (right, down):
        adj[a, b] = True
        adj[b, a] = True
    return adj


def combined_links(rng: np.random.Generator, positions: np.ndarray, radius: float, p: float) -> np.ndarray:
    """A link exists when the pair is within ``radius`` *and* its Bernoulli(p) draw succeeds."""
    return disk_links(positions, radius) & bernoulli_links(rng, len(positions), p)


def apply_packet_loss(rng: np.random.Generator, adj: np.ndarray, loss: float) -> np.ndarray:
    """Drop each directed delivery independently with probability ``loss`` (no draw when ``loss`` is 0)."""
    if loss <= 0.0:
        return adj
    return adj & (rng.random(adj.shape) >= loss)


class TDMASchedule:
    """One slot per robot per frame, in an order drawn once per episode."""

    def __init__(self, n: int, rng: np.random.Generator, shuffle: bool = True):
        self.n = n
        self.order = rng.permutation(n) if shuffle else np.arange(n)
        #: slot index of each robot within the frame
        self.slot_of = np.empty(n, dtype=np.int64)
        self.slot_of[self.order] = np.arange(n)

    def owner(self, slot: int) -> int:
        """Robot that transmits in global slot number ``slot``."""
        return int(self.order[slot % self.n])


def fit_to_budget(sizes_bits: np.ndarray, budget_bits: float | None) -> int:
    """How many items, taken in the given order, fit into ``budget_bits`` (all of them if no budget)."""
    if budget_bits is None or len(sizes_bits) == 0:
        return len(sizes_bits)
    return int(np.searchsorted(np.cumsum(sizes_bits), budget_bits, side="right"))


class BitLedger:
    """Exact bit accounting: bits each agent sent this step and over the episode."""

    def __init__(self, n_agents: int):
        self.step_bits = np.zeros(n_agents, dtype=np.float64)
        self.total_bits = np.zeros(n_agents, dtype=np.float64)
        self.messages = 0

    def begin_step(self) -> None:
        self.step_bits[:] = 0.0

    def add(self, agent: int | np.ndarray, bits: float | np.ndarray, messages: int = 1) -> None:
        """Charge ``bits`` to ``agent`` (an index or an index array with matching ``bits``)."""
        if type(agent) is int and type(bits) in (
            int,
            float,
        ):  # one agent: np.add.at's single addition, minus its overhead
            self.step_bits[agent] += bits
            self.total_bits[agent] += bits
        else:
            np.add.at(self.step_bits, agent, bits)
            np.add.at(self.total_bits, agent, bits)
        self.messages += messages

    def record(self, bits: np.ndarray, messages: int) -> None:
        """This step's bits of every agent at once (replaces ``begin_step`` + ``add`` for all agents)."""
        np.copyto(self.step_bits, bits)
        self.total_bits += self.step_bits
        self.messages += messages

    def reset(self) -> None:
        self.step_bits[:] = 0.0
        self.total_bits[:] = 0.0
        self.messages = 0
