"""RendezvousMapping-v0 (paper 004): the §IV module (clusters, central landmarks, restricted Munkres, Eq. 1–8
utility and partition, Fig. 5's action module) and the world's clustering."""

from __future__ import annotations

import math

import networkx as nx
import numpy as np
import pytest
from helpers.rendezvous_reference import adjacency, central_landmark, clusters, fine_dm_blocks
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from mrcomm_baselines.rendezvous_mapping import action_module
from mrcomm_env.rendezvous import protocol, world


def random_spd(rng, scale=1.0):
    a = rng.normal(size=(2, 2))
    return scale * (a @ a.T + 0.2 * np.eye(2))


# ------------------------------------------------------------------------------------------------ §IV module
def random_adjacency(rng, n, radius):
    pos = rng.uniform(0, 40, size=(n, 2))
    return adjacency(pos, radius), pos


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(1, 40), radius=st.floats(0.0, 30.0))
def test_clusters_are_the_fine_dulmage_mendelsohn_blocks_and_the_connected_components(seed, n, radius):
    adj, _ = random_adjacency(np.random.default_rng(seed), n, radius)
    k, labels = clusters(adj)
    ours = {frozenset(np.flatnonzero(labels == b).tolist()) for b in range(k)}
    assert ours == set(fine_dm_blocks(adj))
    assert ours == {frozenset(c) for c in nx.connected_components(nx.from_numpy_array(adj.astype(int)))}
    k_sp, lab_sp = connected_components(csr_matrix(adj), directed=False)
    assert k == k_sp and (labels == lab_sp).all()  # same numbering as scipy's


def test_central_landmark_is_networkx_eigenvector_centrality_argmax():
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(200):
        adj, pos = random_adjacency(rng, int(rng.integers(3, 15)), 15.0)
        k, labels = clusters(adj)
        big = np.flatnonzero(labels == np.bincount(labels).argmax())
        sub = adj[np.ix_(big, big)].astype(int)
        np.fill_diagonal(sub, 0)
        if len(big) < 3:
            continue
        cent = nx.eigenvector_centrality_numpy(nx.from_numpy_array(sub))
        values = np.array([cent[i] for i in range(len(big))])
        if np.sort(values)[-1] - np.sort(values)[-2] < 1e-6:  # tie: our tie rule decides
            continue
        assert central_landmark(adj[np.ix_(big, big)], pos[big]) == int(np.argmax(values))
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
        k, _ = clusters(adjacency(lm[assigned], d))
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
