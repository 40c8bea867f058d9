"""AsyncCL's bound in docs/learning.md: the flood (``scheme2_qinf``) holds every row as fresh as any policy can, and
the bits of delivering each completed step's packets once are below what any scheme sends.

Expected values come from an independent one-hop flooding recursion over the env's own links (eq. (4)–(5): what a
robot sends at step k is what it held before the exchange), and from the dominance every policy must obey.
"""

from __future__ import annotations

import numpy as np
import pytest

from mrcomm_baselines import make_policy
from mrcomm_env.asynccl.env import AsyncCLEnv
from mrcomm_env.experiments.bounds import asynccl_bound
from mrcomm_env.experiments.evaluation import evaluate_policy

#: the comparison's setting (agents/configs/AsyncCL-v0.json), shorter; delay only: the tables are what matters
SETTING = {"n_robots": 5, "max_cycles": 60, "estimation": False}


def flooded(latest: np.ndarray, delivered: np.ndarray) -> np.ndarray:
    """Rows after one exchange in which every delivered link j → i carries all that j held before it."""
    after = latest.copy()
    for j, i in zip(*np.nonzero(delivered)):
        after[i] = np.maximum(after[i], latest[j])
    return after


def play(env, policy, seed: int):
    """Yield (rows expected of a flood, rows held) after every step of one episode of ``policy``."""
    observations, _ = env.reset(seed=seed)
    policy.reset(env.local_views(), seed)
    while env.agents:
        expected = flooded(env.tables.latest, env.delivered)
        observations, *_ = env.step(policy.act(observations, env.local_views()))
        np.fill_diagonal(expected, env.tables.t)  # every robot adds its own packet of the new step
        yield expected, env.tables.latest.copy()


@pytest.mark.parametrize("kwargs", [{}, {"link_probability": 0.2}, {"packet_loss": 0.3}])
def test_the_flood_is_a_one_hop_flood_and_no_policy_is_fresher(kwargs):
    env = AsyncCLEnv(**SETTING, **kwargs)
    for expected, held in play(env, make_policy("mrcomm/AsyncCL-v0", "scheme2_qinf"), seed=4):
        assert np.array_equal(held, expected)
    flood_rows = [held for _, held in play(env, make_policy("mrcomm/AsyncCL-v0", "scheme2_qinf"), seed=5)]
    for name in ("random", "scheme1", "scheme2_q2", "scheme2_q8"):
        # actions draw nothing from the env's generator: the same seed gives every policy the same links
        rows = [held for _, held in play(env, make_policy("mrcomm/AsyncCL-v0", name), seed=5)]
        assert len(rows) == len(flood_rows)
        assert all((mine <= flood).all() for mine, flood in zip(rows, flood_rows, strict=True))


def test_the_bits_bound_is_below_every_scheme_that_is_as_fast():
    spec = {"metric": "mean_delay", "bits_per": "step"}
    seeds = [7, 8]
    (bound,) = asynccl_bound("mrcomm/AsyncCL-v0", SETTING, seeds, spec)
    for name in ("scheme2_q8", "scheme2_qinf"):
        result = evaluate_policy("mrcomm/AsyncCL-v0", SETTING, make_policy("mrcomm/AsyncCL-v0", name), seeds, spec)
        assert np.mean(result["metric"]) >= bound["metric"] - 1e-12
        assert np.mean(result["bits"]) > bound["bits"] > 0
