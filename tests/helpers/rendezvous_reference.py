"""RendezvousMapping's window, packets, observation, candidate lists, map fusion and recommendation passes written in
numpy: the oracles of their compiled kernels.

The env computes each in compiled calls (``RendezvousMappingEnv._window``, ``_packets``, ``_observe``,
``candidate_lists``, ``filters``' sums of packets, means and tree-edge bits, and ``protocol.recommend``'s passes:
``window_numba``, ``observe_numba``, ``plan_numba``, ``fusion_numba``); these are the same formulas as §III–V and the
module's table state them, kept here and not in the package (#44: one implementation in the package, the reference
under tests/). ``ReferenceRendezvous`` steps whole episodes with them, ``ReferenceTeamMaps`` fuses maps with them,
``reference_recommend`` plans with them (clusters as fine Dulmage–Mendelsohn blocks, l_c by eigenvector centrality),
and ``tests/rendezvous_mapping/test_rendezvous_compiled.py`` compares those with the package's byte for byte."""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, maximum_bipartite_matching

from mrcomm_env.rendezvous import protocol
from mrcomm_env.rendezvous.env import DETOUR_RENDEZVOUS, GO, HOLD, RENDEZVOUS, RendezvousMappingEnv
from mrcomm_env.rendezvous.filters import TeamMaps
from mrcomm_env.rendezvous.world import dense_components


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
    connected components (Pothen & Fan [14]). Used to check ``clusters``."""
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


def reference_recommend(U, landmark_pos, d_comms, record=False) -> protocol.Recommendation:
    """``protocol.recommend`` with every pass in numpy: Munkres (``protocol.assign``), ``clusters``, eq. (6),
    ``central_landmark``, eq. (7) and the cut of eq. (8), until the assigned landmarks are connected."""
    n, L = U.shape
    working = np.arange(L)
    steps: list[protocol.PartitionStep] = []
    if n == 1 and not record:  # one vehicle: its best landmark is a connected cluster of one (shortcut)
        best = int(np.argmax(U[0]))
        return protocol.Recommendation(np.array([best]), np.array([True]), best, True, steps)

    def per_vehicle(rows, values):
        out = np.full(n, -1, dtype=np.int64)
        out[rows] = values
        return out

    while True:
        rows, lp = protocol.assign(U, working)
        adj = adjacency(landmark_pos[lp], d_comms)
        k, labels = clusters(adj)
        main = 0 if k == 1 else int(np.argmax(np.bincount(labels, weights=U[rows, lp], minlength=k)))  # eq. (6)
        members = np.flatnonzero(labels == main)
        lc = int(lp[members[central_landmark(adj[np.ix_(members, members)], landmark_pos[lp[members]])]])
        lo = -1
        if k > 1:
            outside = lp[labels != main]
            lo = int(outside[int(np.argmax(((landmark_pos[outside] - landmark_pos[lc]) ** 2).sum(-1)))])  # eq. (7)
        if record:
            steps.append(
                protocol.PartitionStep(working, per_vehicle(rows, lp), per_vehicle(rows, labels), main, lc, lo)
            )
        if k == 1:
            assignment = per_vehicle(rows, lp)
            return protocol.Recommendation(assignment, assignment >= 0, lc, True, steps)
        keep = (landmark_pos[lo] - landmark_pos[working]) @ (landmark_pos[lo] - landmark_pos[lc]) > 0.0  # eq. (8)
        if keep.sum() < n:
            in_main = np.zeros(n, dtype=bool)
            in_main[rows] = labels == main
            return protocol.Recommendation(per_vehicle(rows, lp), in_main, lc, False, steps)
        working = working[keep]


def reference_window(env, actions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``RendezvousMappingEnv._window`` in numpy: every vehicle's route, and the observations its landmarks still
    yield (``_useful_events``). Returns the new positions, landmarks stayed at, and the kept observations'
    vehicles and landmarks in time order. Sets the env's ``action_kind`` and ``action_ok``."""
    n, c = env.n_agents, env.cfg
    T, u = c.t_window, c.speed
    est = env._estimates
    events_t, events_v, events_l = [], [], []
    new_pos = env.pos.copy()
    new_at = np.full(n, -1, dtype=np.int64)
    for v, a in enumerate(actions):
        ok = bool(env.mask[v, a])
        env.action_ok[v] = ok
        if not ok:
            a = env.K + 1
        here, t, final = env.pos[v], 0.0, -1
        for target, landmark, leave in _route(env, v, a, est[v]):  # leave: departure time, None: stay
            dist = float(np.hypot(*(target - here)))
            arrive = t + dist / u
            if arrive > T + 1e-9:  # out of reach: travel towards it for the rest of the window
                here, final = here + (target - here) * ((T - t) * u / dist), -1
                break
            end = T if leave is None else leave
            sel = env.ticks[(env.ticks >= arrive - 1e-9) & (env.ticks <= end + 1e-9)]
            events_t.append(sel)
            events_v.append(np.full(len(sel), v))
            events_l.append(np.full(len(sel), landmark))
            here, t, final = target, end, landmark
        new_pos[v] = here
        new_at[v] = final
    vehicles, observed = _useful_events(env, events_t, events_v, events_l)
    return new_pos, new_at, vehicles, observed


