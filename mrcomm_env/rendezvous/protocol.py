"""The Utility and Communication Network module of §IV (the recommendation phase), as pure functions.

The env runs it at every decision phase on each connected group's shared map, because the group's plan
defines the rendezvous landmark l_c the actions refer to; the ``paper_protocol`` baseline
(``baselines/rendezvous_mapping.py``) runs the same functions on its own local views and adds the
Action module of §V.

* :func:`utility_matrix` — eq. (1)–(4): U_v(l) = ½ ln |I_{v,l} + Y_l| / |Y_l| with I_{v,l} = t_obs I_obs,
  t_obs = t_window − ‖x_v − x_l‖/u, or ε when the landmark cannot be reached in the window.
* :func:`assign` — Munkres [15] (``scipy.optimize.linear_sum_assignment``, maximising utility).
* :func:`clusters` — the fine Dulmage–Mendelsohn blocks [14] of the adjacency of the assigned landmarks.
  For a symmetric adjacency with its diagonal (a landmark is in range of itself) the diagonal is a
  perfect matching and the fine blocks are the strongly connected components of the symmetric graph,
  i.e. its connected components (MATLAB's ``dmperm(A + speye(n))`` idiom); computed with
  ``scipy.sparse.csgraph``, and :func:`fine_dm_blocks` builds the decomposition directly for the test.
* :func:`central_landmark` — eigenvector centrality [16] of the best cluster's adjacency.
* :func:`recommend` — eq. (5)–(8): cluster value J, μ_max, l_c, outlier l_o and the half-plane cut,
  repeated until the assigned landmarks are connected or fewer working landmarks than vehicles remain. On the
  compiled backend (``core.backend``) the whole loop runs as one numba call (:mod:`.plan_numba`,
  ``recommend_loop``: Munkres as scipy computes it), with the same results; where numpy's rounding of eq. (8)
  could matter it hands over to the passes below, whose clustering, eq. (6), l_c, eq. (7) and the offsets of
  eq. (8) are still one numba call each.

Ties among a row's best landmarks go to the lowest id (a stable sort), never to numpy's ``argpartition``, which
numpy dispatches to SIMD code by CPU: its choice among equal values differs from one CPU to another, so a seeded
episode's plan would too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, maximum_bipartite_matching

from mrcomm_env.core import backend
from mrcomm_env.core.backend import kernel_array
from mrcomm_env.rendezvous import plan_numba
from mrcomm_env.rendezvous.world import dense_components

#: ε of §IV-A: the observation time (s) credited to a landmark that cannot be reached within the window,
#: "to provide some incentive to travel towards a landmark"
EPS_OBS_TIME = 1e-3


def utility_matrix(
    Y: np.ndarray,
    count: np.ndarray,
    vehicle_pos: np.ndarray,
    landmark_pos: np.ndarray,
    speed: float,
    t_window: float,
    info_per_obs: float,
    obs_rate: float,
    budget: int,
) -> np.ndarray:
    """Eq. (1)–(4): the (n, L) mutual-information gain of each vehicle observing each landmark.

    ``Y`` is ``(L, 2, 2)`` (a shared map) or ``(n, L, 2, 2)`` (one map per vehicle), ``count`` ``(L,)`` or
    ``(n, L)`` the observations of each landmark the map holds, ``landmark_pos`` ``(L, 2)`` or ``(n, L, 2)``
    the map's landmark estimates. Observations are isotropic, R⁻¹ = ``info_per_obs`` I,
    made at ``obs_rate`` per second, so I_obs = obs_rate·R⁻¹ (eq. 3). The sensor floor caps a landmark at
    ``budget`` independent observations: the gain counts at most the ``budget − count`` the map believes
    remain (a landmark believed exhausted is worth 0).
    """
    n, L = np.shape(vehicle_pos)[0], np.shape(count)[-1]
    # one map per vehicle, shapes exactly as the env's (the kernel indexes them without numpy's broadcasting)
    per_vehicle = np.shape(Y) == (n, L, 2, 2) and np.shape(count) == (n, L) and np.shape(landmark_pos) == (n, L, 2)
    if per_vehicle and np.shape(vehicle_pos) == (n, 2) and backend.compiled():  # one call, up to numpy's log1p
        argument = plan_numba.utility_argument(
            kernel_array(Y, np.float64),
            kernel_array(count, np.int64),
            kernel_array(vehicle_pos, np.float64),
            kernel_array(landmark_pos, np.float64),
            float(speed),
            float(t_window),
            float(info_per_obs),
            float(obs_rate),
            int(budget),
            EPS_OBS_TIME,
        )
        return 0.5 * np.log1p(argument)
    offset = vehicle_pos[:, None, :] - (landmark_pos if landmark_pos.ndim == 3 else landmark_pos[None, :, :])
    d = np.sqrt(offset[..., 0] ** 2 + offset[..., 1] ** 2)
    t_obs = t_window - d / speed  # eq. (4) inside t_obs = t_window − t_travel
    t_obs = np.where(t_obs > 0.0, t_obs, EPS_OBS_TIME)
    remaining = np.maximum(budget - count, 0)
    g = np.minimum(t_obs * obs_rate, remaining) * info_per_obs  # eq. (3), isotropic: I = g·I₂
    a, b, dd = Y[..., 0, 0], Y[..., 0, 1], Y[..., 1, 1]
    return 0.5 * np.log1p((g * (a + dd) + g * g) / (a * dd - b * b))  # eq. (1), |Y + gI| = |Y| + g tr Y + g²


def assign(U: np.ndarray, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Munkres over the landmark columns ``columns``: (vehicle rows, landmark ids) of the max-utility matching.

    Only the union of every row's n best columns can be matched (a row matched outside its own n best leaves
    one of them free for a swap that is no worse), so Munkres runs on at most n² columns.
    """
    candidates = candidate_columns(U, columns)
    rows, cols = linear_sum_assignment(U[:, candidates], maximize=True)
    return rows, candidates[cols]


