"""Every registered env in TorchRL (``make test-torchrl``): the plain ``PettingZooWrapper`` and our ``make_env``
pass ``check_env_specs``, a ``Collector`` (formerly ``SyncDataCollector``) with a random policy collects across
episode boundaries, the action mask reaches the sampler, and broken infos are caught."""

from __future__ import annotations

import os

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
from mrcomm_env.integrations.torchrl import GROUP, make_batched_env, make_env

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


# ----------------------------------------------------------------------------------- the batched env
#: small teams, so that every env's whole episodes fit in a few seconds; MultiHop's 3×3 grid keeps MultiBinary actions
BATCHED_ARGS = {"MultiHop-v0": {"grid_side": 3}, "mrcomm/MultiHop-v0": {"grid_side": 3}}


def batched_args(env_id: str) -> dict:
    return {**SHORT, **BATCHED_ARGS.get(env_id, {})}


def single_copy_trajectory(env_id: str, kwargs: dict, seed: int, actions: np.ndarray):
    """The PettingZoo env seeded ``seed`` stepped with ``actions`` (T, N, …), reset without a seed after each episode:
    per step the observation acted on, the mask, the infos, then the next observation, rewards and end flags."""
    env = mrcomm_env.make(env_id, **kwargs)
    agents = env.possible_agents
    observations, infos = env.reset(seed=seed)
    out = []
    for action in actions:
        masks = env.action_masks() if hasattr(env, "action_masks") else None
        before = (np.stack([observations[a] for a in agents]), masks, infos)
        observations, rewards, terminated, truncated, step_infos = env.step(dict(zip(agents, action)))
        ended = terminated[agents[0]] or truncated[agents[0]]
        after = (
            np.stack([observations[a] for a in agents]),
            np.array([rewards[a] for a in agents]),
            terminated[agents[0]],
            truncated[agents[0]],
            step_infos,
        )
        out.append((before, after))
        infos = step_infos
        if ended:
            observations, infos = env.reset()
    return out


def assert_infos_equal(columns, infos, agents):
    for key in columns.keys():
        expected = np.array([infos[a][key] for a in agents], dtype=np.float32)
        np.testing.assert_array_equal(columns[key].numpy(), expected, err_msg=key)


def assert_copies_are_single_envs(env, data, env_id: str, kwargs: dict, seed: int) -> None:
    """Every copy i of the rollout ``data`` equals the PettingZoo env seeded ``seed + i`` given the same actions."""
    agents = mrcomm_env.make(env_id, **kwargs).possible_agents
    for i in range(data.batch_size[0]):
        copy = data[i]
        expected = single_copy_trajectory(env_id, kwargs, seed + i, copy[GROUP, "action"].numpy())
        for t, ((obs, masks, infos), (next_obs, rewards, terminated, truncated, next_infos)) in enumerate(expected):
            step = copy[t]
            np.testing.assert_array_equal(step[GROUP, "observation"].numpy(), obs, err_msg=f"copy {i} step {t}")
            np.testing.assert_array_equal(step["state"].numpy(), obs.reshape(-1))
            assert_infos_equal(step[GROUP, "info"], infos, agents)
            if masks is not None:
                np.testing.assert_array_equal(step[GROUP, "action_mask"].numpy(), masks)
            nxt = step["next"]
            np.testing.assert_array_equal(nxt[GROUP, "observation"].numpy(), next_obs)
            np.testing.assert_array_equal(nxt[GROUP, "reward"].numpy()[:, 0], rewards.astype(np.float32))
            assert bool(nxt["terminated"]) == terminated and bool(nxt["truncated"]) == truncated
            assert bool(nxt["done"]) == (terminated or truncated)
            assert nxt[GROUP, "done"].all() == (terminated or truncated)
            assert_infos_equal(nxt[GROUP, "info"], next_infos, agents)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_batched_copy_i_is_the_pettingzoo_env_seeded_s_plus_i(env_id):
    m, seed, steps = 3, 11, 3 * SHORT["max_cycles"] + 2  # three episodes and a bit: automatic resets in between
    env = make_batched_env(env_id, m, seed=seed, **batched_args(env_id))
    check_env_specs(env, seed=seed)  # set_seed(seed) again before its rollout, which reseeds every copy
    env.set_seed(seed)
    data = env.rollout(steps, RandomPolicy(env.full_action_spec), break_when_any_done=False)
    assert data.batch_size == (m, steps)
    assert_copies_are_single_envs(env, data, env_id, batched_args(env_id), seed)


@pytest.mark.parametrize("env_workers", [1, 3])
def test_batched_copies_that_end_apart_stay_single_envs(env_workers):
    # episodes that end by themselves at different steps: the rollout's resets name some copies and not others, and
    # a copy whose next episode began at its last step must not be reset a second time; the copies step in one
    # process or in three (core.sharded), with the same numbers
    env_id, seed, steps = "RendezvousMapping-v0", 11, 120
    kwargs = {"n_vehicles": 3, "n_landmarks": 4, "k_candidates": 5, "max_cycles": 40}
    env = make_batched_env(env_id, 4, seed=seed, env_workers=env_workers, **kwargs)
    assert getattr(env.batch, "workers", 1) == env_workers
    data = env.rollout(steps, break_when_any_done=False)  # env.rand_action: feasible actions only
    ends = [tuple(data["next", "done"][i, :, 0].nonzero().flatten().tolist()) for i in range(4)]
    assert len(set(ends)) > 1 and all(len(e) >= 2 for e in ends), f"the copies must end apart, and often: {ends}"
    assert_copies_are_single_envs(env, data, env_id, kwargs, seed)


