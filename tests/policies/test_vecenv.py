"""The parameter-shared VecEnv against its real consumers: SB3's PPO, VecMonitor, VecNormalize, VecCheckNan and
sb3-contrib's MaskablePPO, with expected values taken from the raw PettingZoo envs stepped in lockstep."""

from __future__ import annotations

import functools
import warnings

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
torch = pytest.importorskip("torch")
torch.set_num_threads(1)

from gymnasium import spaces  # noqa: E402
from gymnasium.wrappers import RecordEpisodeStatistics  # noqa: E402
from pettingzoo import ParallelEnv  # noqa: E402
from pettingzoo.utils.wrappers import BaseParallelWrapper  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.env_checker import _check_obs, _check_unsupported_spaces  # noqa: E402
from stable_baselines3.common.monitor import Monitor  # noqa: E402
from stable_baselines3.common.vec_env import VecCheckNan, VecMonitor, VecNormalize  # noqa: E402

import mrcomm_env  # noqa: E402
from mrcomm_agents import AgentSlotVecEnv, make_vec_env  # noqa: E402
from mrcomm_agents.vecenv import ACTION_MASK_INFO_KEY  # noqa: E402

#: the base env's episode-length argument; one place to change if it is renamed (e.g. to max_cycles)
HORIZON_ARG = "max_cycles"


def channel_kwargs(n_robots: int = 3, horizon: int = 6) -> dict:
    """ChannelAssociation-v0, small field: episodes end by termination mostly, by truncation sometimes."""
    return {"n_robots": n_robots, HORIZON_ARG: horizon}


def multihop_kwargs(horizon: int = 8) -> dict:
    """MultiHop-v0 on a 2×2 grid in its v0 layout: four agents with Box actions, episodes end by truncation."""
    return {"grid_side": 2, "layout": "absolute", HORIZON_ARG: horizon}


def random_actions(rng: np.random.Generator, space: spaces.Space, count: int) -> np.ndarray:
    if isinstance(space, spaces.Discrete):
        return rng.integers(space.start, space.start + space.n, size=count)
    return rng.uniform(space.low, space.high, size=(count, *space.shape)).astype(space.dtype)


def parameters(model) -> dict[str, torch.Tensor]:
    return {name: tensor.detach().clone() for name, tensor in model.policy.state_dict().items()}


def same_parameters(first: dict[str, torch.Tensor], second: dict[str, torch.Tensor]) -> bool:
    return first.keys() == second.keys() and all(torch.equal(first[name], second[name]) for name in first)


# ----------------------------------------------------------------------------- toy environments
class MaskedChoiceEnv(ParallelEnv):
    """Two agents pick one of four actions; a random subset (never empty) is allowed each step.

    The masks are published by ``action_masks()``; the env counts the actions taken against them.
    Reward 1 for the highest allowed action. Episodes are truncated after ``horizon`` steps.
    """

    metadata = {"name": "masked_choice"}
    N_ACTIONS = 4

    def __init__(self, horizon: int = 5):
        self.possible_agents = ["agent_0", "agent_1"]
        self.agents: list[str] = []
        self.render_mode = None
        self.horizon = horizon
        self.rng = np.random.default_rng()
        self.actions_taken = 0
        self.illegal_actions = 0
        self.closed = False
        self.calls = 0
        self._observation_space = spaces.Box(0.0, 1.0, shape=(self.N_ACTIONS + 1,), dtype=np.float32)
        self._action_space = spaces.Discrete(self.N_ACTIONS)

    def observation_space(self, agent):
        return self._observation_space

    def action_space(self, agent):
        return self._action_space

    def _draw_masks(self) -> None:
        masks = self.rng.random((len(self.possible_agents), self.N_ACTIONS)) < 0.4
        masks[np.arange(len(self.possible_agents)), self.rng.integers(0, self.N_ACTIONS, len(self.possible_agents))] = (
            True
        )
        self.masks = masks

    def _observations(self) -> dict:
        time_left = 1.0 - self.t / self.horizon
        return {
            agent: np.append(self.masks[i].astype(np.float32), np.float32(time_left))
            for i, agent in enumerate(self.possible_agents)
        }

    def _infos(self) -> dict:
        return {agent: {} for agent in self.possible_agents}

    def reset(self, seed=None, options=None):
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.agents = list(self.possible_agents)
        self.t = 0
        self._draw_masks()
        return self._observations(), self._infos()

    def step(self, actions):
        rewards = {}
        for i, agent in enumerate(self.agents):
            action = int(actions[agent])
            self.actions_taken += 1
            self.illegal_actions += not self.masks[i, action]
            rewards[agent] = float(action == np.flatnonzero(self.masks[i]).max())
        self.t += 1
        self._draw_masks()
        truncated = self.t >= self.horizon
        observations, infos = self._observations(), self._infos()
        terminations = dict.fromkeys(self.agents, False)
        truncations = dict.fromkeys(self.agents, truncated)
        if truncated:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def action_masks(self) -> np.ndarray:
        return self.masks.copy()

    def count_call(self, increment: int = 1) -> int:
        self.calls += increment
        return self.calls

    def close(self):
        self.closed = True


