"""A parameter-shared Stable-Baselines3 ``VecEnv`` whose slots are the agents of copies of a parallel env.

``AgentSlotVecEnv`` runs M copies of a PettingZoo parallel environment with N possible agents each and shows
SB3 one vectorised environment of M × N slots: slot ``k`` is agent ``k % N`` of copy ``k // N``. One
policy therefore drives every agent (parameter sharing), and every agent-step is one SB3 transition.

Episodes. A copy's episode ends when its ``env.agents`` becomes empty. Every agent slot reports
``done=True`` at the step its own agent leaves ``env.agents``, with ``terminal_observation`` (the
observation that final step returned for the agent) and ``TimeLimit.truncated = truncated and not
terminated`` so that PPO bootstraps from the value of a truncated episode. When the copy's episode ends it
is reset at once and the slots return the first observation of the next episode, as in SB3's
``DummyVecEnv``; the copy's reset infos go to ``reset_infos``.

Agents that are not in ``env.agents`` while their copy runs (gone early, absent at reset, not yet
joined) leave their slot as *padding*: observation zeros, reward 0, action ignored, info
``{"padding": True}``, every action allowed by ``action_masks``. A padding stretch ends with ``done=True``
(terminal observation zeros, not truncated) when the copy's episode ends or the agent joins, so it never
links two real transitions. In the mrcomm environments all agents live and end together and no
padding ever occurs.

Episode statistics. ``VecMonitor`` counts episodes per slot, so one episode of a copy is N episodes in
``ep_info_buffer`` (one per agent, each with that agent's return; SB3's 100-episode ``ep_rew_mean`` window
thus spans 100 / N copy episodes) — padding stretches count too, and their zero observations enter
``VecNormalize``'s statistics. The
slots of a copy whose episode ends also carry ``info["copy_episode"] = {"r": mean over the N agents of
their episode returns, "l": env steps}``, which is the per-copy figure.

Seeding follows SB3: ``seed(s)`` stores seeds that apply at the next ``reset()`` only (copy ``k`` gets
``s + k``); automatic resets after an episode continue each copy's own random stream.
"""

from __future__ import annotations

import functools
import operator
import warnings
from collections.abc import Callable, Sequence
from copy import deepcopy
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils.wrappers import BaseParallelWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvObs, VecEnvStepReturn

import mrcomm_env
from mrcomm_agents.heldout import sb3_masks
from mrcomm_env.core.batched import BatchedEnv, copies_of_one_env

#: the env method sb3-contrib's MaskablePPO calls through ``env_method`` (``get_action_masks``)
ACTION_MASKS_METHOD = "action_masks"
#: per-agent info key an env may use to publish the mask for its next action
ACTION_MASK_INFO_KEY = "action_mask"