def test_batched_partial_reset_restarts_only_the_named_copy():
    env_id, seed = "MapSync-v0", 5
    env = make_batched_env(env_id, 3, seed=seed, max_cycles=8)
    td = env.reset()
    actions = [env.full_action_spec.rand() for _ in range(3)]
    for action in actions:
        td = env.step(td.update(action))
        td = td["next"].exclude("reward", "done", "terminated", "truncated", (GROUP, "reward"))
    held = td[GROUP, "observation"].clone()
    flags = torch.tensor([[False], [True], [False]])
    reset = env.reset(td.update({"_reset": flags}))
    # copies 0 and 2 carry on untouched; copy 1 is its single env reset (no seed) after the same three steps
    torch.testing.assert_close(reset[GROUP, "observation"][[0, 2]], held[[0, 2]], rtol=0, atol=0)
    single = mrcomm_env.make(env_id, max_cycles=8)
    single.reset(seed=seed + 1)
    for action in actions:
        single.step(dict(zip(single.possible_agents, action[GROUP, "action"][1].tolist())))
    first, _ = single.reset()
    np.testing.assert_array_equal(
        reset[GROUP, "observation"][1].numpy(), np.stack([first[a] for a in single.possible_agents])
    )
    assert not reset["done"].any()


def test_batched_collector_crosses_episodes_with_the_mask_in_the_action_spec():
    kwargs = {"n_vehicles": 3, "n_landmarks": 4, "k_candidates": 5, **SHORT}
    env = make_batched_env("RendezvousMapping-v0", 4, seed=2, **kwargs)
    collector = Collector(env, RandomPolicy(env.full_action_spec), frames_per_batch=4 * 10, total_frames=4 * 20)
    data = torch.cat([batch for batch in collector], dim=-1)
    collector.shutdown()
    assert data.batch_size == (4, 20)
    assert data["next", "done"].sum() >= 4 * (20 // SHORT["max_cycles"])
    assert torch.isfinite(data["next", GROUP, "reward"]).all()
    # RandomPolicy samples from a clone of the spec it was given, so the live mask reaches env.rand_action only
    data = env.rollout(20, break_when_any_done=False)
    masks, taken = data[GROUP, "action_mask"], data[GROUP, "action"]
    assert (~masks).any(), "the configuration must leave some slots empty, or the mask is not exercised"
    assert masks.gather(-1, taken.unsqueeze(-1)).all()
    assert (data["next", GROUP, "info", "action_feasible"] == 1).all()


def test_a_closed_batched_env_ends_its_processes_and_begins_new_copies_when_reset_again():
    env = make_batched_env("AsyncCL-v0", 3, seed=5, env_workers=2, n_robots=3, max_cycles=6)
    first = env.reset()[GROUP, "observation"].clone()
    (worker,) = env.batch.worker_pids
    env.close()
    with pytest.raises(ProcessLookupError):  # ended and reaped
        os.kill(worker, 0)
    env.set_seed(5)  # new copies, seeded as the first ones were
    torch.testing.assert_close(env.reset()[GROUP, "observation"], first, rtol=0, atol=0)
    assert env.batch.worker_pids != [worker]
    env.close()


def test_batched_one_hot_actions_and_render():
    env = make_batched_env("MapSync-v0", 2, categorical_actions=False, seed=0, **SHORT)
    check_env_specs(env, seed=0)
    n_actions = mrcomm_env.make("MapSync-v0").action_space("robot_0").n
    assert env.full_action_spec[GROUP, "action"].shape == (2, 2, n_actions)
    env.rollout(3)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[-1] == 3


def test_batched_env_refuses_bad_arguments_at_construction():
    with pytest.raises(ValueError, match="num_envs"):
        make_batched_env("MapSync-v0", 0)
    with pytest.raises(ValueError, match="n_robots"):
        make_batched_env("MapSync-v0", 2, n_robots=-1)
    with pytest.raises(ValueError, match="num_envs.*memory budget"):
        make_batched_env("MapSync-v0", 10**9)
    with pytest.raises(ValueError, match="MapSync-v0"):
        make_batched_env("NoSuchEnv-v0", 2)
    with pytest.raises(ValueError, match="MultiBinary actions.*'mask_unheld'"):
        make_batched_env("MultiHop-v0", 2, grid_side=3, mask_unheld=True)
    for env_workers in (0, 3, True):
        with pytest.raises(ValueError, match=r"'env_workers' must be None or an integer in \[1, num_envs\]"):
            make_batched_env("MapSync-v0", 2, env_workers=env_workers)
