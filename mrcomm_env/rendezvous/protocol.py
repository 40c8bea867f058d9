"""The Utility and Communication Network module of §IV (the recommendation phase), as pure functions.

The env runs it at every decision phase on each connected group's shared map, because the group's plan
defines the rendezvous landmark l_c the actions refer to; the ``paper_protocol`` baseline
(``baselines/rendezvous_mapping.py``) runs the same functions on its own local views and adds the
Action module of §V.

* :func:`utility_matrix` — eq. (1)–(4): U_v(l) = ½ ln |I_{v,l} + Y_l| / |Y_l| with I_{v,l} = t_obs I_obs,
  t_obs = t_window − ‖x_v − x_l‖/u, or ε when the landmark cannot be reached in the window.
* :func:`assign` — Munkres [15] (``scipy.optimize.linear_sum_assignment``, maximising utility).
* :func:`recommend` — eq. (5)–(8): the clusters of the assigned landmarks, cluster value J, μ_max, l_c, outlier
  l_o and the half-plane cut, repeated until the assigned landmarks are connected or fewer working landmarks than
  vehicles remain. The clusters are the fine Dulmage–Mendelsohn blocks [14] of the adjacency of the assigned
  landmarks: for a symmetric adjacency with its diagonal (a landmark is in range of itself) the diagonal is a
  perfect matching and the fine blocks are the strongly connected components of the symmetric graph, i.e. its
  connected components (MATLAB's ``dmperm(A + speye(n))`` idiom); l_c is the largest entry of the Perron vector of
  the main cluster's adjacency, eigenvector centrality [16]. The whole loop runs as one numba call
  (:mod:`.plan_numba`, ``recommend_loop``: Munkres as scipy computes it); where numpy's rounding of eq. (8) could
  matter it hands over to the passes below, whose clustering, eq. (6), l_c, eq. (7) and the offsets of eq. (8) are
  one numba call each (``partition_pass``). Their numpy statements, and the decomposition built directly, are
  the kernels' oracle (``tests/helpers/rendezvous_reference.py``).

Ties among a row's best landmarks go to the lowest id (a stable sort), never to numpy's ``argpartition``, which
numpy dispatches to SIMD code by CPU: its choice among equal values differs from one CPU to another, so a seeded
episode's plan would too.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from mrcomm_env.core.backend import kernel_array
from mrcomm_env.rendezvous import plan_numba

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
    remain (a landmark believed exhausted is worth 0). One map per vehicle (the env's) is one compiled call
    (``plan_numba.utility_argument``, up to numpy's log1p), a shared map (a group's, as the baseline plans) is
    :func:`broadcast_utility`; both give the same bytes on the same maps.
    """
    n, L = np.shape(vehicle_pos)[0], np.shape(count)[-1]
    # one map per vehicle, shapes exactly as the env's (the kernel indexes them without numpy's broadcasting)
    per_vehicle = np.shape(Y) == (n, L, 2, 2) and np.shape(count) == (n, L) and np.shape(landmark_pos) == (n, L, 2)
    if not (per_vehicle and np.shape(vehicle_pos) == (n, 2)):
        return broadcast_utility(Y, count, vehicle_pos, landmark_pos, speed, t_window, info_per_obs, obs_rate, budget)
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


def broadcast_utility(
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
    """:func:`utility_matrix` in numpy, for any shapes numpy broadcasts (a map shared by the vehicles)."""
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
    # one compiled signature: a read-only or strided view would compile the kernels again
    U, landmark_pos = kernel_array(U, np.float64), kernel_array(landmark_pos, np.float64)
    if not record:  # the passes in one call, up to an eq. (8) sign numpy could round otherwise
        status, working, assignment, in_main, central, connected = plan_numba.recommend_loop(
            U, landmark_pos, float(d_comms), working
        )
        if status == plan_numba.PLANNED:
            return Recommendation(assignment, in_main, int(central), bool(connected), steps)
        # AMBIGUOUS: the passes below go on from this working set
    while True:
        rows, lp = assign(U, working)
        # clustering, eq. (6), l_c, eq. (7) and eq. (8)'s offsets in one call; eq. (8)'s product in numpy
        k, labels, main, lc, lo, axis, offsets = plan_numba.partition_pass(
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
