"""RendezvousMapping-v0 (paper 004): filters, fusion without double counting, the §IV module, masks, bad input."""

from __future__ import annotations

import math

import networkx as nx
import numpy as np
import pytest
from filterpy.kalman import InformationFilter
from hypothesis import given, settings
from hypothesis import strategies as st
from numerics import bit_identical
from scipy.optimize import linear_sum_assignment
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

import mrcomm_env
from mrcomm_baselines.rendezvous_mapping import POLICIES, PaperProtocol, action_module
from mrcomm_env.rendezvous import filters, protocol, theory, world
from mrcomm_env.rendezvous.env import HOLD, RendezvousMappingEnv

EPS = np.finfo(float).eps


def random_spd(rng, scale=1.0):
    a = rng.normal(size=(2, 2))
    return scale * (a @ a.T + 0.2 * np.eye(2))


# ------------------------------------------------------------------------------------------------ filter
def test_vectorised_information_filter_matches_filterpy_on_the_same_observations():
    rng = np.random.default_rng(4)
    L, m = 6, 80
    Y0 = np.stack([random_spd(rng, 0.05) for _ in range(L)])
    mu0 = rng.uniform(0, 100, size=(L, 2))
    y0 = np.einsum("lij,lj->li", Y0, mu0)
    landmarks = rng.integers(0, L, size=m)
    R_inv = np.stack([np.linalg.inv(random_spd(rng, 4.0)) for _ in range(m)])
    z = mu0[landmarks] + rng.normal(0, 2.0, size=(m, 2))
    Y, y = Y0.copy(), y0.copy()
    filters.observe(Y, y, landmarks, z, R_inv)
    for lm in range(L):
        f = InformationFilter(dim_x=2, dim_z=2)
        f.x = mu0[lm].copy()
        f.P_inv = Y0[lm].copy()
        f.H = np.eye(2)
        for k in np.flatnonzero(landmarks == lm):
            f.update(z[k], R_inv=R_inv[k])
        # the two differ only by round-off: a sum of k terms (relative k·ε) and one 2×2 solve (cond·ε) on
        # values of size |μ|
        n_obs = max(int((landmarks == lm).sum()), 1)
        cond = np.linalg.cond(Y[lm])
        np.testing.assert_allclose(Y[lm], f.P_inv, rtol=0, atol=8 * n_obs * EPS * np.abs(f.P_inv).max())
        mean = filters.mean_of(Y[lm], y[lm])
        np.testing.assert_allclose(mean, f.x.ravel(), rtol=0, atol=16 * n_obs * cond * EPS * np.abs(mu0).max())


def test_logdet_and_mean_of_match_numpy():
    rng = np.random.default_rng(0)
    Y = np.stack([random_spd(rng) for _ in range(20)])
    y = rng.normal(size=(20, 2))
    np.testing.assert_allclose(filters.logdet2(Y), np.linalg.slogdet(Y)[1], rtol=1e-12)
    np.testing.assert_allclose(filters.mean_of(Y, y), np.linalg.solve(Y, y[..., None])[..., 0], rtol=1e-10)


# ------------------------------------------------------------------------------------------------ fusion
def make_packet(rng, L):
    m = int(rng.integers(1, 4))
    ids = np.sort(rng.choice(L, size=m, replace=False))
    return filters.Packet(ids, rng.normal(size=(m, 2)), rng.integers(1, 4, size=m))


class Gathered:
    """The test's own record of every packet each vehicle made, apart from ``TeamMaps`` (which lets packets go)."""

    def __init__(self, maps: filters.TeamMaps):
        self.maps = maps
        self.packets: list[list[filters.Packet]] = [[] for _ in range(maps.n)]

    def add_own(self, v, packet):
        self.maps.add_own(v, packet)
        if len(packet.landmarks):
            self.packets[v].append(packet)

    def summed(self, version) -> tuple[np.ndarray, np.ndarray]:
        """Prior plus the packets a version vector names, summed afresh."""
        Y, y = self.maps.Y0.copy(), self.maps.y0.copy()
        for u, packets in enumerate(self.packets):
            for p in packets[: version[u]]:
                np.add.at(Y, p.landmarks, p.count[:, None, None] * self.maps.R_inv)
                np.add.at(y, p.landmarks, p.dy)
        return Y, y


def check_no_double_counting(record: Gathered):
    """Every map equals prior + each packet it holds, summed once afresh."""
    maps = record.maps
    for w in range(maps.n):
        Y, y = record.summed(maps.known[w])
        tol = 64 * EPS * max(1.0, np.abs(Y).max())
        np.testing.assert_allclose(maps.Y[w], Y, rtol=0, atol=tol)
        np.testing.assert_allclose(maps.y[w], y, rtol=0, atol=tol * 10)
        # what the maps sum afresh (from the common map on) is that too
        Yw, yw = maps.information_of(maps.known[w])
        np.testing.assert_allclose(Yw, Y, rtol=0, atol=tol)
        np.testing.assert_allclose(yw, y, rtol=0, atol=tol * 10)
    Yc, _ = record.summed(maps.known.min(0))
    np.testing.assert_allclose(maps.common_Y, Yc, rtol=0, atol=64 * EPS * max(1.0, np.abs(Yc).max()))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(2, 6), events=st.integers(1, 25))
def test_fused_map_over_any_meeting_sequence_equals_the_centralized_sum(seed, n, events):
    rng = np.random.default_rng(seed)
    L = 7
    Y0 = np.broadcast_to(np.eye(2) * 0.04, (L, 2, 2)).copy()
    maps = filters.TeamMaps(n, Y0, rng.normal(size=(L, 2)), random_spd(rng))
    record = Gathered(maps)
    for _ in range(events):
        for v in range(n):  # some vehicles gather something in this window
            if rng.random() < 0.6:
                record.add_own(v, make_packet(rng, L))
        # a random set of meetings: random groups, each fused over a random tree
        pos = rng.uniform(0, 30, size=(n, 2))
        links = world.vehicle_links(pos, float(rng.uniform(0, 30)))
        labels, parent = world.spanning_forest(pos, links)
        for g in range(labels.max() + 1):
            members = np.flatnonzero(labels == g)
            maps.fuse_group(members, parent)
            assert (maps.known[members] == maps.known[members].max(0)).all()
        maps.update_common()
        check_no_double_counting(record)
    # everyone meets at last: every map and the fused global map are the centralised sum
    star = np.r_[-1, np.zeros(n - 1, dtype=np.int64)]
    maps.fuse_group(np.arange(n), star)
    maps.update_common()
    Yc, yc = record.summed([len(p) for p in record.packets])
    assert all(log.kept == 0 for log in maps.logs)  # everyone holds everything: every packet was let go
    if maps.common_known.any():  # a version below the common map's names packets that are gone
        with pytest.raises(ValueError, match="'version'"):
            maps.information_of(np.zeros(n, dtype=np.int64))
    for w in range(n):
        np.testing.assert_allclose(maps.Y[w], Yc, rtol=0, atol=64 * EPS * np.abs(Yc).max())
        np.testing.assert_allclose(maps.y[w], yc, rtol=0, atol=640 * EPS * max(1.0, np.abs(yc).max()))
    np.testing.assert_allclose(maps.common_Y, Yc, rtol=0, atol=64 * EPS * np.abs(Yc).max())


