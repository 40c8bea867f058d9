"""The parallel environment every mrcomm environment derives from.

It owns what is the same everywhere: argument validation, seeding, agent names, the shared (cached)
spaces, action validation, ``max_steps`` truncation, infos with identical keys at reset and at every
step, and rendering. A subclass supplies only its paper's world; see ``docs/architecture.md``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from mrcomm_env.core.config import Config, Param, validate_config


class MrcommParallelEnv(ParallelEnv):
    ENV_ID: ClassVar[str] = ""
    DESCRIPTION: ClassVar[str] = ""
    PARAMS: ClassVar[dict[str, Param]] = {}
    METRICS: ClassVar[dict[str, str]] = {}
    INFO_KEYS: ClassVar[dict[str, str]] = {}
    DOCUMENTED_CONFIGS: ClassVar[dict[str, dict[str, Any]]] = {"default": {}}
    VERSION_HISTORY: ClassVar[list[tuple[str, str]]] = []
    #: what one env step stands for in the paper's own time unit, for the benchmark: an env whose step is a
    #: whole TDMA frame sets ("slot", True) so that speed is also reported per slot (N slots per step)
    STEP_UNIT: ClassVar[tuple[str, bool]] = ("step", False)
    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array", "human"], "render_fps": 10}

    # set by _setup()
    n_agents: int
    _obs_space: spaces.Space
    _act_space: spaces.Space

    def __init__(self, render_mode: str | None = None, **kwargs: Any):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"argument 'render_mode' must be one of {self.metadata['render_modes']} or None, got {render_mode!r}"
            )
        self.render_mode = render_mode
        self.cfg: Config = validate_config(self.PARAMS, kwargs, owner=self.ENV_ID or type(self).__name__)
        self._setup()
        self.possible_agents = [f"robot_{i}" for i in range(self.n_agents)]
        self.agents: list[str] = []
        self._agent_index = {a: i for i, a in enumerate(self.possible_agents)}
        self.np_random, self.np_random_seed = seeding.np_random(None)
        self.step_count = 0
        self._figure = None
        self._check_action = _action_checker(self._act_space)

    # ----------------------------------------------------------------- subclass interface
    def _setup(self) -> None:
        raise NotImplementedError

    def _reset_world(self) -> None:
        raise NotImplementedError

    def _step_world(self, actions) -> float | np.ndarray:
        """``actions``: a list of ints (Discrete) or an ``(N, *shape)`` array (Box), in agent order."""
        raise NotImplementedError

    def _observe(self) -> np.ndarray:
        raise NotImplementedError

    def _agent_infos(self) -> dict[str, Any]:
        raise NotImplementedError

    def _terminated(self) -> bool:
        return False

    def metrics(self) -> dict[str, float]:
        raise NotImplementedError

    def _render(self, ax) -> None:
        ax.text(0.5, 0.5, f"{self.ENV_ID}\nstep {self.step_count}", ha="center", va="center")

    def substeps_per_step(self) -> int:
        """How many of ``STEP_UNIT`` one env step holds (1, or N when a step is one slot per agent)."""
        return self.n_agents if self.STEP_UNIT[1] else 1

    # ----------------------------------------------------------------- PettingZoo API
    def observation_space(self, agent: str) -> spaces.Space:
        self._index_of(agent)
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space:
        self._index_of(agent)
        return self._act_space

    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.np_random, self.np_random_seed = seeding.np_random(seed)
        self.agents = list(self.possible_agents)
        self._live = dict.fromkeys(self.agents)  # key view compared with each step's actions in C
        self.step_count = 0
        self._reset_world()
        return self._observations(), self._infos()

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise RuntimeError("step() called on a finished episode; call reset() first")
        if actions.keys() != self._live.keys():
            unknown = sorted(set(actions) - set(self.agents))
            missing = sorted(set(self.agents) - set(actions))
            raise ValueError(
                f"argument 'actions' must hold one action for each agent {self.agents[0]} … {self.agents[-1]}; "
                f"unknown: {unknown[:5]}, missing: {missing[:5]}"
            )
        acts = self._check_action(self.agents, [actions[agent] for agent in self.agents])
        rewards = self._step_world(acts)
        self.step_count += 1
        truncated = self.step_count >= self.cfg["max_steps"]
        terminated = bool(self._terminated())
        observations = self._observations()
        infos = self._infos()
        agents = self.agents
        if isinstance(rewards, (float, int, np.number)):
            reward_dict = dict.fromkeys(agents, float(rewards))
        else:
            reward_dict = dict(zip(agents, np.asarray(rewards, dtype=np.float64).tolist()))
        term_dict = dict.fromkeys(agents, terminated)
        trunc_dict = dict.fromkeys(agents, truncated and not terminated)
        if terminated or truncated:
            self.agents = []
        return observations, reward_dict, term_dict, trunc_dict, infos

    def render(self):
        if self.render_mode is None:
            from gymnasium import logger

            logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        from mrcomm_env.core import render as _render

        if self.render_mode == "rgb_array":
            return _render.to_rgb_array(self._render)
        self._figure = _render.show_human(self._render, self._figure, self.metadata.get("render_fps", 10))
        return None

    def close(self) -> None:
        if self._figure is not None:
            from mrcomm_env.core import render as _render

            _render.close(self._figure)
            self._figure = None

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_figure"] = None
        state["_check_action"] = None
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._check_action = _action_checker(self._act_space)

    # ----------------------------------------------------------------- helpers
    def _index_of(self, agent: str) -> int:
        try:
            return self._agent_index[agent]
        except (KeyError, TypeError):
            raise ValueError(
                f"unknown agent {agent!r}; valid agents are robot_0 … robot_{self.n_agents - 1}"
            ) from None

    def _observations(self) -> dict[str, np.ndarray]:
        obs = self._observe()
        return dict(zip(self.agents, obs))

    def _infos(self) -> dict[str, dict[str, float]]:
        columns = self._agent_infos()
        keys = list(columns)
        values = [np.asarray(columns[k], dtype=np.float64).tolist() for k in keys]
        return {a: dict(zip(keys, row)) for a, row in zip(self.agents, zip(*values))}


def _action_checker(space: spaces.Space):
    """A validator for all agents' actions at once; raises ``ValueError`` naming the agent and the allowed set.

    Checks are vectorised over agents (a per-agent check cost a third of a 100-robot step).
    """
    if isinstance(space, spaces.Discrete):
        lo, n = int(space.start), int(space.n)

        def fail(agent, action):
            raise ValueError(f"action of {agent} must be an integer in [{lo}, {lo + n - 1}], got {action!r}")

        def check(agents, actions):
            if all(type(a) is int for a in actions) and lo <= min(actions) and max(actions) < lo + n:
                return actions  # plain ints, the common case: no numpy round trip
            arr = np.asarray(actions)
            if arr.shape == (len(agents),) and (arr.dtype.kind in "iub" or (arr.dtype.kind == "f" and np.all(arr == np.floor(arr)))):
                ok = (arr >= lo) & (arr < lo + n)
                if ok.all():
                    return arr.astype(np.int64).tolist()
                bad = int(np.argmin(ok))
                fail(agents[bad], actions[bad])
            for agent, action in zip(agents, actions):  # mixed or odd types: find the culprit
                try:
                    value = int(action)
                except (TypeError, ValueError):
                    fail(agent, action)
                if value != action or not lo <= value < lo + n:
                    fail(agent, action)
            fail(agents[0], actions[0])  # pragma: no cover - unreachable

        return check
    if isinstance(space, spaces.Box):
        low, high, shape = space.low, space.high, space.shape

        def check(agents, actions):
            try:
                arr = np.asarray(actions, dtype=space.dtype)
            except (TypeError, ValueError):
                arr = None
            if arr is not None and arr.shape == (len(agents), *shape):
                ok = np.isfinite(arr) & (arr >= low) & (arr <= high)
                ok = ok.reshape(len(agents), -1).all(axis=1)
                if ok.all():
                    return arr
                bad = int(np.argmin(ok))
            else:
                bad = next(
                    (i for i, a in enumerate(actions) if np.shape(a) != shape),
                    0,
                )
            raise ValueError(
                f"action of {agents[bad]} must be a finite array of shape {shape} within "
                f"[{float(np.min(low)):g}, {float(np.max(high)):g}], got {actions[bad]!r}"
            )

        return check

    def check(agents, actions):
        for agent, action in zip(agents, actions):
            if not space.contains(action):
                raise ValueError(f"action of {agent} must lie in {space}, got {action!r}")
        return list(actions)

    return check