def _route(env, v: int, a: int, est: np.ndarray) -> list:
    """The legs (target position, landmark observed there or −1, departure time or None) of action a."""
    c = env.cfg
    if a < env.K:
        lm = int(env.candidates[v, a])
        env.action_kind[v] = GO
        return [(est[lm], lm, None)]
    if a == env.K:
        lp, lc = int(env.assignment[v]), int(env.central[v])
        meet = env.rendezvous_point[v]
        if lp >= 0 and lp != lc:
            d1 = float(np.hypot(*(est[lp] - env.pos[v])))
            d2 = float(np.hypot(*(meet - est[lp])))
            if d1 + d2 < c.speed * c.t_window:  # Fig. 5 condition 4: observe l_p(v), then reach l_c in time
                env.action_kind[v] = DETOUR_RENDEZVOUS
                return [(est[lp], lp, c.t_window - d2 / c.speed), (meet, lc, None)]
        env.action_kind[v] = RENDEZVOUS
        return [(meet, lc, None)]
    env.action_kind[v] = HOLD
    lm = int(env.at_landmark[v])
    return [(env.pos[v], lm, None)] if lm >= 0 else []


def _useful_events(env, events_t, events_v, events_l) -> tuple[np.ndarray, np.ndarray]:
    """The window's observations in time order (ties: vehicle id, then the vehicle's leg) that their landmarks still
    yield: each landmark yields at most ``obs_per_landmark`` independent observations in total (the sensor floor).
    Returns their vehicles and landmarks."""
    none = np.empty(0, dtype=np.int64)
    if not events_t:
        return none, none
    t = np.concatenate(events_t)
    v = np.concatenate(events_v).astype(np.int64)
    lm = np.concatenate(events_l).astype(np.int64)
    if len(t) == 0:
        return none, none
    order = np.lexsort((v, t))
    v, lm = v[order], lm[order]
    by_lm = np.argsort(lm, kind="stable")
    sorted_lm = lm[by_lm]
    start = np.searchsorted(sorted_lm, sorted_lm, side="left")
    rank = np.empty(len(lm), dtype=np.int64)
    rank[by_lm] = np.arange(len(lm)) - start  # earlier observations of the same landmark this window
    useful = env.world_count[lm] + rank < env.cfg.obs_per_landmark
    return v[useful], lm[useful]