def test_channel_filter_is_the_common_information_and_fusion_adds_only_the_difference():
    rng = np.random.default_rng(7)
    L = 5
    maps = filters.TeamMaps(3, np.broadcast_to(np.eye(2), (L, 2, 2)).copy(), np.zeros((L, 2)), random_spd(rng))
    for v in range(3):
        maps.add_own(v, make_packet(rng, L))
    maps.fuse_group(np.array([0, 1]), np.array([-1, 0, -1]))
    maps.add_own(0, make_packet(rng, L))
    maps.add_own(2, make_packet(rng, L))
    common_Y, _ = maps.channel_information(0, 2)
    union_Y, _ = maps.information_of(np.maximum(maps.known[0], maps.known[2]))
    # Y_a + Y_b − common = union: the channel filter removes exactly what would be counted twice
    np.testing.assert_allclose(maps.Y[0] + maps.Y[2] - common_Y, union_Y, rtol=1e-12)


def test_a_reconnecting_vehicle_sends_only_what_the_others_lack():
    rng = np.random.default_rng(3)
    L = 6
    maps = filters.TeamMaps(3, np.broadcast_to(np.eye(2), (L, 2, 2)).copy(), np.zeros((L, 2)), random_spd(rng))
    chain = np.array([-1, 0, 1])  # 0 — 1 — 2
    for v in range(3):
        maps.add_own(v, make_packet(rng, L))
    maps.fuse_group(np.arange(3), chain)
    # vehicle 2 is cut off and gathers two packets; 0 and 1 gather one each and fuse without it
    p2 = [make_packet(rng, L), make_packet(rng, L)]
    for p in p2:
        maps.add_own(2, p)
    maps.add_own(0, make_packet(rng, L))
    maps.add_own(1, make_packet(rng, L))
    maps.fuse_group(np.array([0, 1]), np.array([-1, 0, -1]))
    sent = maps.fuse_group(np.arange(3), chain)
    assert sent[(2, 1)] == sum(p.bits(L) for p in p2)  # only its own two new packets
    lacking = maps.packets(0)[-1].bits(L) + maps.packets(1)[-1].bits(L)
    assert sent[(1, 2)] == lacking
    assert sent[(1, 0)] == sum(p.bits(L) for p in p2) and sent[(0, 1)] == 0
    again = maps.fuse_group(np.arange(3), chain)  # nothing new: nothing sent
    assert all(bits == 0 for bits in again.values())


def test_a_packet_log_lets_go_only_of_packets_everyone_holds_and_keeps_their_bits():
    rng = np.random.default_rng(5)
    log = filters.PacketLog()
    made = [make_packet(rng, 50) for _ in range(40)]
    for p in made:
        log.append(p, p.bits(50))
    bits = np.cumsum([0] + [p.bits(50) for p in made])
    log.drop_before(10)  # fewer to let go than to keep: nothing moves yet
    assert (log.first, log.kept, log.made) == (0, 40, 40)
    log.drop_before(25)  # now as many to go as to stay
    assert (log.first, log.kept, log.made) == (25, 15, 40)
    for k in range(25, 41):
        assert log.bits_before(k) == bits[k]
    for kept, p in zip(log.packets(), made[25:], strict=True):
        assert np.array_equal(kept.landmarks, p.landmarks) and np.array_equal(kept.count, p.count)
        assert kept.dy.tobytes() == p.dy.tobytes()
    with pytest.raises(ValueError, match="not all kept"):
        log.span(24, 30)
    more = make_packet(rng, 50)
    log.append(more, more.bits(50))
    assert log.made == 41 and log.bits_before(41) == bits[40] + more.bits(50)
    assert np.array_equal(log.packets()[-1].landmarks, more.landmarks)


def test_a_connected_team_holds_no_packet_everyone_has_however_long_the_episode():
    """Packets every vehicle holds are in the fused map and never sent again: a team that stays connected keeps
    none of them, over a horizon in which it makes thousands (they were all kept for the whole episode once)."""
    env = RendezvousMappingEnv(
        n_vehicles=4, n_landmarks=30, area=900.0, d_comms=math.inf, obs_per_landmark=10_000, max_cycles=1500
    )
    env.reset(seed=2)
    most = 0
    while env.agents:
        env.step({a: 0 for a in env.agents})
        most = max(most, sum(log.kept for log in env.maps.logs))
    assert sum(log.made for log in env.maps.logs) > 1000
    assert most == 0


def test_packet_logs_of_a_split_team_stay_within_the_bound_the_memory_estimate_counts():
    """With d_comms = 0 vehicles fuse only when they meet at one point, and the logs grow: their arrays stay within
    ``STORED_ENTRY_BYTES`` per entry made, apart from their first few rows (the estimate's term: an entry holds one
    observation or more, and the sensor floor bounds the observations)."""
    env = RendezvousMappingEnv(
        n_vehicles=6, n_landmarks=40, area=1600.0, d_comms=0.0, obs_per_landmark=10_000, max_cycles=400
    )
    env.reset(seed=4)
    made = [0]
    add_own = env.maps.add_own

    def counted(v, packet):
        made[0] += len(packet.landmarks)
        add_own(v, packet)

    env.maps.add_own = counted
    rng = np.random.default_rng(4)
    most = 0
    while env.agents:
        env.step({a: int(rng.integers(env.action_space(a).n)) for a in env.agents})
        logs = env.maps.logs
        most = max(most, sum(log.entries for log in logs))
        held = sum(a.nbytes for log in logs for a in (log.landmarks, log.dy, log.count, log.bounds, log.cum_bits))
        assert made[0] <= env.world_count.sum()
        assert held <= filters.STORED_ENTRY_BYTES * made[0] + len(logs) * 8 * 40
    assert most > 200  # the logs did grow


# ------------------------------------------------------------------------------------------------ §IV module
def random_adjacency(rng, n, radius):
    pos = rng.uniform(0, 40, size=(n, 2))
    return protocol.adjacency(pos, radius), pos


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(1, 40), radius=st.floats(0.0, 30.0))
def test_clusters_are_the_fine_dulmage_mendelsohn_blocks_and_the_connected_components(seed, n, radius):
    adj, _ = random_adjacency(np.random.default_rng(seed), n, radius)
    k, labels = protocol.clusters(adj)
    ours = {frozenset(np.flatnonzero(labels == b).tolist()) for b in range(k)}
    assert ours == set(protocol.fine_dm_blocks(adj))
    assert ours == {frozenset(c) for c in nx.connected_components(nx.from_numpy_array(adj.astype(int)))}
    k_sp, lab_sp = connected_components(csr_matrix(adj), directed=False)
    assert k == k_sp and (labels == lab_sp).all()  # same numbering as scipy's


def test_central_landmark_is_networkx_eigenvector_centrality_argmax():
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(200):
        adj, pos = random_adjacency(rng, int(rng.integers(3, 15)), 15.0)
        k, labels = protocol.clusters(adj)
        big = np.flatnonzero(labels == np.bincount(labels).argmax())
        sub = adj[np.ix_(big, big)].astype(int)
        np.fill_diagonal(sub, 0)
        if len(big) < 3:
            continue
        cent = nx.eigenvector_centrality_numpy(nx.from_numpy_array(sub))
        values = np.array([cent[i] for i in range(len(big))])
        if np.sort(values)[-1] - np.sort(values)[-2] < 1e-6:  # tie: our tie rule decides
            continue
        assert protocol.central_landmark(adj[np.ix_(big, big)], pos[big]) == int(np.argmax(values))
        checked += 1
    assert checked > 50


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(1, 8), L=st.integers(8, 120))
def test_restricted_munkres_attains_the_full_optimum(seed, n, L):
    U = np.random.default_rng(seed).random((n, L))
    r, c = linear_sum_assignment(U, maximize=True)
    rows, lms = protocol.assign(U, np.arange(L))
    assert len(set(lms.tolist())) == len(lms) == n
    assert U[rows, lms].sum() == pytest.approx(U[r, c].sum(), rel=1e-12)


