"""RLlib: ``register_all()`` puts every env id into ``ray.tune``'s registry as an RLlib ``MultiAgentEnv``.

    import mrcomm_env.integrations.rllib as mrcomm_rllib
    from ray.rllib.algorithms.ppo import PPOConfig
    mrcomm_rllib.register_all()
    config = PPOConfig().environment("mrcomm/MapSync-v0", env_config={"n_robots": 3})

Each id is registered under its full name (``"mrcomm/MapSync-v0"``) and its short one (``"MapSync-v0"``); the
``env_config`` dict holds the env's own arguments. The env is wrapped in RLlib's ``ParallelPettingZooEnv``:
agents keep their names ``robot_i``, and since every robot has the same spaces, one policy can be shared with
``policy_mapping_fn=lambda agent_id, *args, **kwargs: "shared"``. RLlib does not read our action masks; an
infeasible action is taken as the env documents it (RendezvousMapping-v0 holds). RLlib's model catalog has
no distribution for ``MultiBinary`` (MultiHop-v0's relay choice), so such spaces are declared as the
equivalent ``MultiDiscrete([2, 2, …])``: the same 0/1 vectors, sampled as independent categoricals.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from gymnasium import spaces
from pettingzoo.utils.wrappers import BaseParallelWrapper

from mrcomm_env.integrations import require
from mrcomm_env.registry import NAMESPACE, canonical_id, env_ids, make

EXTRA = "rllib"


class MultiBinaryAsMultiDiscrete(BaseParallelWrapper):
    """Declares a 1-D ``MultiBinary(n)`` action space as ``MultiDiscrete([2] * n)``; the env takes either."""

    def __init__(self, env):
        super().__init__(env)
        self._action_spaces = {}
        for agent in env.possible_agents:
            space = env.action_space(agent)
            if isinstance(space, spaces.MultiBinary) and len(space.shape) == 1:
                space = spaces.MultiDiscrete(np.full(space.shape, 2), seed=int(space.np_random.integers(2**31)))
            self._action_spaces[agent] = space

    def action_space(self, agent):
        return self._action_spaces[agent]

    @property
    def state_space(self):
        return self.env.state_space


def env_creator(env_id: str):
    """The creator ``register_env`` wants for ``env_id``: ``env_config`` → ``ParallelPettingZooEnv``."""
    pettingzoo_env = require("ray.rllib.env.wrappers.pettingzoo_env", EXTRA)
    env_id = canonical_id(env_id)

    def create(env_config: Mapping | None = None):
        # RLlib passes an EnvContext (a dict that also carries worker_index, num_workers, ...): only its items
        # are env arguments
        return pettingzoo_env.ParallelPettingZooEnv(MultiBinaryAsMultiDiscrete(make(env_id, **dict(env_config or {}))))

    return create


def register_all() -> list[str]:
    """Register every env id (full and short name) with ``ray.tune.registry.register_env``; returns the names."""
    registry = require("ray.tune.registry", EXTRA)
    names = []
    for env_id in env_ids():
        creator = env_creator(env_id)
        for name in (env_id, env_id[len(NAMESPACE) :]):
            registry.register_env(name, creator)
            names.append(name)
    return names
