"""Warm start (``mrcomm train --init-from baseline:NAME``): the cloned policy takes the teacher's decisions."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO
from test_adding_an_environment import ENTRY, ENV_ID

from mrcomm_agents.training import make_training_env
from mrcomm_agents.warm_start import clone
from mrcomm_env.core.policy import Policy
from mrcomm_env.experiments.cli import main
from mrcomm_env.registry import register, unregister

torch.set_num_threads(1)


class BroadcastWhenBehind(Policy):
    """Broadcast exactly when the robot knows no more of the tokens than the team on average: a decision
    that is a function of the observation (own share, team share), so a policy can learn it exactly."""

    name = "broadcast_when_behind"

    def act(self, observations, views):
        return {agent: int(obs[0] <= obs[1]) for agent, obs in observations.items()}


@pytest.fixture
def gossip():
    register(ENV_ID, ENTRY)
    try:
        yield ENV_ID
    finally:
        unregister(ENV_ID)


def _agreement(model, venv, teacher, env_id, seeds) -> float:
    from mrcomm_env.registry import make

    agree = total = 0
    for seed in seeds:
        env = make(env_id, n_robots=8, p_link=0.3)
        observations, _ = env.reset(seed=seed)
        teacher.reset(env.local_views(), seed)
        while env.agents:
            agents = list(observations)
            obs = np.stack([observations[a] for a in agents])
            chosen, _ = model.predict(venv.normalize_obs(obs), deterministic=True)
            labels = teacher.act(observations, env.local_views())
            agree += sum(int(chosen[i]) == labels[a] for i, a in enumerate(agents))
            total += len(agents)
            observations, *_ = env.step(labels)
    return agree / total


def test_cloning_takes_the_teachers_decisions_on_held_out_episodes(gossip):
    from stable_baselines3.common.vec_env import VecNormalize

    from mrcomm_agents.training import TrainConfig

    config = TrainConfig(env_id=gossip, env_kwargs={"n_robots": 8, "p_link": 0.3}, n_envs=1, seed=0)
    venv = VecNormalize(make_training_env(config, 0), norm_obs=True, norm_reward=True)
    model = PPO("MlpPolicy", venv, seed=0, device="cpu", n_steps=32, policy_kwargs={"net_arch": [32, 32]})
    teacher = BroadcastWhenBehind()
    before = _agreement(model, venv, teacher, gossip, seeds=[900, 901])
    report = clone(model, venv, teacher, gossip, config.env_kwargs, seed=0)
    after = _agreement(model, venv, teacher, gossip, seeds=[900, 901])
    assert report.agreement[0] == 1.0  # round 0 rolls out the teacher itself
    assert report.samples > 0 and after >= 0.95 and after > before, (before, after, report)


def test_init_from_names_a_baseline_or_is_refused_before_any_work(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", "MultiHop-v0", "--init-from", "baseline:nope", "--timesteps", "10", "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "init_from" in err and "age_aware" in err and not out.exists()


def test_a_warm_started_run_records_its_teacher(tmp_path):
    out = tmp_path / "run"
    argv = ["train", "ChannelAssociation-v0", "--init-from", "baseline:id_bits", "--timesteps", "64", "--quiet"]
    argv += ["--param", "max_cycles=8", "--out", str(out)]
    assert main(argv) == 0
    record = json.loads((out / "warm_start.json").read_text())
    assert record["teacher"] == "baseline:id_bits" and record["samples"] > 0
    assert json.loads((out / "config.json").read_text())["init_from"] == "baseline:id_bits"


def test_a_maskable_clone_takes_the_teachers_decisions_over_the_allowed_actions():
    """MaskablePPO's clone is fitted and sampled over the allowed actions only (``action_masks``): on held-out
    episodes of a small RendezvousMapping team its deterministic choices are mostly ``paper_protocol``'s, from none
    before, and the fit stays finite (an allowed action never has log-probability −∞)."""
    from sb3_contrib import MaskablePPO
    from stable_baselines3.common.vec_env import VecNormalize

    from mrcomm_agents.training import TrainConfig
    from mrcomm_baselines import make_policy
    from mrcomm_env.registry import make

    env_id, kwargs = "RendezvousMapping-v0", {"n_vehicles": 3, "n_landmarks": 12, "k_candidates": 5, "max_cycles": 8}
    config = TrainConfig(env_id=env_id, algo="maskable_ppo", env_kwargs=kwargs, n_envs=1)
    venv = VecNormalize(make_training_env(config, 0), norm_obs=True, norm_reward=True)
    model = MaskablePPO("MlpPolicy", venv, seed=0, device="cpu", n_steps=16, policy_kwargs={"net_arch": [32, 32]})
    teacher = make_policy(env_id, "paper_protocol")

    def agreement() -> float:
        agree = total = 0
        for seed in (900, 901, 902):
            env = make(env_id, **kwargs)
            observations, _ = env.reset(seed=seed)
            teacher.reset(env.local_views(), seed)
            while env.agents:
                agents, masks = list(observations), env.action_masks()
                obs = venv.normalize_obs(np.stack([observations[a] for a in agents]))
                chosen, _ = model.predict(obs, deterministic=True, action_masks=masks)
                labels = teacher.act(observations, env.local_views())
                assert all(masks[i, int(chosen[i])] for i in range(len(agents)))
                agree += sum(int(chosen[i]) == int(labels[a]) for i, a in enumerate(agents))
                total += len(agents)
                observations, *_ = env.step(labels)
        return agree / total

    before = agreement()
    clone(model, venv, teacher, env_id, kwargs, seed=0)
    assert all(torch.isfinite(p).all() for p in model.policy.parameters())
    after = agreement()
    assert after >= 0.85 and after > before, (before, after)


def test_critic_warmup_trains_only_the_critic_then_releases_the_actor():
    import gymnasium as gym

    from mrcomm_agents.warm_start import CriticWarmup, critic_parameters

    model = PPO("MlpPolicy", gym.make("CartPole-v1"), seed=0, device="cpu", n_steps=64, batch_size=64, n_epochs=2)
    critic = critic_parameters(model.policy)
    names = {id(p): n for n, p in model.policy.named_parameters()}
    assert {names[i].split(".")[-2] for i in critic} >= {"value_net"}  # the value head and its layers
    before = {n: p.detach().clone() for n, p in model.policy.named_parameters()}
    model.learn(128, callback=CriticWarmup(10**9))
    changed = {n for n, p in model.policy.named_parameters() if not torch.equal(p, before[n])}
    assert changed and changed == {names[i] for i in critic if names[i] in changed}  # the critic only
    assert all(p.requires_grad for p in model.policy.parameters())  # released when training ends
    actor = {n for n, p in model.policy.named_parameters() if id(p) not in critic}
    model.learn(128, callback=CriticWarmup(0), reset_num_timesteps=False)
    assert any(not torch.equal(p, before[n]) for n, p in model.policy.named_parameters() if n in actor)


def test_freeze_normalization_keeps_the_statistics_the_clone_was_fitted_with(tmp_path, capsys):
    from mrcomm_agents.artifacts import STATISTICS_FILE, load_statistics

    counts = {}
    for frozen in (False, True):
        config = tmp_path / f"config-{frozen}.json"
        config.write_text(json.dumps({"ppo": {"freeze_normalization": frozen, "eval_episodes": 0}}))
        out = tmp_path / f"run-{frozen}"
        argv = ["train", "ChannelAssociation-v0", "--init-from", "baseline:id_bits", "--timesteps", "128", "--quiet"]
        argv += ["--param", "max_cycles=8", "--config", str(config), "--out", str(out)]
        assert main(argv) == 0
        counts[frozen] = load_statistics(out / STATISTICS_FILE).obs_rms.count
    # the same seed clones from the same rollouts; only the unfrozen run goes on counting PPO's observations
    assert counts[False] - counts[True] >= 128, counts


def test_freeze_normalization_without_a_warm_start_is_refused(tmp_path, capsys):
    config = tmp_path / "config.json"
    config.write_text(json.dumps({"ppo": {"freeze_normalization": True}}))
    out = tmp_path / "run"
    assert (
        main(["train", "ChannelAssociation-v0", "--config", str(config), "--timesteps", "64", "--out", str(out)]) == 2
    )
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "freeze_normalization" in err and "init_from" in err and not out.exists()