def test_utility_is_eq1_with_eq3_eq4_and_the_epsilon_rule():
    rng = np.random.default_rng(2)
    L = 30
    Y = np.stack([random_spd(rng, 0.1) for _ in range(L)])
    count = rng.integers(0, 6, size=L)
    lm = rng.uniform(0, 50, size=(L, 2))
    veh = rng.uniform(0, 50, size=(3, 2))
    speed, T, r, rate, budget = 1.5, 12.0, 0.2, 2.0, 5
    U = protocol.utility_matrix(Y, count, veh, lm, speed, T, r, rate, budget)
    for v in range(3):
        for lm_id in range(L):
            t_obs = T - np.linalg.norm(veh[v] - lm[lm_id]) / speed
            t_obs = t_obs if t_obs > 0 else protocol.EPS_OBS_TIME
            n_obs = min(t_obs * rate, max(budget - count[lm_id], 0))
            gain = n_obs * r * np.eye(2)
            ref = 0.5 * (np.linalg.slogdet(gain + Y[lm_id])[1] - np.linalg.slogdet(Y[lm_id])[1])
            assert U[v, lm_id] == pytest.approx(ref, rel=1e-9, abs=1e-15)
    assert (U[:, count >= budget] == 0).all()  # an exhausted landmark is worth nothing
    assert (U >= 0).all()


def test_partition_ends_connected_or_marked_and_follows_eq7_eq8():
    rng = np.random.default_rng(5)
    for _ in range(30):
        L, n = 80, 6
        lm = rng.uniform(0, 100, size=(L, 2))
        U = rng.random((n, L))
        d = float(rng.choice([0.0, 8.0, 15.0, 30.0]))
        rec = protocol.recommend(U, lm, d, record=True)
        assigned = rec.assignment[rec.assignment >= 0]
        k, _ = protocol.clusters(protocol.adjacency(lm[assigned], d))
        assert rec.connected == (k == 1)
        for before, after in zip(rec.steps, rec.steps[1:]):
            assert before.outlier >= 0 and before.outlier not in after.working  # l_o is cut (eq. 8)
            assert before.central in after.working  # l_c's side is kept
            assert set(after.working.tolist()) < set(before.working.tolist())
            axis = lm[before.outlier] - lm[before.central]
            kept = (lm[before.outlier] - lm[before.working]) @ axis > 0
            assert set(before.working[kept].tolist()) == set(after.working.tolist())
        if d == 0.0:
            assert not rec.connected or n == 1


def test_infinite_comms_needs_no_partition():
    rng = np.random.default_rng(6)
    U = rng.random((5, 40))
    rec = protocol.recommend(U, rng.uniform(0, 100, (40, 2)), math.inf, record=True)
    assert rec.connected and len(rec.steps) == 1 and rec.in_main.all()


def test_action_module_follows_the_four_conditions_of_fig5():
    est = np.array([[0.0, 0.0], [10.0, 0.0], [30.0, 0.0]])
    rec = protocol.Recommendation(np.array([1, 2, -1]), np.array([True, False, False]), central=0, connected=False)
    x = np.array([0.0, 0.0])
    assert action_module(rec, 0, x, est, d_max=15.0) == 1  # in main cluster, reachable
    assert action_module(rec, 0, x, est, d_max=5.0) == 3  # in main cluster, unreachable
    assert action_module(rec, 1, x, est, d_max=61.0) == 2  # outside: 30 there + 30 back to l_c < 61
    assert action_module(rec, 1, x, est, d_max=59.0) == 3
    assert action_module(rec, 2, x, est, d_max=100.0) == 3  # not assigned


# ------------------------------------------------------------------------------------------------ world
def test_uniform_grid_has_zero_clustering_between_spacing_and_diagonal():
    pos = world.jittered_grid(100, 100.0, 0.0, np.random.default_rng(0))  # 10 m spacing
    assert world.clustering_coefficient(pos, 12.0) == 0.0  # the paper's remark on uniform grids (§VI-B.1)
    jittered = world.jittered_grid(100, 100.0, 15.0, np.random.default_rng(0))
    assert world.clustering_coefficient(jittered, 12.0) > 0.3
    assert jittered.min() >= 0.0 and jittered.max() <= 100.0


# ------------------------------------------------------------------------------------------------ env
SMALL = {"n_vehicles": 4, "n_landmarks": 40, "area": 1600.0, "max_cycles": 40}


def test_masks_mark_empty_slots_and_an_infeasible_action_acts_as_hold():
    env = RendezvousMappingEnv(**SMALL, obs_per_landmark=1, k_candidates=12)
    obs, infos = env.reset(seed=0)
    rng = np.random.default_rng(0)
    saw_masked = False
    for _ in range(40):
        if not env.agents:
            break
        mask = env.action_masks()
        assert mask.any(axis=1).all() and mask[:, -1].all()  # hold is always feasible
        assert (mask[:, : env.K] == (env.candidates >= 0)).all()
        assert all(
            infos[a][f"action_mask_{i}"] == float(mask[k, i])
            for k, a in enumerate(env.agents)
            for i in range(env.K + 2)
        )
        masked = np.argwhere(~mask)
        actions = {a: int(rng.choice(np.flatnonzero(mask[k]))) for k, a in enumerate(env.agents)}
        if len(masked):
            saw_masked = True
            v, bad = masked[0]
            actions[env.agents[v]] = int(bad)
            before = env.pos[v].copy()
            obs, _, _, _, infos = env.step(actions)
            assert infos[env.possible_agents[v]]["action_feasible"] == 0.0
            assert env.action_kind[v] == HOLD and np.allclose(env.pos[v], before)
        else:
            obs, _, _, _, infos = env.step(actions)
    assert saw_masked


def test_reward_is_the_fused_information_gain_and_unfused_information_does_not_count():
    env = RendezvousMappingEnv(**SMALL, d_comms=0.0)
    env.reset(seed=1)
    total = 0.0
    greedy = POLICIES["greedy"]()
    views = env.local_views()
    greedy.reset(views, 0)
    obs = env._observations()
    for _ in range(5):
        obs, rewards, *_ = env.step(greedy.act(obs, views))
        total += rewards["robot_0"]
    assert total * env.reward_scale == pytest.approx(env.fused_gain, abs=1e-9)
    if env.n_groups == env.n_agents:  # greedy vehicles apart: they gathered but nothing is fused
        assert env.own_info_fraction().max() > 0.0
    env2 = RendezvousMappingEnv(**SMALL, d_comms=math.inf)
    obs, _ = env2.reset(seed=1)
    total = 0.0
    for _ in range(5):
        obs, rewards, *_ = env2.step(greedy.act(obs, env2.local_views()))
        total += rewards["robot_0"]
    union = float(filters.logdet2(env2.maps.centralized()[0]).sum()) - env2.logdet0
    assert total * env2.reward_scale == pytest.approx(union, rel=1e-9)  # always connected: all is fused