class InfoMaskedChoiceEnv(MaskedChoiceEnv):
    """The same game, but the masks travel only in the infos (``info["action_mask"]``)."""

    action_masks = None  # no method: the VecEnv must read the infos

    def _infos(self) -> dict:
        return {agent: {ACTION_MASK_INFO_KEY: self.masks[i].copy()} for i, agent in enumerate(self.possible_agents)}


class StaggeredEnv(ParallelEnv):
    """Agents live over ``spans[agent] = (join_step, leave_step)``; one leaving at the horizon is truncated.

    ``env.agents`` after t steps holds the agents with join_step ≤ t < leave_step, so agents can be absent at
    reset, join mid-episode and leave early. Observation (step count, agent number); reward 1 per action.
    """

    metadata = {"name": "staggered"}

    def __init__(self, spans: dict[str, tuple[int, int]], horizon: int):
        self.possible_agents = list(spans)
        self.spans = spans
        self.horizon = horizon
        self.agents: list[str] = []
        self.render_mode = None
        self._observation_space = spaces.Box(0.0, 100.0, shape=(2,), dtype=np.float32)
        self._action_space = spaces.Discrete(2)

    def observation_space(self, agent):
        return self._observation_space

    def action_space(self, agent):
        return self._action_space

    def _live(self) -> list[str]:
        return [agent for agent, (join, leave) in self.spans.items() if join <= self.t < leave]

    def _observation(self, agent: str) -> np.ndarray:
        return np.array([self.t, 1 + self.possible_agents.index(agent)], dtype=np.float32)

    def reset(self, seed=None, options=None):
        self.t = 0
        self.agents = self._live()
        return {agent: self._observation(agent) for agent in self.agents}, {agent: {} for agent in self.agents}

    def step(self, actions):
        assert set(actions) == set(self.agents), (sorted(actions), self.agents)
        acting = self.agents
        self.t += 1
        self.agents = self._live()
        leaving = [agent for agent in acting if agent not in self.agents]
        observed = set(acting) | set(self.agents)
        observations = {agent: self._observation(agent) for agent in observed}
        rewards = dict.fromkeys(acting, 1.0)
        truncations = {agent: agent in leaving and self.t >= self.horizon for agent in acting}
        terminations = {agent: agent in leaving and not truncations[agent] for agent in acting}
        return observations, rewards, terminations, truncations, {agent: {} for agent in observed}


class TaggedWrapper(BaseParallelWrapper):
    """A PettingZoo wrapper that changes nothing, to be found by ``env_is_wrapped``."""


class UnevenSpacesEnv(MaskedChoiceEnv):
    def __init__(self, uneven: str):
        super().__init__()
        self.uneven = uneven

    def observation_space(self, agent):
        if self.uneven == "observation" and agent == "agent_1":
            return spaces.Box(0.0, 1.0, shape=(3,), dtype=np.float32)
        if self.uneven == "not_box":
            return spaces.Discrete(3)
        return super().observation_space(agent)

    def action_space(self, agent):
        if self.uneven == "action" and agent == "agent_1":
            return spaces.Discrete(3)
        return super().action_space(agent)


