"""RendezvousMapping-v0 (paper 004): the env's masks, reward, bits, budget, arguments and bad input, and a split
team reconnecting."""

from __future__ import annotations

import math

import networkx as nx
import numpy as np
import pytest

import mrcomm_env
from mrcomm_baselines.rendezvous_mapping import POLICIES, PaperProtocol
from mrcomm_env.rendezvous import filters, theory, world
from mrcomm_env.rendezvous.env import HOLD, RendezvousMappingEnv

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