def test_paper_protocol_plans_what_the_env_plans():
    env = RendezvousMappingEnv(**SMALL, d_comms=10.0)
    obs, _ = env.reset(seed=2)
    policy = PaperProtocol()
    views = env.local_views()
    policy.reset(views, 2)
    for _ in range(10):
        actions = policy.act(obs, views)
        for root, rec in policy.last_plans.items():
            members = np.flatnonzero(env.labels == env.labels[root])
            assert (rec.assignment == env.assignment[members]).all()
            if len(members) == env.n_agents:  # a split team regroups at the last whole-team l_c instead
                assert (env.central[members] == rec.central).all()
            else:
                assert (policy.last_actions[members] == 4).all()
        # the recommendation is candidate 0 unless it is worth nothing (believed exhausted)
        rows = np.flatnonzero(env.assignment >= 0)
        worth = env.utility[rows, env.assignment[rows]] > 0
        assert (env.candidates[rows[worth], 0] == env.assignment[rows[worth]]).all()
        obs, *_ = env.step(actions)


def test_budget_caps_information_and_fraction_stays_in_unit_interval():
    env = RendezvousMappingEnv(n_vehicles=2, n_landmarks=4, area=100.0, d_comms=math.inf, max_cycles=60)
    obs, _ = env.reset(seed=0)
    policy = POLICIES["no_partition"]()
    views = env.local_views()
    policy.reset(views, 0)
    while env.agents:
        obs, *_ = env.step(policy.act(obs, views))
    assert (env.world_count <= env.cfg.obs_per_landmark).all()
    assert env.metrics()["info_fraction"] == pytest.approx(1.0)  # every landmark observed to the floor
    assert env.step_count < 60  # terminated once everything available was fused
    per = theory.available_information(env.cfg.prior_sigma, env.cfg.obs_sigma, env.cfg.obs_per_landmark)
    assert env.fused_gain == pytest.approx(4 * per)


def test_metric_and_argument_names_and_alias():
    env = mrcomm_env.make("RendezvousMapping-v0", max_phases=7, **{k: v for k, v in SMALL.items() if k != "max_cycles"})
    assert env.cfg.max_cycles == 7
    env.reset(seed=0)
    for name in ("iterations_to_half_info", "info_fraction", "normalized_det", "connected_fraction", "bits_sent"):
        assert name in env.metrics()
    for name in (
        "n_vehicles",
        "n_landmarks",
        "area",
        "speed",
        "t_window",
        "d_comms",
        "sigma",
        "k_candidates",
        "max_cycles",
    ):
        assert name in RendezvousMappingEnv.PARAMS


@pytest.mark.parametrize(
    ("arg", "value"),
    [
        ("n_vehicles", 0),
        ("n_landmarks", 3),
        ("speed", 0.0),
        ("speed", -1.0),
        ("t_window", 0.0),
        ("d_comms", -0.1),
        ("sigma", -1.0),
        ("k_candidates", 0),
    ],
)
def test_bad_inputs_raise_value_error_naming_the_argument(arg, value):
    kwargs = {"n_vehicles": 4, "n_landmarks": 40, arg: value}
    with pytest.raises(ValueError, match=f"'{arg}'"):
        RendezvousMappingEnv(**kwargs)


def test_bits_are_counted_for_utility_vectors_and_map_updates():
    env = RendezvousMappingEnv(**SMALL, d_comms=math.inf)
    env.reset(seed=0)
    L, n = SMALL["n_landmarks"], SMALL["n_vehicles"]
    # at reset: one tree of n − 1 edges; each direction carries a version vector, and every vehicle's position
    # and utility vector crosses every edge once, no map update yet
    per_vehicle = 2 * filters.FLOAT_BITS + L * filters.FLOAT_BITS
    expected = 2 * (n - 1) * n * filters.COUNT_BITS + (n - 1) * n * per_vehicle
    assert env.ledger.total_bits.sum() == expected
    env.step({a: 0 for a in env.agents})
    gathered = sum(log.bits_before(log.made) for log in env.maps.logs)
    assert env.ledger.step_bits.sum() >= expected + gathered  # each packet crosses at least one edge


@pytest.mark.parametrize(
    ("prior_sigma", "obs_sigma", "obs_per_landmark"),
    [(1e-3, 1e4, 1), (1e-3, 1e4, 3), (5.0, 3.0, 5), (1.0, 1e-3, 2)],  # tiny and huge σ₀²/σ², and the default
)
def test_information_of_the_fused_map_is_exact_across_the_range(prior_sigma, obs_sigma, obs_per_landmark):
    """With H = I and isotropic Y₀ = I/σ₀², R⁻¹ = I/σ², a landmark observed k times holds 2·ln(1 + kσ₀²/σ²) nats
    more than the prior: info_fraction is Σ_l ln(1 + k_l ρ) / (L ln(1 + budget·ρ)), and with one observation per
    landmark exactly the share of landmarks observed. The old difference of log-determinants gave 0.909, 0.227
    and 1.066 at σ₀ = 1e-3, σ = 1e4 (round-off over an available information of about 1e-12)."""
    env = mrcomm_env.make(
        "RendezvousMapping-v0",
        prior_sigma=prior_sigma,
        obs_sigma=obs_sigma,
        obs_per_landmark=obs_per_landmark,
        n_landmarks=30,
        n_vehicles=4,
        area=900.0,
        d_comms=math.inf,
        max_cycles=12,
    )
    env.reset(seed=3)
    policy = POLICIES["paper_protocol"]()
    obs = env.reset(seed=3)[0]
    policy.reset(env.local_views(), 3)
    rho = prior_sigma**2 / obs_sigma**2
    seen = []
    while env.agents:
        obs, *_ = env.step(policy.act(obs, env.local_views()))
        counts = env.maps.common_count
        expected = math.fsum(math.log1p(k * rho) for k in counts.tolist()) / (30 * math.log1p(obs_per_landmark * rho))
        if obs_per_landmark == 1:
            assert expected == pytest.approx(float((counts > 0).sum()) / 30, rel=1e-12)
        fraction = env.metrics()["info_fraction"]
        assert 0.0 <= fraction <= 1.0
        assert fraction == pytest.approx(expected, rel=1e-12, abs=1e-15)
        seen.append(fraction)
    assert seen[-1] > 0.0, "the episode observed nothing: the check above was vacuous"


@pytest.mark.parametrize(
    ("n_landmarks", "side", "radius", "sigma"),
    [
        (200, 120.0, 15.0, 0.0),
        (200, 120.0, 10.0, 3.0),
        (300, 30.0, 3.0, 0.0),
        (150, 1.0, 10.0, 3.0),
        (2, 5.0, 10.0, 0.0),
    ],
)
def test_clustering_coefficient_is_networkx_average_clustering(n_landmarks, side, radius, sigma):
    """The sparse triangle count gives networkx's value to the last bit, on exact grids (pairs at exactly the
    radius) and jittered ones, on a complete graph (the bounding-box shortcut) and below three nodes."""
    pos = world.jittered_grid(n_landmarks, side, sigma, np.random.default_rng(7))
    graph = nx.from_numpy_array(world.landmark_graph(pos, radius).astype(np.int8))
    assert world.clustering_coefficient(pos, radius) == nx.average_clustering(graph)