# ----------------------------------------------------------------------------- layout, spaces and SB3 sanity
def test_slots_are_agents_of_copies_and_pass_sb3_sanity_checks():
    n_copies, n_robots, seed = 2, 3, 11
    venv = make_vec_env("ChannelAssociation-v0", n_envs=n_copies, seed=seed, **channel_kwargs(n_robots))
    raw = mrcomm_env.make("ChannelAssociation-v0", **channel_kwargs(n_robots))
    assert venv.num_envs == n_copies * n_robots
    assert venv.observation_space == raw.observation_space("robot_0")
    assert venv.action_space == spaces.Discrete(2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _check_unsupported_spaces(venv, venv.observation_space, venv.action_space) is False

    observations = venv.reset()
    assert observations.shape == (n_copies * n_robots, *venv.observation_space.shape)
    assert observations.dtype == np.float32
    for copy_index in range(n_copies):
        raw_observations, raw_infos = raw.reset(seed=seed + copy_index)
        for agent_index, agent in enumerate(raw.possible_agents):
            slot = copy_index * n_robots + agent_index
            _check_obs(observations[slot], venv.observation_space, "reset")
            np.testing.assert_array_equal(observations[slot], raw_observations[agent])
            assert venv.reset_infos[slot] == raw_infos[agent]

    checked = VecCheckNan(venv, raise_exception=True)
    rng = np.random.default_rng(0)
    for _ in range(20):
        observations, rewards, dones, infos = checked.step(random_actions(rng, venv.action_space, venv.num_envs))
        assert observations.shape == (venv.num_envs, *venv.observation_space.shape)
        assert rewards.shape == dones.shape == (venv.num_envs,) and dones.dtype == bool
        assert len(infos) == venv.num_envs
        for slot in range(venv.num_envs):
            _check_obs(observations[slot], venv.observation_space, "step")
            assert "bits_sent" in infos[slot]  # the env's own per-agent info travels with the slot
    venv.close()


@pytest.mark.parametrize("uneven", ["observation", "action", "not_box"])
def test_agents_with_different_spaces_are_refused(uneven):
    with pytest.raises(ValueError, match="observation|action"):
        AgentSlotVecEnv([functools.partial(UnevenSpacesEnv, uneven)])


def test_reused_instance_and_mismatched_copies_are_refused():
    shared = MaskedChoiceEnv()
    with pytest.raises(ValueError, match="same instance"):
        AgentSlotVecEnv([lambda: shared, lambda: shared])
    with pytest.raises(ValueError, match="possible agents"):
        AgentSlotVecEnv([MaskedChoiceEnv, functools.partial(StaggeredEnv, {"x": (0, 2)}, 2)])
    with pytest.raises(ValueError, match="at least one"):
        AgentSlotVecEnv([])


# ----------------------------------------------------------------------------- stepping against the raw env
def test_rewards_terminal_observations_and_truncation_match_raw_envs_in_lockstep():
    n_copies, n_robots, seed = 2, 3, 21
    kwargs = channel_kwargs(n_robots, horizon=6)
    venv = make_vec_env("ChannelAssociation-v0", n_envs=n_copies, seed=seed, **kwargs)
    raws = [mrcomm_env.make("ChannelAssociation-v0", **kwargs) for _ in range(n_copies)]
    agents = raws[0].possible_agents
    expected_observations = np.zeros((venv.num_envs, *venv.observation_space.shape), dtype=np.float32)
    for copy_index, raw in enumerate(raws):
        raw_observations, _ = raw.reset(seed=seed + copy_index)
        for agent_index, agent in enumerate(agents):
            expected_observations[copy_index * n_robots + agent_index] = raw_observations[agent]
    np.testing.assert_array_equal(venv.reset(), expected_observations)

    rng = np.random.default_rng(5)
    endings = {"terminated": 0, "truncated": 0}
    for _ in range(60):
        actions = random_actions(rng, venv.action_space, venv.num_envs)
        observations, rewards, dones, infos = venv.step(actions)
        for copy_index, raw in enumerate(raws):
            slots = range(copy_index * n_robots, (copy_index + 1) * n_robots)
            raw_actions = {agent: int(actions[slot]) for agent, slot in zip(agents, slots)}
            raw_observations, raw_rewards, terminations, truncations, raw_infos = raw.step(raw_actions)
            episode_over = not raw.agents
            for agent, slot in zip(agents, slots):
                assert rewards[slot] == np.float32(raw_rewards[agent])
                assert dones[slot] == episode_over
                assert infos[slot]["bits_sent"] == raw_infos[agent]["bits_sent"]
                assert infos[slot]["TimeLimit.truncated"] == (truncations[agent] and not terminations[agent])
                if episode_over:
                    np.testing.assert_array_equal(infos[slot]["terminal_observation"], raw_observations[agent])
                else:
                    assert "terminal_observation" not in infos[slot]
            if episode_over:
                endings["terminated" if terminations[agents[0]] else "truncated"] += 1
                raw_observations, raw_infos = raw.reset()  # auto-reset: no seed, the copy's stream goes on
                for agent, slot in zip(agents, slots):
                    assert venv.reset_infos[slot] == raw_infos[agent]
            for agent, slot in zip(agents, slots):
                np.testing.assert_array_equal(observations[slot], raw_observations[agent])
    # both kinds of ending occurred, so both flag values were checked
    assert endings["terminated"] > 0 and endings["truncated"] > 0, endings


def test_agents_leaving_joining_and_absent_become_padding():
    # robot_b leaves after 2 steps (terminated), robot_c joins at step 1 and leaves at 3,
    # robot_a leaves at the horizon 4 (truncated), which ends the episode
    spans = {"robot_a": (0, 4), "robot_b": (0, 2), "robot_c": (1, 3)}
    venv = VecMonitor(AgentSlotVecEnv([functools.partial(StaggeredEnv, spans, horizon=4)]))
    observations = venv.reset()
    np.testing.assert_array_equal(observations, [[0, 1], [0, 2], [0, 0]])
    assert venv.env_method("action_masks", indices=2)[0].all()

    # per step: observations after the step, dones, which slots are padding, which done slots are truncated
    expected = [
        ([[1, 1], [1, 2], [1, 3]], [False, False, True], [False, False, True], []),
        ([[2, 1], [0, 0], [2, 3]], [False, True, False], [False, False, False], []),
        ([[3, 1], [0, 0], [0, 0]], [False, False, True], [False, True, False], []),
        ([[0, 1], [0, 2], [0, 0]], [True, True, True], [False, True, True], [0]),
    ]
    terminal = {1: {2: [0, 0]}, 2: {1: [2, 2]}, 3: {2: [3, 3]}, 4: {0: [4, 1], 1: [0, 0], 2: [0, 0]}}
    for step, (expected_observations, expected_dones, padding, truncated) in enumerate(expected, start=1):
        observations, rewards, dones, infos = venv.step(np.zeros(3, dtype=np.int64))
        np.testing.assert_array_equal(observations, expected_observations)
        np.testing.assert_array_equal(dones, expected_dones)
        np.testing.assert_array_equal(rewards, [0.0 if is_padding else 1.0 for is_padding in padding])
        for slot in range(3):
            assert infos[slot].get("padding", False) == padding[slot]
            assert infos[slot]["TimeLimit.truncated"] == (slot in truncated)
            if slot in terminal.get(step, {}):
                np.testing.assert_array_equal(infos[slot]["terminal_observation"], terminal[step][slot])
            else:
                assert "terminal_observation" not in infos[slot]
    # copy statistics: 4 + 2 + 2 agent-steps over three agents; per-slot episodes counted by VecMonitor
    assert infos[0]["copy_episode"] == {"r": pytest.approx(8 / 3), "l": 4}
    assert venv.episode_count == 6


# ----------------------------------------------------------------------------- seeding
def test_seed_applies_at_the_next_reset_only():
    def rng_state(env) -> dict:
        return env.np_random.bit_generator.state

    make_copy = functools.partial(mrcomm_env.make, "ChannelAssociation-v0", **channel_kwargs(3))
    venv = AgentSlotVecEnv([make_copy, make_copy])
    raw = make_copy()
    venv.reset()
    states_in_use = [rng_state(env) for env in venv.envs]
    assert venv.seed(5) == [5, 5, 5, 6, 6, 6]
    assert [rng_state(env) for env in venv.envs] == states_in_use  # stored, not applied yet

    seeded = venv.reset()
    seeded_states = []
    for copy_index, env in enumerate(venv.envs):
        raw_observations, _ = raw.reset(seed=5 + copy_index)
        assert rng_state(env) == rng_state(raw)
        np.testing.assert_array_equal(
            seeded[3 * copy_index : 3 * copy_index + 3], np.stack(list(raw_observations.values()))
        )
        seeded_states.append(rng_state(env))
    assert seeded_states[0] != seeded_states[1]

    # the next reset is unseeded: each copy continues the stream its seed started
    venv.reset()
    for copy_index, env in enumerate(venv.envs):
        raw.reset(seed=5 + copy_index)
        raw.reset()
        assert rng_state(env) == rng_state(raw) != seeded_states[copy_index]


def test_options_reach_the_copies_at_the_next_reset():
    received = []

    class OptionsProbe(MaskedChoiceEnv):
        def reset(self, seed=None, options=None):
            received.append(options)
            return super().reset(seed, options)

    venv = AgentSlotVecEnv([OptionsProbe, OptionsProbe])
    venv.set_options([{"level": 1}, {"level": 2}])
    venv.reset()
    venv.reset()
    assert received == [{"level": 1}, {"level": 2}, None, None]
    with pytest.raises(ValueError, match="one dict per copy"):
        venv.set_options([{}] * venv.num_envs)


# ----------------------------------------------------------------------------- attributes and methods
def test_attributes_methods_and_wrappers_per_slot_with_indices():
    def wrapped_copy():
        return TaggedWrapper(MaskedChoiceEnv())

    venv = AgentSlotVecEnv([wrapped_copy, MaskedChoiceEnv, MaskedChoiceEnv])  # 3 copies × 2 agents
    venv.reset()
    assert venv.render_mode is None
    assert venv.get_attr("horizon") == [5] * 6
    assert venv.get_attr("horizon", indices=3) == [5]

    venv.set_attr("horizon", 7, indices=[3])  # slot 3 is agent 1 of copy 1: the whole copy changes
    assert venv.get_attr("horizon") == [5, 5, 7, 7, 5, 5]
    assert venv.get_attr("horizon", indices=[5, 2, -1]) == [5, 7, 5]
    assert venv.envs[1].horizon == 7 and venv.envs[0].horizon == 5

    assert venv.env_method("action_space", "agent_0", indices=[0, 1, 4]) == [spaces.Discrete(4)] * 3
    # a method runs once per copy, not once per slot, and its result is repeated for each slot of the copy
    assert venv.env_method("count_call", indices=[3, 2, 0]) == [1, 1, 1]
    assert venv.env_method("count_call", 10) == [11, 11, 11, 11, 10, 10]
    assert venv.env_method("count_call", increment=5, indices=-1) == [15]

    assert venv.has_attr("horizon") and not venv.has_attr("no_such_attribute")
    with pytest.raises(AttributeError):
        venv.get_attr("no_such_attribute")
    with pytest.raises(IndexError):
        venv.get_attr("horizon", indices=[6])

    assert venv.env_is_wrapped(TaggedWrapper) == [True, True, False, False, False, False]
    assert venv.env_is_wrapped(TaggedWrapper, indices=[1, 2]) == [True, False]
    assert venv.env_is_wrapped(Monitor) == [False] * 6
    assert venv.env_is_wrapped(RecordEpisodeStatistics, indices=0) == [False]

    venv.close()
    assert all(env.unwrapped.closed for env in venv.envs)


def test_action_masks_from_method_infos_or_all_allowed():
    venv = AgentSlotVecEnv([MaskedChoiceEnv, MaskedChoiceEnv])
    venv.seed(3)
    venv.reset()
    for _ in range(3):
        masks = venv.env_method("action_masks")
        assert len(masks) == 4 and all(mask.dtype == bool and mask.shape == (4,) for mask in masks)
        for slot, mask in enumerate(masks):
            np.testing.assert_array_equal(mask, venv.envs[slot // 2].masks[slot % 2])
        assert [mask.tolist() for mask in venv.env_method("action_masks", indices=[3, 0])] == [
            masks[3].tolist(),
            masks[0].tolist(),
        ]
        venv.step(np.array([np.flatnonzero(mask)[0] for mask in masks]))

    info_venv = AgentSlotVecEnv([InfoMaskedChoiceEnv])
    info_venv.reset()
    for _ in range(7):  # crosses an auto-reset: the masks then come from the reset infos
        masks = info_venv.env_method("action_masks")
        np.testing.assert_array_equal(np.stack(masks), info_venv.envs[0].masks)
        info_venv.step(np.array([np.flatnonzero(mask)[-1] for mask in masks]))
    assert info_venv.envs[0].illegal_actions == 0

    plain = make_vec_env("ChannelAssociation-v0", n_envs=1, seed=0, **channel_kwargs(3))
    plain.reset()
    assert plain.has_attr("action_masks")
    assert [mask.tolist() for mask in plain.env_method("action_masks")] == [[True, True]] * 3
    box_actions = make_vec_env("MultiHop-v0", n_envs=1, seed=0, **multihop_kwargs())
    assert not box_actions.has_attr("action_masks")


# ----------------------------------------------------------------------------- learning
def test_ppo_trains_and_is_deterministic_per_seed():
    def train(seed: int) -> tuple[dict, dict]:
        venv = make_vec_env("ChannelAssociation-v0", n_envs=2, **channel_kwargs(3))
        model = PPO("MlpPolicy", venv, seed=seed, n_steps=16, batch_size=32, n_epochs=2, device="cpu")
        initial = parameters(model)
        model.learn(total_timesteps=300)
        assert model.num_timesteps >= 300
        return initial, parameters(model)

    initial, trained = train(seed=7)
    _, trained_again = train(seed=7)
    _, trained_other_seed = train(seed=8)
    assert not same_parameters(initial, trained)
    assert same_parameters(trained, trained_again)
    assert not same_parameters(trained, trained_other_seed)


def test_vec_monitor_and_vec_normalize_wrap_it_for_ppo():
    n_robots, horizon = 4, 8
    venv = make_vec_env("MultiHop-v0", n_envs=2, **multihop_kwargs(horizon))
    monitored = VecMonitor(venv)
    normalized = VecNormalize(monitored, gamma=0.9)
    model = PPO("MlpPolicy", normalized, seed=3, n_steps=16, batch_size=32, n_epochs=2, gamma=0.9, device="cpu")
    model.learn(total_timesteps=256)

    # Box actions, episodes of exactly `horizon` steps; every slot is one monitored episode per copy episode
    assert monitored.episode_count > 0 and monitored.episode_count % n_robots == 0
    assert len(model.ep_info_buffer) == monitored.episode_count
    assert all(episode["l"] == horizon for episode in model.ep_info_buffer)
    assert normalized.obs_rms.count > model.num_timesteps

    # VecMonitor's per-slot return of a team-reward env equals the VecEnv's per-copy mean return
    normalized.reset()
    rng = np.random.default_rng(1)
    for _ in range(horizon):
        _, _, dones, infos = normalized.step(random_actions(rng, venv.action_space, venv.num_envs))
    assert dones.all()  # every episode lasts exactly `horizon` steps
    for slot in range(venv.num_envs):
        assert infos[slot]["episode"]["r"] == pytest.approx(infos[slot]["copy_episode"]["r"], rel=1e-5)
        assert infos[slot]["episode"]["l"] == infos[slot]["copy_episode"]["l"] == horizon
        assert infos[slot]["TimeLimit.truncated"]


def test_maskable_ppo_never_takes_a_masked_action():
    maskable = pytest.importorskip("sb3_contrib")

    def train(use_masking: bool):
        venv = AgentSlotVecEnv([MaskedChoiceEnv, MaskedChoiceEnv])
        model = maskable.MaskablePPO("MlpPolicy", venv, seed=4, n_steps=16, batch_size=32, n_epochs=2, device="cpu")
        model.learn(total_timesteps=256, use_masking=use_masking)
        return venv, model

    venv, model = train(use_masking=True)
    taken = sum(venv.get_attr("actions_taken", indices=[0, 2]))
    assert taken >= 256
    assert sum(venv.get_attr("illegal_actions", indices=[0, 2])) == 0
    # and as MaskablePPO recorded it: each stored action is allowed by the mask stored beside it
    buffer = model.rollout_buffer
    actions = buffer.actions.reshape(-1).astype(int)
    masks = buffer.action_masks.reshape(len(actions), MaskedChoiceEnv.N_ACTIONS)
    assert masks[np.arange(len(actions)), actions].all()
    assert not masks.all()  # some actions were masked, so the check above had something to refuse

    # control: the same training without masks does take forbidden actions
    unmasked_venv, _ = train(use_masking=False)
    assert sum(unmasked_venv.get_attr("illegal_actions", indices=[0, 2])) > 0


# ----------------------------------------------------------------------------- rendering
def test_render_tiles_one_image_per_copy():
    venv = make_vec_env("ChannelAssociation-v0", n_envs=2, seed=0, render_mode="rgb_array", **channel_kwargs(3))
    venv.reset()
    images = venv.get_images()
    assert len(images) == 2 and images[0].ndim == 3 and images[0].shape[2] == 3
    tiled = venv.render()
    height, width = images[0].shape[:2]
    assert tiled.shape[0] * tiled.shape[1] == 2 * height * width  # two copies tiled, not six slots

    silent = make_vec_env("ChannelAssociation-v0", n_envs=1, **channel_kwargs(3))
    with pytest.warns(UserWarning, match="render_mode"):
        assert silent.render() is None


BATCH_PATH_CASES = [
    ("ChannelAssociation-v0", channel_kwargs(3, horizon=6)),
    # a mobile field: the copies step as one array world (BatchedEnv.world), read through sync_copies
    (
        "ChannelAssociation-v0",
        {"n_robots": 10, "mobile_fraction": 0.3, "wireless_range": 6.0, "visual_range": 6.0, HORIZON_ARG: 6},
    ),
    # a neighbourhood: episodes end every few steps and the world begins the next ones itself (reset_copies)
    ("ChannelAssociation-v0", {"scene": "neighborhood", "w": 3, "v": 2, HORIZON_ARG: 12}),
    ("MultiHop-v0", multihop_kwargs(horizon=4)),
    ("MultiHop-v0", {"grid_side": 2, HORIZON_ARG: 4}),  # MultiBinary actions
    ("MapSync-v0", {HORIZON_ARG: 5}),
    ("AsyncCL-v0", {"n_robots": 3, HORIZON_ARG: 5}),
    ("RendezvousMapping-v0", {"n_vehicles": 3, "n_landmarks": 30, "area": 1600.0, HORIZON_ARG: 3}),
]


@pytest.mark.parametrize(("env_id", "kwargs"), BATCH_PATH_CASES, ids=lambda v: str(v))
def test_mrcomm_copies_step_as_one_batch_with_the_same_transitions_as_the_per_agent_path(env_id, kwargs):
    """Unwrapped mrcomm copies are stepped through ``BatchedEnv`` (arrays); any wrapped env through its own
    ``step()``. Both paths give SB3 the same observations, rewards, dones, infos and reset infos."""
    n_copies, seed = 2, 4
    batched = make_vec_env(env_id, n_envs=n_copies, seed=seed, **kwargs)
    per_agent = AgentSlotVecEnv(
        [functools.partial(lambda: BaseParallelWrapper(mrcomm_env.make(env_id, **kwargs))) for _ in range(n_copies)]
    )
    per_agent.seed(seed)
    assert batched.batch is not None and per_agent.batch is None
    assert batched.reset().tobytes() == per_agent.reset().tobytes()
    assert batched.reset_infos == per_agent.reset_infos
    rng = np.random.default_rng(3)
    space = batched.action_space
    for _ in range(3 * kwargs[HORIZON_ARG] + 1):
        if isinstance(space, spaces.MultiBinary):
            actions = rng.integers(0, 2, size=(batched.num_envs, *space.shape)).astype(np.float32)
        else:
            actions = random_actions(rng, space, batched.num_envs)
        first, second = batched.step(actions), per_agent.step(actions)
        for got, want in zip(first[:3], second[:3]):
            assert got.dtype == want.dtype and got.tobytes() == want.tobytes()
        for got, want in zip(first[3], second[3]):
            assert got.keys() == want.keys()
            for key in got:
                if key == "terminal_observation":
                    assert got[key].dtype == want[key].dtype and got[key].tobytes() == want[key].tobytes()
                else:
                    assert got[key] == want[key], key
        assert batched.reset_infos == per_agent.reset_infos
    assert batched.get_attr("step_count") == per_agent.get_attr("step_count")
    assert batched.env_method("bits_sent") == per_agent.env_method("bits_sent")
    np.testing.assert_equal(batched.env_method("metrics"), per_agent.env_method("metrics"))  # NaN: not yet defined
