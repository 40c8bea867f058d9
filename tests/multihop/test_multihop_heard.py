"""MultiHop-v0's ``observe_heard``: what each robot heard bounds its neighbours' tables, the sixth candidate feature,
the ``heard_aware`` baseline that reads it, and the settings it refuses."""

from __future__ import annotations

import numpy as np
import pytest

from mrcomm_baselines import make_policy
from mrcomm_env.experiments.evaluation import run_episode
from mrcomm_env.multihop import protocol as proto
from mrcomm_env.multihop.env import RELATIVE_FEATURES, MultiHopEnv

SMALL = dict(grid_side=4, slot_size=3, max_cycles=12)


def random_episode(env, seed, frames):
    """Reset ``env`` to ``seed`` and yield after each of ``frames`` frames of seeded random select bits."""
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    for frame in range(frames):
        env.step({a: rng.integers(0, 2, env.n_agents - 1).astype(np.int8) for a in env.agents})
        yield frame


def test_heard_is_a_lower_bound_on_each_neighbours_table_and_holds_every_broadcast():
    env = MultiHopEnv(observe_heard=True, **SMALL)
    env.reset(seed=3)
    links = env.adj.astype(bool)  # a grid's links: the same every frame
    for _ in random_episode(env, seed=3, frames=12):
        heard = env.heard
        # nothing is ever known of a robot that is not a neighbour, nor of a robot's own table
        assert not np.isfinite(heard[~links]).any()
        # what robot i knows neighbour k holds is never fresher than k's own table (the bound is sound)
        finite = np.isfinite(heard)
        assert (heard[finite] <= np.broadcast_to(env.stamps[None], heard.shape)[finite]).all()
        # and it holds every stamp either of them broadcast this frame (the bound keeps what was heard)
        for i, k in zip(*np.nonzero(links), strict=True):
            for sender in (i, k):
                sent = env.last_sent[sender]
                assert (heard[i, k, sent] >= env.sent_stamp[sender, sent]).all()
    # every robot broadcasts its own estimate each frame, so every neighbour's own entry is known
    assert np.isfinite(heard[links, np.nonzero(links)[1]]).all()


def lack_by_loops(env):
    """The ``neighbour_lack`` feature written as its definition reads, one robot, neighbour and estimate at a time."""
    n, t_frame = env.n_agents, env.frame_dur
    lack = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            if env.stamps[i, j] == proto.UNKNOWN:
                continue
            shares = []
            for k in np.flatnonzero(env.adj[i]):
                if k == j:
                    continue
                if env.heard[i, k, j] == proto.UNKNOWN:
                    shares.append(1.0)
                else:
                    g = max(env.stamps[i, j] - env.heard[i, k, j], 0.0)
                    shares.append(g / (g + t_frame))
            lack[i, j] = float(np.mean(shares)) if shares else 0.0
    return lack


def test_neighbour_lack_is_the_mean_freshness_the_neighbours_lack():
    env = MultiHopEnv(observe_heard=True, **SMALL)
    seen = []
    for _ in random_episode(env, seed=5, frames=6):
        lack = env.neighbour_lack()
        # elementwise float64 in another order: agreement to a few ulps of values in [0, 1]
        np.testing.assert_allclose(lack, lack_by_loops(env), rtol=0, atol=1e-12)
        seen.append(lack)
    seen = np.stack(seen)
    assert ((seen >= 0) & (seen <= 1)).all()
    assert (seen == 1.0).any() and ((seen > 0) & (seen < 1)).any()  # both kinds of entry occur


def test_the_sixth_feature_is_the_lack_of_each_ranked_candidate_and_nothing_else_changes():
    plain = MultiHopEnv(**SMALL)
    heard = MultiHopEnv(observe_heard=True, **SMALL)
    n = plain.n_agents
    assert heard.observation_space("robot_0").shape == ((RELATIVE_FEATURES + 1) * (n - 1) + 3,)
    assert heard.observation_layout()["features"] == RELATIVE_FEATURES + 1
    rng = np.random.default_rng(0)
    obs_p, _ = plain.reset(seed=9)
    obs_h, _ = heard.reset(seed=9)
    for _ in range(SMALL["max_cycles"]):
        for agent in plain.agents:
            with_heard = obs_h[agent][:-3].reshape(n - 1, RELATIVE_FEATURES + 1)
            np.testing.assert_array_equal(with_heard[:, :RELATIVE_FEATURES], obs_p[agent][:-3].reshape(n - 1, -1))
            np.testing.assert_array_equal(obs_h[agent][-3:], obs_p[agent][-3:])
            i = heard.possible_agents.index(agent)
            candidates = heard.local_view(agent)["candidates"]
            expected = heard.neighbour_lack()[i, candidates].astype(np.float32)
            np.testing.assert_array_equal(with_heard[:, RELATIVE_FEATURES], expected)
        actions = {a: rng.integers(0, 2, n - 1).astype(np.int8) for a in plain.agents}
        obs_p, rew_p, _, _, info_p = plain.step(actions)
        obs_h, rew_h, _, _, info_h = heard.step(actions)
        assert rew_p == rew_h and info_p == info_h  # the frame itself is the same
    assert plain.metrics() == heard.metrics()


@pytest.mark.parametrize(
    "bad",
    [
        dict(observe_heard=True, layout="absolute"),
        dict(observe_heard=True, scene="field", speed=1.0),
        dict(observe_heard=True, scene="coverage"),
    ],
)
def test_observe_heard_is_refused_where_links_move_or_candidates_are_absent(bad):
    with pytest.raises(ValueError, match="observe_heard"):
        MultiHopEnv(**bad)


def test_a_team_whose_tables_outgrow_the_budget_is_refused_naming_observe_heard():
    MultiHopEnv(grid_side=32)  # in range without it
    with pytest.raises(ValueError, match="observe_heard"):
        MultiHopEnv(grid_side=32, observe_heard=True)  # 28 · 1024³ bytes, over the 4 GiB default


def test_heard_aware_needs_the_heard_view_and_beats_age_aware_with_it():
    plain = MultiHopEnv(grid_side=6, slot_size=4, max_cycles=30)
    plain.reset(seed=0)
    with pytest.raises(ValueError, match="observe_heard"):
        make_policy("mrcomm/MultiHop-v0", "heard_aware").reset(plain.local_views(), 0)
    env = MultiHopEnv(grid_side=6, slot_size=4, max_cycles=30, observe_heard=True)
    ages = {}
    for name in ("heard_aware", "age_aware"):
        runs = [run_episode(env, make_policy("mrcomm/MultiHop-v0", name), seed) for seed in (0, 1, 2)]
        ages[name] = [r["weighted_mean_age"] for r in runs]
        bits = [r["bits_sent"] for r in runs]
        assert max(bits) <= env.n_agents * 30 * env.m * env.cfg.bits_per_estimate
    # resending only what some neighbour lacks leaves room for estimates age_aware wastes it on: fresher tables in
    # every episode, not only on average
    assert all(h < a for h, a in zip(ages["heard_aware"], ages["age_aware"], strict=True))