def test_a_split_team_reconnects_within_the_phases_to_cross_the_area():
    """A split team regroups at the point where its last whole-team plan placed l_c, the same point for every
    vehicle, so every split ends within ⌈√2·side / d_max⌉ phases: the farthest any vehicle can be from that point,
    covered at d_max = speed·t_window per phase. Runs at Fig. 10's settings (d_comms = 10 < d_max = 30), where
    the team splits often; before the fix, subgroups aimed at their own estimates of l_c and some never met."""
    env = RendezvousMappingEnv(d_comms=10.0, t_window=30.0, max_cycles=150)
    bound = math.ceil(math.sqrt(2.0) * env.side / env.d_max)
    splits = 0
    for seed in range(8):
        for sigma in (0.0, 12.0):
            env = RendezvousMappingEnv(d_comms=10.0, t_window=30.0, sigma=sigma, max_cycles=150)
            policy = PaperProtocol()
            obs, _ = env.reset(seed=seed)
            policy.reset(env.local_views(), seed)
            split_for = 0
            while env.agents:
                obs, *_ = env.step(policy.act(obs, env.local_views()))
                if env.n_groups > 1:
                    splits += split_for == 0
                    split_for += 1
                    assert split_for <= bound, f"seed {seed}, σ {sigma}: split for {split_for} phases (bound {bound})"
                    # every vehicle of a split team heads for the one regroup point
                    assert np.ptp(env.local_views().team("rendezvous_point"), axis=0).max() == 0.0
                split_for = split_for if env.n_groups > 1 else 0
    assert splits >= 5, "these settings must split the team for the test to mean anything"


# ------------------------------------------------------------------------------------------------ compiled plan
def _use_plan_backend(monkeypatch, compiled: bool) -> None:
    """The compiled partition pass, spanning forest, observation, window and fusion, or the numpy/scipy reference
    (``protocol.recommend``, ``world.spanning_forest``, the env and ``filters`` ask at every call)."""
    import types

    from mrcomm_env.rendezvous import env as env_module

    choice = types.SimpleNamespace(compiled=lambda: compiled)
    monkeypatch.setattr(protocol, "backend", choice)
    monkeypatch.setattr(world, "backend", choice)
    monkeypatch.setattr(env_module, "backend", choice)
    monkeypatch.setattr(filters, "backend", choice)


def _tied_layout(rng, L: int) -> np.ndarray:
    """Landmark estimates with the ties the pass must settle as the reference does: an exact grid (equal
    separations: complete clusters, regular graphs whose Perron vector ties every member, equidistant outliers)
    or a random field."""
    if rng.random() < 0.5:
        side = math.ceil(math.sqrt(L))
        grid = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:L]
        return grid * float(rng.choice([5.0, 10.0]))
    return rng.uniform(0, 100, size=(L, 2))


def _random_plan(rng, min_vehicles: int, max_landmarks: int, tie_probability: float, exhausted_share: float):
    """``(U, landmark estimates, d_comms)`` of a random plan: 1–12 vehicles, tied layouts, and with probability
    ``tie_probability`` a share of exhausted landmarks, worth exactly 0 (ties in U: a row's n best tie at 0)."""
    n = int(rng.integers(min_vehicles, 13))
    L = int(rng.integers(n, max_landmarks))
    lm = _tied_layout(rng, L)
    U = rng.random((n, L))
    if rng.random() < tie_probability:
        U[:, rng.random(L) < exhausted_share] = 0.0
    return U, lm, float(rng.choice([0.0, 5.0, 10.0, 10.5, 15.0, 30.0, math.inf]))


def test_compiled_partition_pass_plans_what_the_reference_plans(monkeypatch):
    pytest.importorskip("numba")
    rng = np.random.default_rng(11)
    passes = ties = eigenvectors = 0
    for _ in range(400):
        U, lm, d = _random_plan(rng, min_vehicles=1, max_landmarks=90, tie_probability=0.4, exhausted_share=0.7)
        plans = []
        for compiled in (False, True):
            _use_plan_backend(monkeypatch, compiled)
            plans.append(protocol.recommend(U, lm, d, record=True))
        want, got = plans
        assert np.array_equal(want.assignment, got.assignment) and np.array_equal(want.in_main, got.in_main)
        assert (want.central, want.connected) == (got.central, got.connected)
        assert len(want.steps) == len(got.steps)
        for a, b in zip(want.steps, got.steps):
            assert np.array_equal(a.working, b.working) and np.array_equal(a.cluster_of, b.cluster_of)
            assert (a.main, a.central, a.outlier) == (b.main, b.central, b.outlier)
            passes += 1
            main = a.assignment[a.cluster_of == a.main]
            ties += len(main) > 1
            eigenvectors += not protocol.adjacency(lm[main], d).all()  # l_c from the Perron vector, not a tie
    # many passes, many main clusters that needed l_c settled, and many whose eigenvector settled it
    assert passes > 1000 and ties > 100 and eigenvectors > 100


def test_compiled_munkres_is_scipys_linear_sum_assignment_including_its_ties():
    pytest.importorskip("numba")
    from mrcomm_env.rendezvous import plan_numba

    rng = np.random.default_rng(3)
    for trial in range(3000):
        rows = int(rng.integers(1, 13))
        cost = rng.random((rows, int(rng.integers(rows, 40))))
        if trial % 3 == 1:  # few distinct values: many optimal matchings, settled by scipy's tie rules
            cost = np.floor(cost * 3.0)
        elif trial % 3 == 2:  # exhausted landmarks: whole columns worth exactly 0
            cost[:, rng.random(cost.shape[1]) < 0.6] = 0.0
        matched_rows, matched_columns = linear_sum_assignment(cost, maximize=True)
        assert np.array_equal(matched_rows, np.arange(rows))
        assert np.array_equal(plan_numba.lsap_max(cost), matched_columns)


def test_compiled_eq8_sign_is_numpys_or_says_rounding_could_change_it():
    pytest.importorskip("numba")
    from mrcomm_env.rendezvous import plan_numba

    rng = np.random.default_rng(8)
    answered = unsure = 0
    for trial in range(20000):
        axis = rng.uniform(-50.0, 50.0, size=2)
        offset = rng.uniform(-50.0, 50.0, size=2)
        if trial % 2:  # nearly perpendicular: x·y within rounding of 0
            offset = np.array([-axis[1], axis[0]]) * rng.uniform(0.1, 3.0) + rng.normal(0.0, 1e-14, size=2)
        sign = plan_numba._sign_of_dot(offset[0], offset[1], axis[0], axis[1])
        if sign == 2:
            unsure += 1
            continue
        answered += 1
        assert sign == int(np.sign(offset[None, :] @ axis)[0]), (offset, axis)
    assert answered > 10000 and unsure > 1000


def test_compiled_spanning_forest_is_scipys_dijkstra_forest_or_says_it_is_ambiguous(monkeypatch):
    pytest.importorskip("numba")
    from mrcomm_env.rendezvous import forest_numba

    rng = np.random.default_rng(5)
    exact = ambiguous = deep = 0
    for trial in range(3000):
        n = int(rng.integers(2, 31))
        if trial % 3 == 0:  # a random team
            pos = rng.uniform(0.0, 60.0, size=(n, 2))
        elif trial % 3 == 1:  # vehicles on an exact grid: many shortest paths of equal length
            pos = rng.integers(0, 5, size=(n, 2)) * 10.0
        else:  # half the team co-located (a rendezvous), the rest at random
            pos = rng.uniform(0.0, 60.0, size=(n, 2))
            pos[rng.random(n) < 0.5] = pos[0]
        links = world.vehicle_links(pos, float(rng.choice([0.0, 10.0, 15.0, 20.0, 30.0, math.inf])))
        _use_plan_backend(monkeypatch, False)
        labels, parent = world.spanning_forest(pos, links)  # scipy's Dijkstra
        got_labels, got_parent, tied = forest_numba.spanning_forest(pos, links, world.LINK_LENGTH_FLOOR)
        _use_plan_backend(monkeypatch, True)
        assert bit_identical(world.spanning_forest(pos, links), (labels, parent))  # the dispatch, either branch
        if tied:
            ambiguous += 1
            continue
        exact += 1
        assert bit_identical((got_labels, got_parent), (labels, parent))
        # a tree that is not a star: Dijkstra chose among longer paths, not only the root's links
        deep += bool(((parent >= 0) & (parent[np.maximum(parent, 0)] >= 0)).any())
    # both branches taken many times, and many of the exact trees were more than one hop deep
    assert exact > 1000 and ambiguous > 100 and deep > 500


