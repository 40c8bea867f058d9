"""Adapters that hand every registered env to the MARL frameworks users benchmark with.

One module per framework, each importing its framework only when called, so ``import mrcomm_env`` stays light:

- ``mrcomm_env.integrations.torchrl``: ``make_env(env_id, **kw)`` → a TorchRL ``PettingZooWrapper``
  (extra ``torchrl``)
- ``mrcomm_env.integrations.benchmarl``: ``MrcommTask`` → a BenchMARL task family (extra ``benchmarl``)
- ``mrcomm_env.integrations.rllib``: ``register_all()`` → every id in ``ray.tune``'s registry (extra ``rllib``)

These are adapters over the env layer (``docs/architecture.md``): they import the registry and the envs,
never the policies or the experiments.
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo.utils.wrappers import BaseParallelWrapper

from mrcomm_env.core.base import MASK_INFO_PREFIX
from mrcomm_env.registry import canonical_id, make


def require(module: str, extra: str) -> ModuleType:
    """Import ``module`` or fail with one line naming the extra that installs it."""
    try:
        return importlib.import_module(module)
    except ImportError as error:
        raise ImportError(
            f"{module} is not installed ({error}); install it with: pip install 'mrcomm-env[{extra}]'"
        ) from None


def refuse_unmaskable_actions(env) -> None:
    """TorchRL masks the specs of discrete actions (and BenchMARL the policies over them); an env that masks the
    select bits of a MultiBinary action (MultiHop-v0's ``mask_unheld``) has no such spec, so it is refused here
    rather than sampled as if unmasked."""
    space = env.action_space(env.possible_agents[0])
    if not isinstance(space, spaces.Discrete):
        raise ValueError(
            f"{env.ENV_ID} masks its {type(space).__name__} actions, which TorchRL's specs cannot mask (they mask "
            "Discrete actions): make it without the argument that turns the masks on (MultiHop-v0: 'mask_unheld')"
        )


class ActionMaskInInfos(BaseParallelWrapper):
    """Puts an env's feasible-action mask into each agent's infos as one bool array ``"action_mask"``.

    Our envs report the mask as scalar infos ``action_mask_0 … action_mask_{K+1}`` (infos stay plain numbers,
    see ``docs/architecture.md``) and as ``env.action_masks()``; TorchRL's ``PettingZooWrapper`` looks for an
    array under ``info["action_mask"]`` and from it masks the action spec, so random and learned policies
    sample feasible actions only. The scalar copies are dropped so the mask is not reported twice.
    Envs without ``action_masks()`` pass through unchanged.
    """

    def __init__(self, env):
        super().__init__(env)
        self.has_action_mask = callable(getattr(env.unwrapped, "action_masks", None))
        if self.has_action_mask:
            refuse_unmaskable_actions(env.unwrapped)

    def _with_mask(self, infos: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        if not self.has_action_mask or not infos:
            return infos
        masks = np.asarray(self.env.unwrapped.action_masks(), dtype=bool)
        index = {agent: i for i, agent in enumerate(self.env.possible_agents)}
        out = {}
        for agent, info in infos.items():
            kept = {k: v for k, v in info.items() if not k.startswith(MASK_INFO_PREFIX)}
            kept["action_mask"] = masks[index[agent]].copy()
            out[agent] = kept
        return out

    def reset(self, seed=None, options=None):
        observations, infos = self.env.reset(seed=seed, options=options)
        return observations, self._with_mask(infos)

    def step(self, actions):
        observations, rewards, terminations, truncations, infos = self.env.step(actions)
        return observations, rewards, terminations, truncations, self._with_mask(infos)

    @property
    def state_space(self):
        return self.env.state_space


def make_parallel_env(env_id: str, **env_kwargs):
    """``mrcomm_env.make(env_id, **env_kwargs)`` with the action mask in the infos as an array, for adapters."""
    canonical_id(env_id)  # unknown ids fail here, naming the valid ones
    return ActionMaskInInfos(make(env_id, **env_kwargs))