def candidate_columns(U: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """The columns Munkres needs to see among ``columns``: all of them up to n², else the sorted union of every
    row's n best (ties to the lowest column, :func:`best_positions`)."""
    n = U.shape[0]
    if len(columns) <= n * n:
        return columns
    # the sorted union, as np.unique gives it, in two calls (np.unique costs ~8 µs on these few ids)
    return columns[np.flatnonzero(np.bincount(best_positions(-U, columns).ravel()))]


def best_positions(negated_U: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """(n, n): the positions in ``columns`` of every row's n best, from −U: a stable sort, so ties go to the lowest
    position and a NaN after every number. (numpy's ``argpartition`` would be O(W), but its choice among ties
    depends on the CPU's SIMD selection code.)"""
    n = negated_U.shape[0]
    return np.argsort(negated_U[:, columns], axis=1, kind="stable")[:, :n]


def adjacency(pos: np.ndarray, d_comms: float) -> np.ndarray:
    """Bool adjacency of the given landmarks: separation less than d_comms (§IV-C), with the diagonal."""
    if math.isinf(d_comms):
        return np.ones((len(pos), len(pos)), dtype=bool)
    adj = ((pos[:, None, :] - pos[None, :, :]) ** 2).sum(-1) < d_comms * d_comms
    np.fill_diagonal(adj, True)
    return adj


#: up to this many landmarks, :func:`clusters` closes the adjacency densely instead of calling scipy's sparse
#: graph routines, whose set-up costs ~0.3 ms per call on a 10 × 10 matrix (the plan calls it many times)
DENSE_CLUSTERS_MAX = 64


def clusters(adj: np.ndarray) -> tuple[int, np.ndarray]:
    """The fine Dulmage–Mendelsohn blocks of a symmetric adjacency with diagonal: its connected components,
    numbered in order of their lowest member (as ``scipy.sparse.csgraph.connected_components`` numbers them)."""
    n = len(adj)
    if n == 1:
        return 1, np.zeros(1, dtype=np.int32)
    if n > DENSE_CLUSTERS_MAX:
        return connected_components(csr_matrix(adj), directed=False)
    return dense_components(adj)


def fine_dm_blocks(adj: np.ndarray) -> list[frozenset[int]]:
    """The fine Dulmage–Mendelsohn decomposition of a square matrix with a perfect matching, built directly:
    match rows to columns (Hopcroft–Karp), orient the bipartite graph by the matching, and take the strongly
    connected components (Pothen & Fan [14]). Used to check :func:`clusters`."""
    a = csr_matrix(adj.astype(np.int8))
    match = maximum_bipartite_matching(a, perm_type="column")  # match[row] = column
    if (match < 0).any():
        raise ValueError("the matrix has no perfect matching; its fine decomposition has coarse parts")
    n = adj.shape[0]
    # directed graph on rows: row i → row j when column match[j] has a nonzero in row i
    row_of_col = np.empty(n, dtype=np.int64)
    row_of_col[match] = np.arange(n)
    rows, cols = np.nonzero(adj)
    digraph = csr_matrix((np.ones(len(rows)), (rows, row_of_col[cols])), shape=(n, n))
    k, labels = connected_components(digraph, directed=True, connection="strong")
    return [frozenset(np.flatnonzero(labels == b).tolist()) for b in range(k)]


def central_landmark(adj: np.ndarray, pos: np.ndarray) -> int:
    """Index (into ``adj``) of the most central landmark: the largest entry of the Perron eigenvector of the
    cluster's adjacency [16]. Ties (complete graphs, pairs) go to the landmark nearest the cluster's centroid,
    then to the lowest index."""
    n = len(adj)
    if n == 1:
        return 0
    a = adj.astype(np.float64)
    np.fill_diagonal(a, 0.0)  # A and A + I have the same eigenvectors
    _, vecs = np.linalg.eigh(a)
    lead = np.abs(vecs[:, -1])
    top = np.flatnonzero(lead >= lead.max() * (1.0 - 1e-9))
    if len(top) > 1:
        centre = pos.mean(0)
        top = top[np.argsort(((pos[top] - centre) ** 2).sum(-1), kind="stable")]
    return int(top[0])


@dataclass
class PartitionStep:
    """One pass of §IV-C/D, kept for drawing Fig. 4."""

    working: np.ndarray  # l_w at the start of the pass
    assignment: np.ndarray  # (n,) landmark of each vehicle, −1 none
    cluster_of: np.ndarray  # (n,) cluster label of each vehicle's landmark, −1 none
    main: int  # label of μ_max
    central: int  # l_c
    outlier: int  # l_o, −1 when the assignment was connected


@dataclass
class Recommendation:
    """What the recommendation phase hands the Action module (§V)."""

    assignment: np.ndarray  # (n,) l_p(v), −1 when v is not assigned
    in_main: np.ndarray  # (n,) bool: l_p(v) ∈ μ_max
    central: int  # l_c
    connected: bool  # the assigned landmarks form one cluster
    steps: list[PartitionStep] = field(default_factory=list)


def recommend(U: np.ndarray, landmark_pos: np.ndarray, d_comms: float, record: bool = False) -> Recommendation:
    """§IV-B–D: assign, cluster, and cut outliers until the assigned landmarks are connected.

    ``U`` is the group's (n, L) utility matrix (eq. 1), ``landmark_pos`` the group's (L, 2) landmark
    estimates. The cut (eq. 8) keeps the landmarks l with (x_lo − x_lc)ᵀ(x_lo − x_l) > 0, which always drops
    l_o itself, so the loop ends. When fewer working landmarks than vehicles remain, the last assignment is
    returned, marked unconnected.
    """
    n, L = U.shape
    working = np.arange(L)
    steps: list[PartitionStep] = []
    if n == 1 and not record:  # one vehicle: its best landmark is a connected cluster of one (shortcut)
        best = int(np.argmax(U[0]))
        return Recommendation(np.array([best]), np.array([True]), best, True, steps)
    kernels = plan_numba if backend.compiled() else None
    if kernels is not None:  # one compiled signature: a read-only or strided view would compile the kernels again
        U, landmark_pos = kernel_array(U, np.float64), kernel_array(landmark_pos, np.float64)
    if kernels is not None and not record:  # the passes compiled, up to an eq. (8) sign numpy could round otherwise
        status, working, assignment, in_main, central, connected = kernels.recommend_loop(
            U, landmark_pos, float(d_comms), working
        )
        if status == kernels.PLANNED:
            return Recommendation(assignment, in_main, int(central), bool(connected), steps)
        # AMBIGUOUS: the passes below go on from this working set
    while True:
        rows, lp = assign(U, working)
        if kernels is None:
            adj = adjacency(landmark_pos[lp], d_comms)
            k, labels = clusters(adj)
            if k == 1:
                main = 0
            else:
                J = np.bincount(labels, weights=U[rows, lp], minlength=k)  # eq. (6)
                main = int(np.argmax(J))
            members = np.flatnonzero(labels == main)
            lc = int(lp[members[central_landmark(adj[np.ix_(members, members)], landmark_pos[lp[members]])]])
            if k == 1:
                lo = -1
            else:
                outside = lp[labels != main]
                d2 = ((landmark_pos[outside] - landmark_pos[lc]) ** 2).sum(-1)
                lo = int(outside[int(np.argmax(d2))])  # eq. (7)
                axis = landmark_pos[lo] - landmark_pos[lc]
                offsets = landmark_pos[lo] - landmark_pos[working]
        else:  # the same pass compiled, up to eq. (8)'s product
            k, labels, main, lc, lo, axis, offsets = kernels.partition_pass(
                U, landmark_pos, rows, lp, float(d_comms), working
            )
        if record:
            steps.append(PartitionStep(working, _per_vehicle(n, rows, lp), _per_vehicle(n, rows, labels), main, lc, lo))
        if k == 1:
            assignment = _per_vehicle(n, rows, lp)
            return Recommendation(assignment, assignment >= 0, lc, True, steps)
        keep = offsets @ axis > 0.0  # eq. (8)
        if keep.sum() < n:
            in_main = np.zeros(n, dtype=bool)
            in_main[rows] = labels == main
            return Recommendation(_per_vehicle(n, rows, lp), in_main, lc, False, steps)
        working = working[keep]


def _per_vehicle(n: int, rows: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(n,) int64: ``values`` at the matched vehicle ``rows``, −1 at the vehicles Munkres left unassigned."""
    out = np.full(n, -1, dtype=np.int64)
    out[rows] = values
    return out