def test_compiled_recommendation_loop_plans_what_the_reference_plans_from_any_pass(monkeypatch):
    """The whole loop compiled (numpy choosing a row's tied best columns when asked) gives the reference's plan,
    and so does resuming it from the working set of any of the reference's passes."""
    pytest.importorskip("numba")
    from mrcomm_env.rendezvous import plan_numba

    def compiled_from(U, lm, d, working):
        nonlocal chose_itself
        best = np.empty((0, 0), dtype=np.int64)
        chose_itself += len(working) > U.shape[0] ** 2  # a pre-selection the loop may settle itself
        while True:
            status, working, assignment, in_main, central, connected = plan_numba.recommend_loop(
                U, lm, d, working, best
            )
            statuses[status] += 1
            if status == plan_numba.PLANNED:
                return assignment, in_main, central, connected
            if status == plan_numba.AMBIGUOUS:
                return None
            chose_itself -= best.size == 0 and len(working) > U.shape[0] ** 2  # it could not
            if every_row:  # numpy's picks on every row, as the reference's candidate_columns takes them
                best = protocol.best_positions(-U, working)
            else:  # on the tied rows only, as protocol.recommend hands them over
                rows, negated = plan_numba.tied_rows(U, working)
                assert rows.size and np.array_equal(negated, -U[np.ix_(rows, working)])
                best = np.ascontiguousarray(np.argpartition(negated, len(U) - 1, axis=1)[:, : len(U)])

    rng = np.random.default_rng(13)
    chose_itself = every_row = 0
    statuses = {plan_numba.PLANNED: 0, plan_numba.NEED_COLUMNS: 0, plan_numba.AMBIGUOUS: 0}
    resumed = 0
    for _ in range(300):  # more landmarks than a row's n best: the loop's own pre-selection, or numpy's on ties
        U, lm, d = _random_plan(rng, min_vehicles=2, max_landmarks=200, tie_probability=0.5, exhausted_share=0.8)
        _use_plan_backend(monkeypatch, False)
        want = protocol.recommend(U, lm, d, record=True)
        _use_plan_backend(monkeypatch, True)
        got = protocol.recommend(U, lm, d)
        expected = (want.assignment, want.in_main, want.central, want.connected)
        assert bit_identical(got.assignment, want.assignment) and bit_identical(got.in_main, want.in_main)
        assert (type(got.central), got.central, got.connected) == (int, want.central, want.connected)
        for every_row, step in enumerate(want.steps):
            every_row %= 2
            plan = compiled_from(U, lm, d, step.working)
            if plan is not None:
                resumed += 1
                assert all(bit_identical(a, b) for a, b in zip(plan, expected, strict=True))
    # plans finished in the loop, many that needed numpy's choice among tied columns on the way, and many whose
    # first pass had more columns than Munkres needs and chose them itself
    assert resumed > 500 and statuses[plan_numba.PLANNED] > 500 and statuses[plan_numba.NEED_COLUMNS] > 100
    assert chose_itself > 100


def test_recommend_resumes_the_reference_passes_where_the_compiled_loop_hands_over(monkeypatch):
    """The compiled loop stops when an eq. (8) sign could round either way (rare in random plans, so forced here):
    ``protocol.recommend`` then runs the reference's passes from the working set it stopped at, and plans what the
    reference plans."""
    pytest.importorskip("numba")
    from mrcomm_env.rendezvous import plan_numba

    rng = np.random.default_rng(17)
    resumed = 0
    for _ in range(200):
        U, lm, d = _random_plan(rng, min_vehicles=2, max_landmarks=120, tie_probability=0.5, exhausted_share=0.8)
        _use_plan_backend(monkeypatch, False)
        want = protocol.recommend(U, lm, d, record=True)
        if len(want.steps) < 2:
            continue
        stop_at = want.steps[int(rng.integers(1, len(want.steps)))].working
        handed_over = []

        def hand_over(U, landmark_pos, d_comms, working, best, stop_at=stop_at, handed_over=handed_over):
            handed_over.append(True)
            return plan_numba.AMBIGUOUS, stop_at.copy(), np.full(len(U), -1), np.zeros(len(U), bool), -1, False

        monkeypatch.setattr(plan_numba, "recommend_loop", hand_over)
        _use_plan_backend(monkeypatch, True)
        got = protocol.recommend(U, lm, d)
        monkeypatch.undo()
        assert handed_over
        assert bit_identical(got.assignment, want.assignment) and bit_identical(got.in_main, want.in_main)
        assert (got.central, got.connected) == (want.central, want.connected)
        resumed += 1
    assert resumed > 50


@pytest.mark.parametrize(
    "kwargs",
    [
        {},  # the default
        {"n_vehicles": 1, "n_landmarks": 3},  # nobody else to list, more candidate slots than landmarks
        {"n_vehicles": 3, "k_candidates": 8, "d_comms": 0.0},  # more slots than other vehicles; split at once
        {"n_vehicles": 12, "k_candidates": 1, "sigma": 0.0, "d_comms": 15.0},  # an exact grid: tied distances
        {"speed": 0.01, "t_window": 2.0, "area": 1e6},  # nothing within reach: every candidate far away
    ],
)
def test_compiled_observation_is_the_reference_at_every_step(monkeypatch, kwargs):
    """The same state observed by both backends, byte for byte, over whole episodes of random actions."""
    pytest.importorskip("numba")
    env = RendezvousMappingEnv(max_cycles=30, **kwargs)
    env.reset(seed=8)
    rng = np.random.default_rng(3)
    observed = 0
    while True:
        both = []
        for compiled in (False, True):
            _use_plan_backend(monkeypatch, compiled)
            both.append(env._observe())
        reference, twin = both
        assert twin.dtype == reference.dtype == np.float32 and twin.shape == reference.shape
        assert twin.tobytes() == reference.tobytes(), np.argwhere(twin != reference)[:5]
        observed += 1
        if not env.agents:
            break
        env.step({a: int(rng.integers(env.K + 2)) for a in env.agents})
    assert observed > 5