def reference_packets(v: np.ndarray, lm: np.ndarray, weighted: np.ndarray, n_landmarks: int, n_vehicles: int):
    """``RendezvousMappingEnv._packets`` in numpy: one grouping of the (vehicle, landmark) pairs, each pair's
    observations summed in time order by ``np.add.at`` (as a per-vehicle sum would). Returns the owners, their
    bounds, the landmark ids, counts and summed vectors, and each vehicle's observations."""
    pairs, inverse, counts = np.unique(v * n_landmarks + lm, return_inverse=True, return_counts=True)
    dy = np.zeros((len(pairs), 2))
    np.add.at(dy, inverse, weighted)
    owner, ids = np.divmod(pairs, n_landmarks)
    bounds = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1], True])  # vehicles in increasing order
    return owner[bounds[:-1]], bounds, ids, counts, dy, np.bincount(v, minlength=n_vehicles)


def reference_observation(env) -> np.ndarray:
    """``RendezvousMappingEnv._observe`` in numpy: the head (position, clock, group, connected, own information),
    the K candidates, the rendezvous and the K nearest other vehicles at their last known positions."""
    n, K, c = env.n_agents, env.K, env.cfg
    side, T, u = env.side, c.t_window, c.speed
    rows = np.arange(n)

    def rel(d):  # relative offsets to [0, 1], 0.5 = here
        return np.clip(d / (2.0 * side) + 0.5, 0.0, 1.0)

    def travel(dist):  # travel time over (travel time + window): 0 here, 0.5 at d_max, → 1 far away
        t = dist / u
        return t / (t + T)

    head = np.column_stack(
        [
            np.clip(env.pos / side, 0.0, 1.0),
            np.full(n, min(env.phases / c.max_cycles, 1.0)),
            env.group.sum(1) / n,
            np.full(n, float(env.n_groups == 1)),
            np.clip(env.own_info_fraction(), 0.0, 1.0),
        ]
    )
    valid = env.candidates >= 0
    cand = np.where(valid, env.candidates, 0)
    cpos = env._estimates[rows[:, None], cand]  # (n, K, 2)
    off = cpos - env.pos[:, None, :]
    cand_feats = (
        np.concatenate(
            [
                rel(off),
                np.clip(env.candidate_utility / env.u_max, 0.0, 1.0)[..., None],
                travel(np.hypot(off[..., 0], off[..., 1]))[..., None],
                env.in_main[:, None].repeat(K, 1)[..., None] & (cand == env.assignment[:, None])[..., None],
                (cand == env.assignment[:, None])[..., None],
                valid[..., None],
            ],
            axis=-1,
        )
        * valid[..., None]
    )
    lc = env.rendezvous_point
    lp = env._estimates[rows, np.maximum(env.assignment, 0)]
    d1 = np.hypot(*(lp - env.pos).T)
    d2 = np.hypot(*(lc - lp).T)
    fits = (env.assignment >= 0) & (d1 + d2 < env.d_max)
    lc_off = lc - env.pos
    rdv = np.column_stack([rel(lc_off), travel(np.hypot(*lc_off.T)), fits, env.plan_connected])
    # the K nearest other vehicles at their last known positions
    others = env.known_pos - env.pos[:, None, :]
    dist = np.hypot(others[..., 0], others[..., 1])
    dist[rows, rows] = np.inf
    order = np.argsort(dist, axis=1, kind="stable")[:, :K]
    k_real = min(K, n - 1)
    near = np.zeros((n, K, 5))
    if k_real > 0:
        idx = order[:, :k_real]
        age = env.phases - env.known_phase[rows[:, None], idx]
        near[:, :k_real] = np.concatenate(
            [
                rel(others[rows[:, None], idx]),
                env.group[rows[:, None], idx][..., None],
                (age / (age + 1.0))[..., None],
                np.ones((n, k_real, 1)),
            ],
            axis=-1,
        )
    return np.concatenate([head, cand_feats.reshape(n, -1), rdv, near.reshape(n, -1)], axis=1).astype(np.float32)