class AgentSlotVecEnv(VecEnv):
    """M copies of an N-agent PettingZoo parallel env as one SB3 ``VecEnv`` of M × N agent slots.

    :param env_fns: one function per copy, each returning a new ``ParallelEnv``; all copies must have the
        same ``possible_agents``, and every agent the same observation space (a ``Box``) and action space.
    :raises ValueError: no copies, one instance returned twice, or differing agents or spaces.
    """

    def __init__(self, env_fns: Sequence[Callable[[], ParallelEnv]]):
        if len(env_fns) == 0:
            raise ValueError("argument 'env_fns' must hold at least one environment constructor, got none")
        self.envs: list[ParallelEnv] = [fn() for fn in env_fns]
        if len({id(env) for env in self.envs}) != len(self.envs):
            raise ValueError(
                "argument 'env_fns' must build a new environment per call; some returned the same instance "
                "(use functools.partial(mrcomm_env.make, env_id, ...) rather than lambda: env)"
            )
        self.agent_names: list[str] = list(self.envs[0].possible_agents)
        if not self.agent_names:
            raise ValueError("the environment has no possible agents")
        self.n_agents = len(self.agent_names)
        self.n_copies = len(self.envs)
        observation_space, action_space = self._shared_spaces()
        self._agent_index = {agent: i for i, agent in enumerate(self.agent_names)}
        self._mask_length = _mask_length(action_space)

        # spaces are copied so that seeding or editing SB3's view (PPO seeds action_space) leaves the envs alone
        super().__init__(self.n_copies * self.n_agents, deepcopy(observation_space), deepcopy(action_space))

        self._observations = np.zeros((self.num_envs, *observation_space.shape), dtype=observation_space.dtype)
        self._active = np.zeros(self.num_envs, dtype=bool)
        # each slot's latest info["action_mask"] (None when absent): the fallback source of action masks
        self._info_masks: list[np.ndarray | None] = [None] * self.num_envs
        self._copy_returns = np.zeros(self.n_copies, dtype=np.float64)
        self._copy_lengths = np.zeros(self.n_copies, dtype=np.int64)
        self._actions: np.ndarray | None = None
        # mrcomm envs (unwrapped) are stepped as one batch of arrays, without per-agent dictionaries; any other
        # PettingZoo env (wrapped, foreign, with agents that come and go) through its own step()
        self.batch: BatchedEnv | None = None
        if copies_of_one_env(self.envs):
            self.batch = BatchedEnv.of(self.envs, argument="env_fns", copy=False)  # copied into the slots

    def _shared_spaces(self) -> tuple[spaces.Box, spaces.Space]:
        first_env, first_agent = self.envs[0], self.agent_names[0]
        observation_space = first_env.observation_space(first_agent)
        action_space = first_env.action_space(first_agent)
        for copy_index, env in enumerate(self.envs):
            if list(env.possible_agents) != self.agent_names:
                raise ValueError(
                    f"every copy must have the same possible agents; copy 0 has {self.agent_names}, "
                    f"copy {copy_index} has {list(env.possible_agents)}"
                )
            for agent in self.agent_names:
                if env.observation_space(agent) != observation_space:
                    raise ValueError(
                        f"a shared policy needs one observation space for all agents: {first_agent} of copy 0 has "
                        f"{observation_space}, {agent} of copy {copy_index} has {env.observation_space(agent)}"
                    )
                if env.action_space(agent) != action_space:
                    raise ValueError(
                        f"a shared policy needs one action space for all agents: {first_agent} of copy 0 has "
                        f"{action_space}, {agent} of copy {copy_index} has {env.action_space(agent)}"
                    )
        if not isinstance(observation_space, spaces.Box):
            raise ValueError(f"observations must lie in a gymnasium Box space, got {observation_space}")
        return observation_space, action_space

    # ----------------------------------------------------------------- reset and step
    def reset(self) -> VecEnvObs:
        if self.batch is not None:
            seeds = [self._seeds[copy_index * self.n_agents] for copy_index in range(self.n_copies)]
            copy_options = [self._options[copy_index * self.n_agents] or None for copy_index in range(self.n_copies)]
            observations, info_columns = self.batch.reset(seed=seeds, options=copy_options)
            for copy_index in range(self.n_copies):
                self._start_batched_episode(copy_index, observations[copy_index], info_columns, copy_index)
            self._reset_seeds()
            self._reset_options()
            return self._observations.copy()
        for copy_index, env in enumerate(self.envs):
            first_slot = copy_index * self.n_agents
            options = self._options[first_slot]
            maybe_options = {"options": options} if options else {}
            observations, infos = env.reset(seed=self._seeds[first_slot], **maybe_options)
            self._start_episode(copy_index, observations, infos)
        # seeds and options apply to this one reset (SB3 semantics)
        self._reset_seeds()
        self._reset_options()
        return self._observations.copy()

    def step_async(self, actions: np.ndarray) -> None:
        actions = np.asarray(actions)
        if actions.shape[:1] != (self.num_envs,):
            raise ValueError(
                f"argument 'actions' must hold one action per slot ({self.num_envs}), got shape {actions.shape}"
            )
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        if self.batch is not None:
            return self._step_batch()
        if isinstance(self.action_space, spaces.Discrete):
            # plain ints: what a PettingZoo env expects for Discrete, and the base env's fast path
            slot_actions: Sequence[Any] = self._actions.reshape(self.num_envs).tolist()
        else:
            slot_actions = self._actions
        self._actions = None

        rewards = np.zeros(self.num_envs, dtype=np.float32)
        dones = np.zeros(self.num_envs, dtype=bool)
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for copy_index, env in enumerate(self.envs):
            first_slot = copy_index * self.n_agents
            acting = list(env.agents)  # a list: iteration order must not depend on string hashing
            acting_set = set(acting)
            if not acting:
                raise RuntimeError(f"copy {copy_index} has no live agent; call reset() before stepping")
            step_actions = {agent: slot_actions[first_slot + self._agent_index[agent]] for agent in acting}
            observations, agent_rewards, terminations, truncations, agent_infos = env.step(step_actions)
            live_after = set(env.agents)
            copy_over = not live_after

            for agent in acting:
                slot = first_slot + self._agent_index[agent]
                reward = float(agent_rewards.get(agent, 0.0))
                rewards[slot] = reward
                self._copy_returns[copy_index] += reward
                terminated = bool(terminations.get(agent, False))
                truncated = bool(truncations.get(agent, False))
                info = dict(agent_infos.get(agent, {}))
                info["TimeLimit.truncated"] = truncated and not terminated
                if agent in live_after:
                    self._observations[slot] = observations[agent]
                else:
                    # an agent that leaves without either flag set counts as terminated: no bootstrapping
                    dones[slot] = True
                    info["terminal_observation"] = np.array(observations[agent], dtype=self.observation_space.dtype)
                    self._observations[slot] = 0
                    self._active[slot] = False
                infos[slot] = info
                self._info_masks[slot] = _info_mask(info)

            for agent_index, agent in enumerate(self.agent_names):
                if agent in acting_set:
                    continue
                slot = first_slot + agent_index
                joins = agent in live_after
                info = {"TimeLimit.truncated": False, "padding": True}
                if joins or copy_over:
                    dones[slot] = True
                    info["terminal_observation"] = np.zeros_like(self._observations[slot])
                if joins:
                    if agent not in observations:
                        raise ValueError(f"{agent} joined copy {copy_index} but step() returned no observation for it")
                    self._observations[slot] = observations[agent]
                    self._active[slot] = True
                infos[slot] = info
                self._info_masks[slot] = None

            self._copy_lengths[copy_index] += 1
            if copy_over:
                copy_episode = {
                    "r": float(self._copy_returns[copy_index] / self.n_agents),
                    "l": int(self._copy_lengths[copy_index]),
                }
                for slot in range(first_slot, first_slot + self.n_agents):
                    infos[slot]["copy_episode"] = dict(copy_episode)
                observations, reset_infos = env.reset()
                self._start_episode(copy_index, observations, reset_infos)

        return self._observations.copy(), rewards, dones, infos

    def _step_batch(self) -> VecEnvStepReturn:
        """``step_wait`` for mrcomm envs: every copy in one ``BatchedEnv.step``; the same transitions, infos and
        automatic resets as the per-agent path below (``tests/policies/test_vecenv.py`` compares them)."""
        assert self._actions is not None and self.batch is not None
        n = self.n_agents
        actions = self._actions.reshape(self.n_copies, n, *(self.action_space.shape or ()))
        self._actions = None
        out = self.batch.step(actions)
        rewards = out.rewards.astype(np.float32).reshape(self.num_envs)
        dones = np.repeat(out.ended, n)
        keys = [*out.infos, "TimeLimit.truncated"]
        # one row per slot: its info columns' numbers, then whether its copy was cut by the time limit
        columns = [column.reshape(self.num_envs).tolist() for column in out.infos.values()]
        columns.append(np.repeat(out.truncated, n).tolist())
        infos = _dicts_of_columns(keys, columns, self.num_envs)
        if ACTION_MASK_INFO_KEY in out.infos:  # (info columns are numbers: a mask there is one number per agent)
            self._info_masks = [_info_mask(info) for info in infos]
        # each copy adds its agents' rewards one by one in agent order, as the per-agent path does: an accumulation
        # is a running sum, never regrouped
        running = np.concatenate((self._copy_returns[:, None], out.rewards), axis=1)
        self._copy_returns = np.add.accumulate(running, axis=1)[:, -1]
        self._copy_lengths += 1
        self._observations[:] = out.observations.reshape(self._observations.shape)
        for copy_index, final in out.final_observations.items():
            first_slot = copy_index * n
            copy_episode = {
                "r": float(self._copy_returns[copy_index] / n),
                "l": int(self._copy_lengths[copy_index]),
            }
            terminal = np.array(final, dtype=self.observation_space.dtype)  # one fresh array: its rows to the slots
            for agent_index in range(n):
                info = infos[first_slot + agent_index]
                info["terminal_observation"] = terminal[agent_index]
                info["copy_episode"] = dict(copy_episode)
            self._start_batched_episode(copy_index, out.observations[copy_index], out.reset_infos[copy_index], None)
        return self._observations.copy(), rewards, dones, infos

    def _start_batched_episode(
        self, copy_index: int, observations: np.ndarray, info_columns: dict[str, np.ndarray], row: int | None
    ) -> None:
        """``_start_episode`` from a batch: ``info_columns`` key → (M, N) with ``row`` the copy's, or (N,)."""
        first_slot = copy_index * self.n_agents
        slots = slice(first_slot, first_slot + self.n_agents)
        keys = list(info_columns)
        columns = [(info_columns[key] if row is None else info_columns[key][row]).tolist() for key in keys]
        self._active[slots] = True
        self._observations[slots] = observations
        self.reset_infos[slots] = _dicts_of_columns(keys, columns, self.n_agents)
        masked = ACTION_MASK_INFO_KEY in info_columns  # (a column of numbers: one per agent)
        self._info_masks[slots] = (
            [_info_mask(info) for info in self.reset_infos[slots]] if masked else [None] * self.n_agents
        )
        self._copy_returns[copy_index] = 0.0
        self._copy_lengths[copy_index] = 0

    def _start_episode(self, copy_index: int, observations: dict[str, Any], infos: dict[str, dict]) -> None:
        """Load a copy's first observations and reset infos into its slots."""
        live = set(self.envs[copy_index].agents)
        for agent_index, agent in enumerate(self.agent_names):
            slot = copy_index * self.n_agents + agent_index
            self._active[slot] = agent in live
            self._observations[slot] = observations[agent] if agent in live else 0
            self.reset_infos[slot] = dict(infos.get(agent, {}))
            self._info_masks[slot] = _info_mask(self.reset_infos[slot])
        self._copy_returns[copy_index] = 0.0
        self._copy_lengths[copy_index] = 0

    # ----------------------------------------------------------------- seeding and options
    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seeds for the next ``reset()``: copy ``k`` gets ``seed + k``; returns each slot's (its copy's) seed."""
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        self._seeds = [seed + slot // self.n_agents for slot in range(self.num_envs)]
        return self._seeds

    def set_options(self, options: list[dict] | dict | None = None) -> None:
        """Reset options for the next ``reset()``: one dict for all copies, or a list with one dict per copy."""
        if options is None:
            options = {}
        if isinstance(options, dict):
            per_copy = [options] * self.n_copies
        else:
            per_copy = list(options)
            if len(per_copy) != self.n_copies:
                raise ValueError(
                    f"argument 'options' must be a dict or a list of one dict per copy ({self.n_copies}), "
                    f"got a list of {len(per_copy)}"
                )
        self._options = [deepcopy(per_copy[slot // self.n_agents]) for slot in range(self.num_envs)]

    # ----------------------------------------------------------------- attributes and methods of the copies
    def _slot_indices(self, indices: VecEnvIndices) -> list[int]:
        slots = []
        for index in self._get_indices(indices):
            slot = operator.index(index)
            if not -self.num_envs <= slot < self.num_envs:
                raise IndexError(f"slot index {slot} out of range for {self.num_envs} slots")
            slots.append(slot % self.num_envs)
        return slots

    def _per_slot(self, indices: VecEnvIndices, per_copy: Callable[[int], Any]) -> list[Any]:
        """``per_copy(copy_index)`` called once per copy the slots belong to, its result repeated for each slot."""
        slots = self._slot_indices(indices)
        results: dict[int, Any] = {}
        for slot in slots:
            copy_index = slot // self.n_agents
            if copy_index not in results:
                results[copy_index] = per_copy(copy_index)
        return [results[slot // self.n_agents] for slot in slots]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The attribute of each requested slot's env copy (slots of one copy share it)."""
        self._sync_copies()
        return self._per_slot(indices, lambda copy_index: getattr(self.envs[copy_index], attr_name))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set the attribute on the copies of the requested slots; it then holds for every slot of those copies."""
        self._sync_copies()
        self._per_slot(indices, lambda copy_index: setattr(self.envs[copy_index], attr_name, value))
        self._reload_copies()

    def _sync_copies(self) -> None:
        # a batch stepping its copies as one array world (BatchedEnv.world) writes their state into the env objects
        # before anything reads them, and takes it back after anything may have changed them (SB3's VecEnv reads
        # render_mode through get_attr before the batch exists)
        batch = getattr(self, "batch", None)
        if batch is not None:
            batch.sync_copies()

    def _reload_copies(self) -> None:
        batch = getattr(self, "batch", None)
        if batch is not None:
            batch.reload_copies()

    def has_attr(self, attr_name: str) -> bool:
        """Whether every copy has ``attr_name``; ``action_masks`` also exists whenever masks can be formed."""
        if attr_name == ACTION_MASKS_METHOD and self._mask_length is not None:
            return True
        return all(hasattr(env, attr_name) for env in self.envs)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        """Call a method of the requested slots' copies, once per copy, one result per slot.

        ``action_masks`` is answered per slot instead: a boolean mask over the slot agent's actions, from the
        env's own ``action_masks()`` (an ``(N, n_actions)`` array) if it has one, else from the agent's latest
        ``info["action_mask"]``, else all True. Padding slots allow every action.
        """
        if method_name == ACTION_MASKS_METHOD:
            if method_args or method_kwargs:
                raise TypeError("action_masks() takes no arguments")
            slots = self._slot_indices(indices)
            copy_masks = self._per_slot(slots, self._copy_action_masks)
            return [masks[slot % self.n_agents].copy() for masks, slot in zip(copy_masks, slots)]
        self._sync_copies()
        results = self._per_slot(
            indices, lambda copy_index: getattr(self.envs[copy_index], method_name)(*method_args, **method_kwargs)
        )
        self._reload_copies()
        return results

    def _copy_action_masks(self, copy_index: int) -> np.ndarray:
        """The ``(N, mask length)`` boolean masks of one copy's agents for their next action."""
        env = self.envs[copy_index]
        first_slot = copy_index * self.n_agents
        env_masks = getattr(env, ACTION_MASKS_METHOD, None)
        if callable(env_masks):
            if self.batch is not None:
                self.batch.sync_copies([copy_index])
            masks = np.array(sb3_masks(env_masks(), self.action_space), dtype=bool)
            valid_shape = masks.ndim == 2 and masks.shape[0] == self.n_agents
            if self._mask_length is not None:
                valid_shape = valid_shape and masks.shape[1] == self._mask_length
            if not valid_shape:
                width = "n_actions" if self._mask_length is None else self._mask_length
                raise ValueError(
                    f"{type(env).__name__}.action_masks() must return one mask per possible agent, "
                    f"shape ({self.n_agents}, {width}), got {masks.shape}"
                )
        else:
            if self._mask_length is None:
                raise AttributeError(
                    f"action masks need a Discrete, MultiDiscrete or MultiBinary action space or an env method "
                    f"action_masks(); the action space is {self.action_space}"
                )
            masks = np.ones((self.n_agents, self._mask_length), dtype=bool)
            for agent_index in range(self.n_agents):
                info_mask = self._info_masks[first_slot + agent_index]
                if info_mask is not None:
                    masks[agent_index] = info_mask.reshape(self._mask_length)
        # a padding slot's action is ignored; allowing all keeps the masked distribution well defined
        masks[~self._active[first_slot : first_slot + self.n_agents]] = True
        return masks

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        """Whether each requested slot's copy is, or wraps through PettingZoo wrappers, a ``wrapper_class``."""
        return self._per_slot(indices, lambda copy_index: _is_wrapped(self.envs[copy_index], wrapper_class))

    # ----------------------------------------------------------------- rendering and closing
    def get_images(self) -> Sequence[np.ndarray | None]:
        """One image per copy (not per slot: the N agents of a copy share one scene)."""
        if self.render_mode != "rgb_array":
            warnings.warn(
                f"The render mode is {self.render_mode}, but this method assumes it is `rgb_array` to obtain images.",
                stacklevel=2,
            )
            return [None for _ in self.envs]
        self._sync_copies()
        return [env.render() for env in self.envs]

    def close(self) -> None:
        for env in self.envs:
            env.close()