@pytest.mark.parametrize(
    "kwargs",
    [
        {},  # the default
        # crowded: a dozen vehicles on a dozen landmarks reach the floor within a window, on tied instants
        {"n_vehicles": 12, "n_landmarks": 12, "area": 400.0, "obs_rate": 4.0, "obs_per_landmark": 7},
        {"speed": 0.3},  # most targets out of reach (d_max = 4.5 m): travel towards them
        {"sigma": 0.0, "d_comms": 15.0, "n_vehicles": 8},  # an exact grid: tied distances and detours
        # a high floor at a high rate: hundreds of kept observations in a window
        {"obs_per_landmark": 1000, "obs_rate": 50.0, "n_landmarks": 20, "n_vehicles": 6, "area": 900.0},
    ],
)
def test_compiled_window_is_the_reference_at_every_step(monkeypatch, kwargs):
    """The same window by both backends: positions, landmarks stayed at, action kinds and feasibility, and the
    kept observations in order (random actions, infeasible ones included)."""
    pytest.importorskip("numba")
    from mrcomm_env.rendezvous import env as env_module
    from mrcomm_env.rendezvous import window_numba

    assert (window_numba.GO, window_numba.DETOUR_RENDEZVOUS, window_numba.RENDEZVOUS, window_numba.HOLD) == (
        env_module.GO,
        env_module.DETOUR_RENDEZVOUS,
        env_module.RENDEZVOUS,
        env_module.HOLD,
    )
    env = RendezvousMappingEnv(max_cycles=25, **kwargs)
    env.reset(seed=5)
    rng = np.random.default_rng(2)
    kinds, kept = set(), 0
    while env.agents:
        actions = [int(rng.integers(env.K + 2)) for _ in env.agents]
        kind_before, ok_before = env.action_kind.copy(), env.action_ok.copy()
        want = env._window(actions)
        want_kind, want_ok = env.action_kind.copy(), env.action_ok.copy()
        env.action_kind[:], env.action_ok[:] = kind_before, ok_before
        got = window_numba.window(
            np.asarray(actions, dtype=np.int64), env.mask, env.candidates, env.assignment, env.central,
            env.rendezvous_point, env.at_landmark, env.pos, env._estimates, env.ticks, env.cfg.t_window,
            env.cfg.speed, env.world_count, env.cfg.obs_per_landmark, env.action_kind, env.action_ok,
        )  # fmt: skip
        for a, b in zip(want, got, strict=True):
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
        assert np.array_equal(env.action_kind, want_kind) and np.array_equal(env.action_ok, want_ok)
        kinds.update(want_kind.tolist())
        kept += len(want[2])
        env.step(dict(zip(env.agents, actions)))
    assert kept > 0 and len(kinds) >= 3


def test_compiled_fusion_adds_packets_and_takes_means_as_numpy_does(monkeypatch):
    """Entries with repeated landmarks (np.add.at's order matters), added into one map on both backends, and the
    means of the maps: bit for bit."""
    pytest.importorskip("numba")
    rng = np.random.default_rng(4)
    L = 12
    for trial in range(300):
        m = int(rng.integers(1, 20))
        landmarks = rng.integers(0, L if trial % 2 else 3, m).astype(np.int32)
        dcount = rng.integers(1, 4, m).astype(np.int32)
        R_inv = random_spd(rng, 10.0 ** rng.integers(-4, 5)) if trial % 3 else np.eye(2) * rng.uniform(0.1, 1e4)
        dy = rng.normal(0.0, 10.0 ** rng.integers(-3, 6), (m, 2))
        start = (np.eye(2) * rng.uniform(1e-4, 1e6, (L, 1, 1)), rng.normal(0.0, 100.0, (L, 2)))
        maps = []
        for compiled in (False, True):
            _use_plan_backend(monkeypatch, compiled)
            Y, y, count = start[0].copy(), start[1].copy(), np.zeros(L, dtype=np.int64)
            filters._add_entries(Y, y, count, landmarks, dy, dcount, R_inv)
            maps.append((Y, y, count, filters.mean_of(Y[None], y[None])))
        for want, got in zip(*maps):
            assert want.dtype == got.dtype and want.tobytes() == got.tobytes()


def test_compiled_group_fusion_is_the_references(monkeypatch):
    """Groups fused over random trees in random meeting sequences, with packets piling up past the cumulative table's
    first size: the bits each tree edge carries both ways (``fusion_numba.edge_bits``) and every member's map and
    version vector after the exchange, the same bytes on both backends."""
    pytest.importorskip("numba")
    rng = np.random.default_rng(17)
    L, edges, silent = 9, 0, 0
    for _ in range(20):
        n = int(rng.integers(2, 9))
        R_inv = random_spd(rng)
        both = [
            filters.TeamMaps(n, np.broadcast_to(np.eye(2), (L, 2, 2)).copy(), np.zeros((L, 2)), R_inv) for _ in range(2)
        ]
        for _ in range(int(rng.integers(5, 40))):
            for v in range(n):
                if rng.random() < 0.7:
                    packet = make_packet(rng, L)
                    for maps in both:
                        maps.add_own(v, packet)
            pos = rng.uniform(0, 30, size=(n, 2))
            labels, parent = world.spanning_forest(pos, world.vehicle_links(pos, float(rng.uniform(0, 30))))
            for g in range(labels.max() + 1):
                members = np.flatnonzero(labels == g)
                sent = []
                for compiled, maps in zip((False, True), both):
                    _use_plan_backend(monkeypatch, compiled)
                    sent.append(maps.fuse_group(members, parent))
                assert sent[0] == sent[1] and list(sent[0]) == list(sent[1])
                assert all(type(bits) is int for bits in sent[1].values())
                edges += len(sent[0])
                silent += sum(bits == 0 for bits in sent[0].values())
                for name in ("known", "Y", "y", "count"):
                    assert getattr(both[0], name).tobytes() == getattr(both[1], name).tobytes(), name
    assert edges > 300 and 0 < silent < edges


def test_compiled_candidate_ranking_is_numpys_bit_for_bit(monkeypatch):
    """``candidate_lists`` on both backends (numpy's argpartition chooses the set on both): the same bytes, with tied
    and zero utilities, recommendations worth something or nothing or absent, NaN, and K below, at and above L."""
    pytest.importorskip("numba")
    from mrcomm_env.rendezvous.env import candidate_lists

    rng = np.random.default_rng(12)
    ties = nans = 0
    for trial in range(400):
        n, L, K = int(rng.integers(1, 11)), int(rng.integers(1, 40)), int(rng.integers(1, 12))
        utility = np.round(rng.random((n, L)), int(rng.integers(0, 3)))  # rounded: many exact ties
        utility[:, rng.random(L) < 0.3] = 0.0  # believed exhausted
        if trial % 7 == 0:
            utility[rng.random((n, L)) < 0.05] = np.nan
        assignment = rng.integers(-1, L, n)
        got = []
        for compiled in (False, True):
            _use_plan_backend(monkeypatch, compiled)
            got.append(candidate_lists(utility, assignment, K))
        for want, have in zip(*got):
            assert want.dtype == have.dtype and want.tobytes() == have.tobytes()
        ties += int(sum(len(np.unique(row)) < L for row in utility))
        nans += int(np.isnan(utility).any())
    assert ties > 200 and nans > 20
    for compiled in (False, True):  # a recommendation that is no landmark: numpy's IndexError on both backends
        _use_plan_backend(monkeypatch, compiled)
        with pytest.raises(IndexError):
            candidate_lists(np.ones((2, 5)), np.array([0, 5]), 3)


