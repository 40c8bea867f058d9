"""Checks the per-env world tests and the batch tests share: a batch's copy i against the single env seeded
s + i, episode after episode, byte for byte."""

from __future__ import annotations

import numpy as np

import mrcomm_env
from mrcomm_env.core.batched import sample_actions
from mrcomm_env.testing import same


def as_bytes(array) -> bytes:
    """The array's bytes in C order: two arrays are byte-identical when these are equal."""
    return np.ascontiguousarray(array).tobytes()


def assert_copies_are_single_envs(batch, env_id, kwargs, horizon, make_single=None, some_terminate=True):
    """Steps ``batch`` and one single env per copy with the same random actions for ``horizon`` steps;
    asserts every copy's observations, rewards, ends, infos, bits and final metrics equal its single env's
    (seeded 11 + i, reset without a seed after each end) and that every copy ended at least twice.
    Returns the single envs."""
    n_copies, seed = batch.n_copies, 11
    make_single = make_single or (lambda: mrcomm_env.make(env_id, **kwargs))
    singles = [make_single() for _ in range(n_copies)]
    observations, infos = batch.reset(seed=seed)
    agents = singles[0].possible_agents
    for i, env in enumerate(singles):
        single_obs, single_infos = env.reset(seed=seed + i)
        assert as_bytes(observations[i]) == as_bytes(np.stack([single_obs[a] for a in agents]))
        assert {k: v[i].tolist() for k, v in infos.items()} == {
            k: [single_infos[a][k] for a in agents] for k in single_infos[agents[0]]
        }
    rng = np.random.default_rng(0)
    episodes_ended = np.zeros(n_copies, dtype=int)
    copies_terminated = 0
    for _ in range(horizon):
        actions = sample_actions(batch.action_space, rng, (n_copies, batch.n_agents))
        out = batch.step(actions)
        copies_terminated += int(out.terminated.sum())
        for i, env in enumerate(singles):
            obs, rewards, terminations, truncations, step_infos = env.step(dict(zip(agents, actions[i])))
            assert as_bytes(out.rewards[i]) == as_bytes(np.array([rewards[a] for a in agents]))
            assert (bool(out.terminated[i]), bool(out.truncated[i])) == (
                terminations[agents[0]],
                truncations[agents[0]],
            )
            assert {k: v[i].tolist() for k, v in out.infos.items()} == {
                k: [step_infos[a][k] for a in agents] for k in step_infos[agents[0]]
            }
            final = np.stack([obs[a] for a in agents])
            if env.agents:  # the episode goes on
                assert i not in out.final_observations
                assert as_bytes(out.observations[i]) == as_bytes(final)
                assert batch.bits_sent()[i] == env.bits_sent()
                continue
            episodes_ended[i] += 1
            assert as_bytes(out.final_observations[i]) == as_bytes(final)
            # NaN equals NaN: a metric with nothing to measure is NaN, and one sent from another process is its own object
            assert same(out.final_metrics[i], env.metrics()), (out.final_metrics[i], env.metrics())
            next_obs, next_infos = env.reset()  # no seed: the copy's own stream goes on
            assert as_bytes(out.observations[i]) == as_bytes(np.stack([next_obs[a] for a in agents]))
            assert {k: v.tolist() for k, v in out.reset_infos[i].items()} == {
                k: [next_infos[a][k] for a in agents] for k in next_infos[agents[0]]
            }
            assert batch.bits_sent()[i] == env.bits_sent()  # the new episode's (RendezvousMapping sends at reset)
    assert (episodes_ended >= 2).all(), episodes_ended  # the automatic resets were exercised
    if some_terminate and kwargs.get("scene") == "neighborhood" and not kwargs.get("miss_probability"):
        assert copies_terminated > 0  # a perfect channel tells the IDs apart in a few steps: episodes terminate
    return singles