class ReferenceRendezvous(RendezvousMappingEnv):
    """RendezvousMapping whose window, packets and observation are the numpy oracles above."""

    def _window(self, actions):
        return reference_window(self, actions)

    def _packets(self, v, lm, weighted):
        return reference_packets(v, lm, weighted, self.cfg.n_landmarks, self.n_agents)

    def _observe(self):
        return reference_observation(self)


def reference_candidate_lists(utility: np.ndarray, assignment: np.ndarray, K: int) -> tuple[np.ndarray, np.ndarray]:
    """``env.candidate_lists`` in numpy: the recommendation first (when assigned and worth anything), then the k best
    by (−work, id), landmarks worth nothing left out, empty slots −1."""
    n, L = utility.shape
    k = min(K, L)
    work = utility.copy()
    rows = np.arange(n)
    has_rec = (assignment >= 0) & (utility[rows, np.maximum(assignment, 0)] > 0)
    work[rows[has_rec], assignment[has_rec]] = np.inf  # the recommendation ranks first
    # the k best by (−work, id): a stable sort, not argpartition, whose choice among ties depends on the CPU
    top = np.argsort(-work, axis=1, kind="stable")[:, :k]
    cand = np.full((n, K), -1, dtype=np.int64)
    cand_u = np.zeros((n, K))
    real = utility[rows[:, None], top]
    keep = real > 0
    cand[:, :k] = np.where(keep, top, -1)
    cand_u[:, :k] = np.where(keep, real, 0.0)
    return cand, cand_u


def reference_add_entries(Y, y, count, landmarks, dy, dcount, R_inv) -> None:
    """``filters._add_entries`` in numpy: ``dcount · R_inv``, ``dy`` and ``dcount`` added at ``landmarks``, in place,
    repeats in order (``np.add.at``)."""
    np.add.at(Y, landmarks, dcount[:, None, None] * R_inv)
    np.add.at(y, landmarks, dy)
    np.add.at(count, landmarks, dcount)


def reference_mean_of(Y: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``filters.mean_of`` in numpy: μ = Y⁻¹ y by the closed-form inverse of each 2×2 Y."""
    a, b, c, d = Y[..., 0, 0], Y[..., 0, 1], Y[..., 1, 0], Y[..., 1, 1]
    det = a * d - b * c
    return np.stack([(d * y[..., 0] - b * y[..., 1]) / det, (a * y[..., 1] - c * y[..., 0]) / det], axis=-1)


def missing_bits(maps: TeamMaps, have: np.ndarray, want: np.ndarray) -> int:
    """Bits of the packets in ``want`` (a version vector) beyond ``have``."""
    return sum(
        log.bits_before(w) - log.bits_before(h) for log, h, w in zip(maps.logs, have.tolist(), want.tolist()) if w > h
    )


def reference_edge_bits(maps: TeamMaps, members, parent, sides) -> dict[tuple[int, int], int]:
    """``TeamMaps._edge_bits`` in numpy: over each tree edge (a, parent[a]) of a group, the bits of the packets a's
    side holds beyond the other side's, and back."""
    sent: dict[tuple[int, int], int] = {}
    in_group = np.zeros(maps.n, dtype=bool)
    in_group[members] = True
    for a, side_a in sides.items():
        b = int(parent[a])
        other = in_group.copy()
        other[side_a] = False
        union_a, union_b = maps.known[side_a].max(0), maps.known[other].max(0)
        sent[(a, b)] = missing_bits(maps, union_b, union_a)
        sent[(b, a)] = missing_bits(maps, union_a, union_b)
    return sent


class ReferenceTeamMaps(TeamMaps):
    """:class:`~mrcomm_env.rendezvous.filters.TeamMaps` whose sums into the vehicles' maps and tree-edge bits are the
    numpy oracles above."""

    def _add(self, w, landmarks, dy, count):
        reference_add_entries(self.Y[w], self.y[w], self.count[w], landmarks, dy, count, self.R_inv)

    def _edge_bits(self, members, parent, sides):
        return reference_edge_bits(self, members, parent, sides)
