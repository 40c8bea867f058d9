"""What every scripted policy shares: the interface, parameter validation and the random policy."""

from __future__ import annotations

from typing import Any

import numpy as np

from mrcomm_env.core.config import Param, validate_config


class Policy:
    """A team policy: ``act`` returns one action per live agent.

    Scripted baselines may read from ``env`` only what their own robot knows (its own filter, table or
    estimate list), never the ground truth of other robots.
    """

    name = "policy"
    PARAMS: dict[str, Param] = {}

    def __init__(self, **params: Any):
        self.params = validate_config(self.PARAMS, params, owner=f"policy '{self.name}'")
        self.rng = np.random.default_rng()

    def reset(self, env, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, observations: dict[str, np.ndarray], env) -> dict[str, Any]:  # pragma: no cover - interface
        raise NotImplementedError


class RandomPolicy(Policy):
    """Uniformly random actions from each agent's action space (seeded through ``reset``)."""

    name = "random"

    def reset(self, env, seed: int | None = None) -> None:
        super().reset(env, seed)
        self._space = env.action_space(env.possible_agents[0])
        self._space.seed(int(self.rng.integers(2**31)))

    def act(self, observations, env):
        return {agent: self._space.sample() for agent in observations}