def test_compiled_utility_is_numpys_bit_for_bit(monkeypatch):
    """Eq. (1)–(4) of one map per vehicle on both backends: the same bytes, with landmarks out of reach (ε), exhausted
    or over-observed (worth 0), exactly at the window's edge, at distance 0, and under a nearly singular Y."""
    pytest.importorskip("numba")
    rng = np.random.default_rng(9)
    edges = reaches = exhausted = 0
    for trial in range(200):
        n, L = int(rng.integers(1, 11)), int(rng.integers(1, 60))
        speed, t_window, info, rate = (float(x) for x in rng.uniform(0.2, 3.0, 4))
        budget = int(rng.integers(1, 12))
        vehicles = rng.uniform(0, 40, (n, 2))
        landmarks = rng.uniform(0, 40, (n, L, 2))
        landmarks[:, : L // 4] = vehicles[:, None, :]  # distance 0
        if trial % 3 == 0:  # a landmark exactly one window's travel away: t_obs = 0 takes ε
            landmarks[:, -1] = vehicles + np.array([speed * t_window, 0.0])
        scale = 10.0 ** rng.integers(-6, 7, (n, L, 1, 1))
        Y = np.array([random_spd(rng, 0.1) for _ in range(n * L)]).reshape(n, L, 2, 2) * scale
        Y[:, 0, 0, 1] = Y[:, 0, 1, 0] = np.sqrt(Y[:, 0, 0, 0] * Y[:, 0, 1, 1]) * (1 - 1e-12)  # |Y| ≈ 0
        count = rng.integers(0, budget + 3, (n, L))
        got = []
        for compiled in (False, True):
            _use_plan_backend(monkeypatch, compiled)
            args = (Y, count, vehicles, landmarks, speed, t_window, info, rate, budget)
            got.append(protocol.utility_matrix(*args))
        assert got[0].dtype == got[1].dtype and got[0].tobytes() == got[1].tobytes()
        travel = np.linalg.norm(vehicles[:, None, :] - landmarks, axis=-1) / speed
        edges += int((t_window - travel == 0.0).sum())
        reaches += int((travel < t_window).sum())
        exhausted += int((count >= budget).sum())
    assert edges > 10 and reaches > 1000 and exhausted > 1000
    # shapes numpy broadcasts (one estimate shared by every vehicle) are numpy's on both backends
    shared = []
    for compiled in (False, True):
        _use_plan_backend(monkeypatch, compiled)
        shared.append(protocol.utility_matrix(Y, count, vehicles, landmarks[:1], speed, t_window, info, rate, budget))
    assert shared[0].shape == (n, L) and shared[0].tobytes() == shared[1].tobytes()


@pytest.mark.parametrize("compiled", [False, True])
def test_a_packet_outside_the_map_raises_on_both_backends(monkeypatch, compiled):
    if compiled:
        pytest.importorskip("numba")
    _use_plan_backend(monkeypatch, compiled)
    Y, y, count = np.ones((4, 2, 2)), np.ones((4, 2)), np.zeros(4, dtype=np.int64)
    with pytest.raises(IndexError):
        filters._add_entries(Y, y, count, np.array([1, 4], np.int32), np.ones((2, 2)), np.ones(2, np.int32), np.eye(2))


def test_compiled_packets_of_a_window_are_the_references(monkeypatch):
    """Random kept observations (repeated pairs, vehicles out of order, a vehicle with none) become the same
    packets, maps and counts on both backends, to the last bit."""
    pytest.importorskip("numba")
    import copy

    rng = np.random.default_rng(11)
    env = RendezvousMappingEnv(n_vehicles=7, n_landmarks=30, obs_per_landmark=50)
    env.reset(seed=1)
    for trial in range(200):
        m = int(rng.integers(1, 40))
        v = rng.integers(0, 6, m)  # vehicle 6 never observes
        lm = rng.integers(0, 30 if trial % 2 else 3, m)  # half the trials: three landmarks, many repeats
        runs = []
        for compiled in (False, True):
            _use_plan_backend(monkeypatch, compiled)
            twin = copy.deepcopy(env)
            twin._apply_observations(v, lm)
            runs.append(twin)
        want, got = runs
        for name in ("Y", "y", "count", "known"):
            assert getattr(want.maps, name).tobytes() == getattr(got.maps, name).tobytes(), name
        assert np.array_equal(want.step_obs, got.step_obs) and np.array_equal(want.world_count, got.world_count)
        for ours, theirs in zip(want.maps.logs, got.maps.logs, strict=True):
            assert (ours.first, ours.kept) == (theirs.first, theirs.kept)
            assert ours.cum_bits[: ours.kept + 1].tobytes() == theirs.cum_bits[: theirs.kept + 1].tobytes()
            for a, b in zip(ours.packets(), theirs.packets(), strict=True):
                for field in ("landmarks", "dy", "count"):
                    x, y = getattr(a, field), getattr(b, field)
                    assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), field
        env = got  # go on from there: packets accumulate
    assert sum(log.made for log in env.maps.logs) > 200


@pytest.mark.parametrize(
    "kwargs",
    [
        {"d_comms": 10.0},  # the default: the team splits and regroups
        {"d_comms": math.inf, "n_vehicles": 6},  # one complete plan per phase
        {"d_comms": 0.0, "n_vehicles": 5},  # co-located only
        {"d_comms": 15.0, "sigma": 0.0, "n_vehicles": 12},  # an exact grid: ties everywhere
        {"d_comms": 20.0, "clumping": 0.9, "n_vehicles": 8},
    ],
)
@pytest.mark.parametrize("policy", ["paper_protocol", "random"])
def test_whole_episodes_are_identical_with_the_compiled_plan_and_forest(monkeypatch, kwargs, policy):
    pytest.importorskip("numba")
    _assert_backends_agree(monkeypatch, {"n_landmarks": 80, "area": 3600.0, "max_cycles": 25, **kwargs}, policy, 29)


@st.composite
def _drawn_configs(draw):
    """RendezvousMapping arguments across what the compiled plan, forest, window and fusion branch on: one vehicle
    to a crowd, few landmarks to many, no links to all, exact grids (ties) and clumps, a sensor floor of one."""
    n = draw(st.integers(1, 9))
    return {
        "n_vehicles": n,
        "n_landmarks": draw(st.integers(n, 70)),
        "area": draw(st.sampled_from([400.0, 3600.0, 20_000.0])),
        "speed": draw(st.sampled_from([0.2, 1.0, 3.0])),
        "t_window": draw(st.sampled_from([1.0, 10.0, 40.0])),
        "d_comms": draw(st.sampled_from([0.0, 5.0, 15.0, 40.0, math.inf])),
        "sigma": draw(st.sampled_from([0.0, 5.0, 30.0])),
        "clumping": draw(st.sampled_from([0.0, 0.5, 0.9])),
        "k_candidates": draw(st.integers(1, 8)),
        "obs_per_landmark": draw(st.sampled_from([1, 3, 20])),
        "obs_rate": draw(st.sampled_from([0.2, 1.0, 4.0])),
        "max_cycles": draw(st.integers(1, 10)),
    }


@settings(max_examples=25, deadline=None)
@given(kwargs=_drawn_configs(), policy=st.sampled_from(["paper_protocol", "random"]), seed=st.integers(0, 2**16))
def test_whole_episodes_of_drawn_configurations_are_identical_with_the_compiled_plan_and_forest(kwargs, policy, seed):
    """The fixed cases above, and drawn ones (25 per run, the same ones in ``make test``)."""
    pytest.importorskip("numba")
    with pytest.MonkeyPatch.context() as monkeypatch:
        _assert_backends_agree(monkeypatch, kwargs, policy, seed)


def _assert_backends_agree(monkeypatch, kwargs, policy, seed):
    """One seeded episode under the baseline ``policy`` on each backend: every observation, reward and info, the
    plans (assignment, l_c), the positions and the metrics, byte for byte."""
    from mrcomm_baselines import make_policy

    def episode(compiled):
        _use_plan_backend(monkeypatch, compiled)
        env = RendezvousMappingEnv(**kwargs)
        pol = make_policy("RendezvousMapping-v0", policy)
        views = env.local_views()
        obs, infos = env.reset(seed=seed)
        pol.reset(views, seed)
        trace = [(obs, infos)]
        while env.agents:
            obs, rewards, _, _, infos = env.step(pol.act(obs, views))
            trace.append((obs, rewards, infos, env.assignment.copy(), env.central.copy(), env.pos.copy()))
        return trace, repr(env.metrics())

    reference, compiled = episode(False), episode(True)
    assert len(reference[0]) == len(compiled[0]) > 1
    for want, got in zip(reference[0], compiled[0]):
        assert all(bit_identical(a, b) for a, b in zip(want, got, strict=True))
    assert reference[1] == compiled[1]