def make_vec_env(env_id: str, n_envs: int = 1, seed: int | None = None, **env_kwargs: Any) -> AgentSlotVecEnv:
    """``n_envs`` copies of ``mrcomm_env.make(env_id, **env_kwargs)`` as one ``AgentSlotVecEnv``.

    With ``seed``, the first ``reset()`` seeds copy ``k`` with ``seed + k`` (as SB3's ``make_vec_env``).
    """
    if n_envs < 1:
        raise ValueError(f"argument 'n_envs' must be at least 1, got {n_envs}")
    venv = AgentSlotVecEnv([functools.partial(mrcomm_env.make, env_id, **env_kwargs) for _ in range(n_envs)])
    if seed is not None:
        venv.seed(seed)
    return venv


def _dicts_of_columns(keys: list[str], columns: list[list[Any]], count: int) -> list[dict[str, Any]]:
    """``count`` dicts, the i-th holding each column's i-th value under the column's key, keys in order: filled
    column by column, 2.5 times as fast as a ``dict(zip(keys, row))`` per row at a hundred slots."""
    dicts: list[dict[str, Any]] = [{} for _ in range(count)]
    for key, column in zip(keys, columns):
        for entry, value in zip(dicts, column):
            entry[key] = value
    return dicts


def _mask_length(action_space: spaces.Space) -> int | None:
    """Length of one flat action mask as sb3-contrib's masked distributions read it, or None if unmaskable."""
    if isinstance(action_space, spaces.Discrete):
        return int(action_space.n)
    if isinstance(action_space, spaces.MultiDiscrete):
        return int(np.sum(action_space.nvec))
    if isinstance(action_space, spaces.MultiBinary):
        return 2 * int(np.prod(action_space.shape))
    return None


def _info_mask(info: dict[str, Any]) -> np.ndarray | None:
    """A private copy of ``info["action_mask"]``: wrappers such as VecNormalize edit the infos they pass on."""
    mask = info.get(ACTION_MASK_INFO_KEY)
    return None if mask is None else np.array(mask, dtype=bool)


def _is_wrapped(env: Any, wrapper_class: type) -> bool:
    while True:
        if isinstance(env, wrapper_class):
            return True
        if not isinstance(env, (BaseParallelWrapper, gym.Wrapper)):
            return False
        env = env.env
