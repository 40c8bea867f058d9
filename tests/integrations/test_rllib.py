"""Every registered env in RLlib (``make test-rllib``): ``register_all()`` puts each id into ray.tune's registry,
and one PPO training iteration on the new API stack, with one policy shared by all robots, runs and updates it."""

from __future__ import annotations

import numpy as np
import pytest
import ray
import torch
from gymnasium import spaces
from ray.rllib.algorithms.ppo import PPOConfig
from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec
from ray.rllib.core.rl_module.rl_module import RLModuleSpec
from ray.tune.registry import ENV_CREATOR, _global_registry

import mrcomm_env
from mrcomm_env.integrations.rllib import env_creator, register_all

ENV_IDS = mrcomm_env.env_ids()
SHORT = {"max_cycles": 8}
TRAIN_BATCH = 64  # env steps per iteration: a few episodes of 8 steps


@pytest.fixture(scope="module")
def ray_local():
    # two CPUs (the CI machine has two), no dashboard, the node on loopback only
    ray.init(num_cpus=2, include_dashboard=False, _node_ip_address="127.0.0.1", log_to_driver=False)
    register_all()
    yield
    ray.shutdown()


def test_register_all_registers_full_and_short_names():
    names = register_all()
    expected = set(ENV_IDS) | {i.split("/", 1)[1] for i in ENV_IDS}
    assert set(names) == expected
    for name in expected:
        assert _global_registry.contains(ENV_CREATOR, name)


def test_registered_creator_passes_env_config_to_the_env():
    register_all()
    env = _global_registry.get(ENV_CREATOR, "MapSync-v0")({"n_robots": 3, "max_cycles": 4})
    observations, _ = env.reset(seed=0)
    assert sorted(observations) == ["robot_0", "robot_1", "robot_2"]
    for _ in range(4):
        actions = {a: env.action_space[a].sample() for a in observations}
        observations, _, terminated, truncated, _ = env.step(actions)
    assert terminated["__all__"] or truncated["__all__"]


def test_multibinary_actions_are_offered_as_binary_multidiscrete():
    env = env_creator("MultiHop-v0")(SHORT)
    space = env.action_space["robot_0"]
    bare = mrcomm_env.make("MultiHop-v0").action_space("robot_0")
    assert isinstance(space, spaces.MultiDiscrete) and space.shape == bare.shape and (space.nvec == 2).all()
    observations, _ = env.reset(seed=0)
    env.step({a: env.action_space[a].sample() for a in observations})  # the env accepts what RLlib samples


def test_unknown_env_id_names_the_valid_ids():
    with pytest.raises(ValueError, match="MapSync-v0"):
        env_creator("NoSuchEnv-v0")


def shared_policy_ppo(env_id: str):
    return (
        PPOConfig()
        .environment(env_id, env_config=SHORT)
        .env_runners(num_env_runners=0)
        .multi_agent(policies={"shared"}, policy_mapping_fn=lambda agent_id, *args, **kwargs: "shared")
        .rl_module(
            rl_module_spec=MultiRLModuleSpec(
                rl_module_specs={"shared": RLModuleSpec(model_config={"fcnet_hiddens": [32, 32]})}
            )
        )
        .training(train_batch_size_per_learner=TRAIN_BATCH, minibatch_size=32, num_epochs=1)
        .debugging(seed=0)
    )


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_one_ppo_iteration_with_a_shared_policy(ray_local, env_id):
    config = shared_policy_ppo(env_id)
    assert config.enable_rl_module_and_learner and config.enable_env_runner_and_connector_v2  # new API stack
    algo = config.build_algo()
    try:
        before = {k: v.clone() for k, v in algo.get_module("shared").state_dict().items()}
        result = algo.train()
        after = algo.get_module("shared").state_dict()
    finally:
        algo.stop()
    n_agents = len(mrcomm_env.make(env_id).possible_agents)
    assert result["env_runners"]["num_env_steps_sampled"] >= TRAIN_BATCH
    learner = result["learners"]["shared"]
    assert set(result["learners"]) == {"shared", "__all_modules__"}  # one policy for every robot
    # every robot's step trains the one shared module
    assert learner["num_module_steps_trained"] >= TRAIN_BATCH * n_agents
    assert np.isfinite(learner["total_loss"]) and np.isfinite(learner["entropy"])
    assert any(not torch.equal(before[k], after[k]) for k in before), "the iteration did not update the policy"
