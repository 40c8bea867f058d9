"""The mapping world of §VI: a square area, landmarks on a jittered grid, vehicles and their links.

Landmarks start on a uniform grid and are shifted by N(0, σ²) per axis while staying inside the area
(§VI-B.1); the shift is reflected at the borders so that large σ does not pile landmarks on the edges.
σ sets the mean clustering coefficient C (Watts–Strogatz [17]) of the landmark graph whose edges join
landmarks closer than a radius (d_comms or d_max = u·t_window).

Vehicles are linked when they are within d_comms of each other (``≤``, so that co-located vehicles are
linked when d_comms = 0: the "rendezvous" of §VI-B.3). At a decision phase each connected group fuses
over an acyclic network, the shortest-path tree from its lowest-index vehicle found with Dijkstra's
algorithm (§III).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from mrcomm_env.rendezvous import forest_numba

#: added to every link length so that co-located vehicles (distance 0) still form an edge: scipy's sparse
#: graphs read a stored 0 as "no edge"
LINK_LENGTH_FLOOR = 1e-6


def grid_shape(n_landmarks: int) -> tuple[int, int]:
    """Rows × columns of the smallest near-square grid holding ``n_landmarks`` points."""
    cols = math.ceil(math.sqrt(n_landmarks))
    rows = math.ceil(n_landmarks / cols)
    return rows, cols


def jittered_grid(n_landmarks: int, side: float, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """(L, 2) landmark positions: cell centres of a uniform grid, shifted by N(0, σ²), reflected into the area.

    When the grid has more cells than landmarks, a random subset of cells is used.
    """
    rows, cols = grid_shape(n_landmarks)
    cells = rng.permutation(rows * cols)[:n_landmarks]
    cells.sort()
    pos = np.column_stack([(cells % cols + 0.5) * side / cols, (cells // cols + 0.5) * side / rows])
    if sigma > 0:
        pos = pos + rng.normal(0.0, sigma, size=pos.shape)
        pos = reflect(pos, side)
    return pos


#: landmarks per cluster centre of :func:`clump` (⌈N_l / 8⌉ centres): clumps of about eight, a few landmarks more
#: than a vertex's neighbours in the paper's sparse graphs, so that clumping raises C instead of isolating points
LANDMARKS_PER_CLUMP = 8


def clump(pos: np.ndarray, side: float, clumping: float, rng: np.random.Generator) -> np.ndarray:
    """Move every landmark the fraction ``clumping`` of the way to the nearest of ⌈N_l/8⌉ centres drawn uniformly
    in the area (our extension of §VI-B.1: the σ-shift alone tends to a uniformly random layout, whose C is about
    0.55 in graphs as sparse as the paper's; clumps of landmarks raise C towards 1). No draw when 0."""
    if clumping <= 0.0:
        return pos
    centres = rng.uniform(0.0, side, size=(math.ceil(len(pos) / LANDMARKS_PER_CLUMP), 2))
    _, nearest = cKDTree(centres).query(pos)
    return pos + clumping * (centres[nearest] - pos)


def reflect(pos: np.ndarray, side: float) -> np.ndarray:
    """Fold coordinates into [0, side] by reflection at the borders."""
    period = np.mod(pos, 2.0 * side)
    return np.where(period > side, 2.0 * side - period, period)


def landmark_graph(pos: np.ndarray, radius: float) -> np.ndarray:
    """(L, L) bool adjacency: landmarks whose Euclidean separation is less than ``radius`` (§IV-C), no self loops."""
    if math.isinf(radius):
        adj = np.ones((len(pos), len(pos)), dtype=bool)
    else:
        d2 = ((pos[:, None, :] - pos[None, :, :]) ** 2).sum(-1)
        adj = d2 < radius * radius
    np.fill_diagonal(adj, False)
    return adj


def landmark_edges(pos: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The edges (i < j) of :func:`landmark_graph` without the (L, L) matrix: candidate pairs from a k-d tree,
    then the very same test ``Σ (x_i − x_j)² < radius²``, so that pairs at exactly ``radius`` (an unperturbed
    grid) fall on the same side as in the dense graph."""
    if math.isinf(radius):
        i, j = np.triu_indices(len(pos), 1)
        return i, j
    pairs = cKDTree(pos).query_pairs(radius * (1.0 + 1e-9) + 1e-300, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    keep = ((pos[i] - pos[j]) ** 2).sum(-1) < radius * radius
    return i[keep], j[keep]


def clustering_coefficient(pos: np.ndarray, radius: float) -> float:
    """Mean clustering coefficient C [17] of the landmark graph at ``radius`` (isolated nodes and leaves count 0).

    networkx's ``average_clustering``, computed as it does (c_v = 2 T(v) / (d_v (d_v − 1)), averaged in node
    order), but with the triangles T(v) from one sparse product (A·A ∘ A) over the edges a k-d tree finds: about
    linear in the landmarks for the sparse graphs of the figures, where networkx's per-node sets were cubic on a
    dense graph. A graph known complete from its bounding box (every pair closer than ``radius``) has C = 1.
    """
    n = len(pos)
    if n < 3:
        return 0.0
    span = float(np.hypot(*(pos.max(0) - pos.min(0))))
    if span < radius * (1.0 - 1e-9):  # every pair is an edge: each c_v = 1
        return 1.0
    i, j = landmark_edges(pos, radius)
    adj = csr_matrix((np.ones(2 * len(i)), (np.concatenate([i, j]), np.concatenate([j, i]))), shape=(n, n))
    degree = np.diff(adj.indptr)
    triangles = np.asarray((adj @ adj).multiply(adj).sum(1)).ravel() / 2.0
    total = 0.0
    for t, d in zip(triangles.astype(np.int64).tolist(), degree.tolist()):
        total += 0.0 if d < 2 else 2 * t / (d * (d - 1))
    return total / n


def vehicle_links(pos: np.ndarray, d_comms: float) -> np.ndarray:
    """(N, N) bool: vehicles within d_comms of each other (co-located ones always), no self loops."""
    n = len(pos)
    if math.isinf(d_comms):
        links = np.ones((n, n), dtype=bool)
    else:
        d = np.sqrt(((pos[:, None, :] - pos[None, :, :]) ** 2).sum(-1))
        links = d <= d_comms + 1e-9
    np.fill_diagonal(links, False)
    return links


def dense_components(adj: np.ndarray) -> tuple[int, np.ndarray]:
    """Connected components of a small symmetric bool adjacency *with its diagonal*, numbered in order of their
    lowest member (as ``scipy.sparse.csgraph.connected_components`` numbers them). A transitive closure by
    repeated squaring, ⌈log₂ n⌉ products at most: for the ≤ 64-node graphs here it is ~10× faster than
    scipy's sparse set-up."""
    n = len(adj)
    reach = adj.astype(np.float32)
    while True:
        closed = (reach @ reach) > 0
        if (closed == (reach > 0)).all():
            break
        reach = closed.astype(np.float32)
    first = np.argmax(reach > 0, axis=1)  # lowest member of each vertex's component
    number = np.cumsum(first == np.arange(n)) - 1
    labels = number[first].astype(np.int32)
    return int(labels.max()) + 1, labels


def spanning_forest(pos: np.ndarray, links: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Connected groups and their acyclic fusion networks (§III).

    Returns ``(labels, parent)``: ``labels[i]`` numbers i's connected group (groups numbered in order of
    their lowest-index vehicle, which is the root), ``parent[i]`` is i's parent in the group's Dijkstra
    shortest-path tree (−1 at the root). Link lengths are Euclidean distances. One compiled call
    (``forest_numba.spanning_forest``), unless equal path lengths make the trees ambiguous: then scipy's
    Dijkstra settles them (:func:`dijkstra_forest`, whose trees the kernel's are whenever it answers).
    """
    n = len(pos)
    if n == 1:
        return np.zeros(1, dtype=np.int64), np.full(1, -1, dtype=np.int64)
    labels, parent, ambiguous = forest_numba.spanning_forest(pos, links, LINK_LENGTH_FLOOR)
    return dijkstra_forest(pos, links) if ambiguous else (labels, parent)


def dijkstra_forest(pos: np.ndarray, links: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`spanning_forest` by scipy's Dijkstra from each group's lowest vehicle (its choice among paths of equal
    length is the forest's)."""
    n = len(pos)
    d = np.sqrt(((pos[:, None, :] - pos[None, :, :]) ** 2).sum(-1)) + LINK_LENGTH_FLOOR
    k, labels = dense_components(links | np.eye(n, dtype=bool))
    labels = labels.astype(np.int64)
    if k == n:  # nobody linked: no trees to build
        return labels, np.full(n, -1, dtype=np.int64)
    roots = np.flatnonzero(np.r_[True, labels[1:] > np.maximum.accumulate(labels)[:-1]])  # lowest of each group
    graph = csr_matrix(np.where(links, d, 0.0))
    _, pred, _ = dijkstra(graph, directed=False, indices=roots, return_predecessors=True, min_only=True)
    parent = np.where(pred < 0, -1, pred).astype(np.int64)
    return labels, parent
