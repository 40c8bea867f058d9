"""Every registered env in TorchRL (``make test-torchrl``): the plain ``PettingZooWrapper`` and our ``make_env``
pass ``check_env_specs``, a ``Collector`` (formerly ``SyncDataCollector``) with a random policy collects across
episode boundaries, the action mask reaches the sampler, and broken infos are caught."""

from __future__ import annotations

import numpy as np
import pytest
import torch

# torchrl 0.14 has only the new name Collector for the single-process SyncDataCollector
from torchrl.collectors import Collector
from torchrl.envs import PettingZooWrapper
from torchrl.envs.utils import check_env_specs
from torchrl.modules import RandomPolicy

import mrcomm_env
from mrcomm_env.integrations import ActionMaskInInfos
from mrcomm_env.integrations.torchrl import GROUP, make_env

ENV_IDS = mrcomm_env.env_ids()
# short episodes, so a 2-batch collection crosses several resets on every env
SHORT = {"max_cycles": 6}


def reference_infos(env_id: str, steps: int = 3):
    """Infos of the bare PettingZoo env at reset and at each of ``steps`` random steps."""
    env = mrcomm_env.make(env_id, **SHORT)
    _, infos = env.reset(seed=0)
    out = [infos]
    for _ in range(steps):
        actions = {a: env.action_space(a).sample() for a in env.agents}
        out.append(env.step(actions)[-1])
    return out


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_plain_pettingzoo_wrapper_passes_check_env_specs(env_id):
    env = PettingZooWrapper(mrcomm_env.make(env_id, **SHORT), return_state=True, seed=0)
    check_env_specs(env, seed=0)
    assert list(env.group_map) == [GROUP]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_infos_are_numbers_with_the_same_keys_at_reset_and_step(env_id):
    # TorchRL builds its info spec from the reset infos alone; a key that appears later, or a value that is not
    # one number, breaks every rollout. This checks the contract itself, not only what TorchRL tolerates.
    all_infos = reference_infos(env_id)
    keys = set(next(iter(all_infos[0].values())))
    for infos in all_infos:
        for info in infos.values():
            assert set(info) == keys
            assert all(isinstance(v, float) for v in info.values())


class _InfoKeyAppearsAtStep(ActionMaskInInfos):
    def step(self, actions):
        out = super().step(actions)
        for info in out[-1].values():
            info["late_key"] = 1.0
        return out


class _InfoValueIsText(ActionMaskInInfos):
    def step(self, actions):
        out = super().step(actions)
        for info in out[-1].values():
            info[next(iter(info))] = "text"
        return out


@pytest.mark.parametrize("broken", [_InfoKeyAppearsAtStep, _InfoValueIsText])
def test_check_env_specs_catches_infos_that_break_the_contract(broken):
    # the control for the tests above: the same check must fail when the infos change shape between reset and step
    env = PettingZooWrapper(broken(mrcomm_env.make("MapSync-v0", **SHORT)), return_state=True, seed=0)
    with pytest.raises(TypeError):  # torchrl 0.14: writing an unknown key into the info td, or torch.tensor("text")
        check_env_specs(env, seed=0)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_make_env_collects_random_frames_across_episodes(env_id):
    env = make_env(env_id, seed=1, **SHORT)
    check_env_specs(env, seed=1)
    n_agents = len(env.group_map[GROUP])
    frames_per_batch = 10
    collector = Collector(
        env, RandomPolicy(env.full_action_spec), frames_per_batch=frames_per_batch, total_frames=2 * frames_per_batch
    )
    batches = list(collector)
    collector.shutdown()
    assert len(batches) == 2
    data = torch.cat(batches)
    assert data.batch_size == torch.Size([2 * frames_per_batch])
    next_group = data["next", GROUP]
    assert next_group["reward"].shape == (2 * frames_per_batch, n_agents, 1)
    assert torch.isfinite(next_group["reward"]).all()
    # 20 frames of 6-step episodes: the collector reset the env at least twice and stepped on
    assert data["next", "done"].sum() >= 20 // SHORT["max_cycles"]
    # every info key of the env arrives, one float per robot
    expected_keys = {k for k in reference_infos(env_id, steps=0)[0]["robot_0"] if not k.startswith("action_mask_")}
    assert set(next_group["info"].keys()) == expected_keys
    assert data["next", "state"].shape[-1] == mrcomm_env.make(env_id).state_space.shape[0]


def test_action_mask_reaches_the_random_policy():
    # RendezvousMapping-v0 masks empty candidate slots; with the mask in the action spec the random policy
    # only ever takes feasible actions, which the env confirms through its own info ``action_feasible``
    env = make_env("RendezvousMapping-v0", seed=3, n_vehicles=3, n_landmarks=4, k_candidates=5, **SHORT)
    assert ("robot", "action_mask") in env.observation_spec.keys(True, True)
    data = env.rollout(3 * SHORT["max_cycles"], break_when_any_done=False)
    masks = data[GROUP, "action_mask"]
    assert (~masks).any(), "the configuration must leave some slots empty, or the mask is not exercised"
    taken = data[GROUP, "action"]
    assert masks.gather(-1, taken.unsqueeze(-1)).all()
    assert (data["next", GROUP, "info", "action_feasible"] == 1).all()
    # and the mask is the env's own
    bare = mrcomm_env.make("RendezvousMapping-v0", n_vehicles=3, n_landmarks=4, k_candidates=5, **SHORT)
    bare.reset(seed=3)
    np.testing.assert_array_equal(masks[0].numpy(), bare.action_masks())


def test_multibinary_actions_stay_binary_vectors():
    env = make_env("MultiHop-v0", seed=0, **SHORT)
    n = len(env.group_map[GROUP])
    action = env.full_action_spec[GROUP, "action"]
    assert action.shape == (n, n - 1)
    sample = action.rand()
    assert set(sample.unique().tolist()) <= {0, 1}


def test_one_hot_actions_on_request():
    env = make_env("MapSync-v0", categorical_actions=False, seed=0, **SHORT)
    check_env_specs(env, seed=0)
    assert env.full_action_spec[GROUP, "action"].shape[-1] == mrcomm_env.make("MapSync-v0").action_space("robot_0").n


def test_unknown_env_id_names_the_valid_ids():
    with pytest.raises(ValueError, match="MapSync-v0"):
        make_env("NoSuchEnv-v0")
