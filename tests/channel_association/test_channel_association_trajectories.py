"""mrcomm/ChannelAssociation-v0 keeps views and caches on its hot path (incremental ranges, cached
statistics, buffered coin flips): a pickled copy taken mid-episode must still step exactly like the
original."""

from __future__ import annotations

import numpy as np

from mrcomm_baselines.channel_association import POLICIES
from mrcomm_env.channel_association.env import ChannelAssociationEnv


def test_pickled_env_continues_identically():
    """The tuned env keeps views and caches; a pickled copy mid-episode must step exactly like the original."""
    import pickle

    for kwargs in ({"mobile_fraction": 0.5}, {"n_robots": 90, "mobile_fraction": 0.2}):
        env, policy = ChannelAssociationEnv(**kwargs), POLICIES["coin_flip"]()
        obs, _ = env.reset(seed=1)
        policy.reset(env.local_views(), 1)
        for _ in range(5):
            obs, *_ = env.step(policy.act(obs, env.local_views()))
        clone = pickle.loads(pickle.dumps(env))
        for _ in range(20):
            actions = policy.act(obs, env.local_views())
            a, b = env.step(actions), clone.step(actions)
            assert all(np.array_equal(a[0][k], b[0][k]) for k in a[0]) and a[1:] == b[1:]
            obs = a[0]
        assert env.metrics() == clone.metrics()
