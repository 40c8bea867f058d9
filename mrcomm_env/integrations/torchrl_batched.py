"""TorchRL: M copies of one env as one ``EnvBase`` with ``batch_size=[M]`` (``make_batched_env``).

What ``VmasEnv`` is to VMAS: TorchRL and BenchMARL step all copies in one call instead of one
``PettingZooWrapper`` per copy in a ``SerialEnv``. Under it is :class:`~mrcomm_env.core.batched.BatchedEnv`, so
envs with a copy-axis world (ChannelAssociation, MapSync, MultiHop) step every copy as arrays, and the others step
their copies in turn without TorchRL's per-copy wrapping, by default split between two processes on two or more
cores (``env_workers``, :mod:`mrcomm_env.core.sharded`).

The keys and specs are those of :func:`mrcomm_env.integrations.torchrl.make_env` with a leading copy axis: group
``"robot"`` holds ``observation`` ``(M, N, obs_dim)``, ``action`` ``(M, N)`` (categorical; one-hot or binary
vectors, or Box actions, with a trailing axis), ``reward`` ``(M, N, 1)``, ``done``/``terminated``/``truncated``
``(M, N, 1)``, every info key ``("info", key)`` ``(M, N)`` float32 and, for envs with ``action_masks()``,
``action_mask`` ``(M, N, K)``, which also masks the action spec (so ``env.rand_action`` and masked distributions pick
feasible actions; TorchRL's ``RandomPolicy`` samples from a clone of the spec it was given, without later masks).
The root holds ``done``/``terminated``/``truncated`` ``(M, 1)`` and ``state`` ``(M, state_dim)``.

**Episodes.** A copy whose episode ends reports its final step, as TorchRL wants. Its next episode has then
already begun, drawn from the copy's own random stream (``BatchedEnv`` resets it at once); a reset that names the
copy (``_reset``, as collectors send) hands out that episode's first observation and draws nothing more. A reset
of a copy that did not end begins a new episode of that copy alone.

**Seeds.** ``set_seed(s)`` (or ``seed=s``) seeds the next full reset: copy i is then the PettingZoo env
``mrcomm_env.make(id, **env_args)`` reset with seed ``s + i`` and, after each episode, reset without a seed:
the same observations, rewards and infos, byte for byte (``tests/integrations/test_torchrl.py``).
"""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
from gymnasium import spaces

from mrcomm_env.core.base import MASK_INFO_PREFIX, mask_info_keys
from mrcomm_env.core.batched import BatchedEnv
from mrcomm_env.core.sharded import stepping_batch
from mrcomm_env.integrations import refuse_unmaskable_actions, require
from mrcomm_env.registry import make

EXTRA = "torchrl"
GROUP = "robot"
DONE_KEYS = ("done", "terminated", "truncated")

torch = require("torch", EXTRA)
_envs = require("torchrl.envs", EXTRA)
_specs = require("torchrl.data", EXTRA)
_tensordict = require("tensordict", EXTRA)
TensorDict = _tensordict.TensorDict
#: TorchRL's env base class, looked up at import (the module is only imported where TorchRL is installed)
EnvBase: Any = _envs.EnvBase


class BatchedTorchRLEnv(EnvBase):
    """``num_envs`` copies of the env ``env_id`` (with ``env_kwargs``) as one TorchRL env (see the module docstring).

    :raises ValueError: an unknown id or a bad env argument (the env's own message), ``num_envs`` not a positive
        integer or over the env's memory budget, actions the adapter cannot express, or ``return_state`` on an env
        whose ``state()`` is not its robots' observations concatenated.
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        *,
        device: str = "cpu",
        seed: int | None = None,
        categorical_actions: bool = True,
        return_state: bool = True,
        env_workers: int | None = None,
        **env_kwargs: Any,
    ):
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"argument 'num_envs' must be an integer ≥ 1, got {num_envs!r}")
        # one probe copy, reset unseeded, tells the spaces and the info keys (a bad argument fails here)
        probe = make(env_id, **env_kwargs)
        BatchedEnv.check_memory(probe, num_envs, "num_envs")
        if callable(getattr(probe, "action_masks", None)):
            refuse_unmaskable_actions(probe)
        if return_state and not probe.state_is_joint_observation():
            raise ValueError(
                f"argument 'return_state': {probe.ENV_ID} defines its own state(), which a batch of copies cannot "
                "build from its observations; pass return_state=False"
            )
        _, infos = probe.reset_arrays()
        self.env_id = probe.ENV_ID
        #: the episode length of every copy (BenchMARL's ``max_steps``)
        self.max_cycles = int(probe.cfg["max_cycles"])
        self.return_state = bool(return_state)
        self.categorical_actions = bool(categorical_actions)
        self._mask_keys = mask_info_keys(infos)
        self._info_keys = [k for k in infos if not k.startswith(MASK_INFO_PREFIX)]
        # the processes stepping the copies (None: two on two or more cores where the copies step one after another,
        # ``core.sharded.default_workers``): the same numbers whatever their count
        if env_workers is not None and (
            isinstance(env_workers, bool) or not isinstance(env_workers, int) or not 1 <= env_workers <= num_envs
        ):
            raise ValueError(f"argument 'env_workers' must be None or an integer in [1, num_envs], got {env_workers!r}")
        self._make_batch = partial(
            stepping_batch, partial(make, env_id, **env_kwargs), num_envs, env_workers, copy=False
        )
        self.batch = self._make_batch()
        self.n_agents = self.batch.n_agents
        #: TorchRL's multi-agent grouping: every robot in one group (they share spaces)
        self.group_map = {GROUP: list(self.batch.possible_agents)}
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self.is_closed = False  # EnvBase starts closed unless told (its wrappers say so once their env is built)
        self._make_specs(probe)
        self._seed = seed
        self._started = False
        #: copies whose episode ended at the last step and whose next episode has begun, not yet handed out
        self._pending = np.zeros(num_envs, dtype=bool)
        self._infos: dict[str, np.ndarray] = {}
        #: copy index → the metrics (``env.metrics()``) of the episodes that ended at the last step
        self.last_final_metrics: dict[int, dict[str, float]] = {}

    # ------------------------------------------------------------------ specs
    def _make_specs(self, probe) -> None:
        m, n = self.batch.n_copies, self.n_agents
        lead = (m, n)
        obs_space = self.batch.observation_space
        group = {
            "observation": _bounded(obs_space, lead, self.device),
            "info": _specs.Composite(
                {key: _specs.Unbounded(shape=lead, dtype=torch.float32, device=self.device) for key in self._info_keys},
                shape=lead,
                device=self.device,
            ),
        }
        if self._mask_keys:
            group["action_mask"] = _specs.Categorical(
                2, shape=(*lead, len(self._mask_keys)), dtype=torch.bool, device=self.device
            )
        observation = {GROUP: _specs.Composite(group, shape=lead, device=self.device)}
        if self.return_state:
            observation["state"] = _bounded(probe.state_space, (m,), self.device)
        self.observation_spec = _specs.Composite(observation, shape=(m,), device=self.device)
        self.action_spec = _specs.Composite(
            {GROUP: _specs.Composite({"action": self._action_leaf(lead)}, shape=lead, device=self.device)},
            shape=(m,),
            device=self.device,
        )
        self.reward_spec = _specs.Composite(
            {
                GROUP: _specs.Composite(
                    {"reward": _specs.Unbounded(shape=(*lead, 1), dtype=torch.float32, device=self.device)},
                    shape=lead,
                    device=self.device,
                )
            },
            shape=(m,),
            device=self.device,
        )
        done = {key: _specs.Categorical(2, shape=(m, 1), dtype=torch.bool, device=self.device) for key in DONE_KEYS}
        done[GROUP] = _specs.Composite(
            {key: _specs.Categorical(2, shape=(*lead, 1), dtype=torch.bool, device=self.device) for key in DONE_KEYS},
            shape=lead,
            device=self.device,
        )
        self.done_spec = _specs.Composite(done, shape=(m,), device=self.device)

    def _action_leaf(self, lead: tuple[int, int]):
        space = self.batch.action_space
        if isinstance(space, spaces.Discrete) and int(space.start) == 0:
            if self.categorical_actions:
                return _specs.Categorical(int(space.n), shape=lead, dtype=torch.int64, device=self.device)
            return _specs.OneHot(int(space.n), shape=(*lead, int(space.n)), device=self.device)
        if isinstance(space, spaces.MultiBinary) and len(space.shape) == 1:
            bits = space.shape[0]
            return _specs.Binary(bits, shape=(*lead, bits), dtype=torch.int8, device=self.device)
        if isinstance(space, spaces.Box) and space.is_bounded():
            return _bounded(space, lead, self.device)
        raise ValueError(
            f"{self.env_id}: the batched TorchRL env takes Discrete (from 0), 1-D MultiBinary or bounded Box actions, "
            "and this "
            f"configuration acts in {space}"
        )

    # ------------------------------------------------------------------ TorchRL's hooks
    def _set_seed(self, seed: int | None) -> None:
        self._seed = seed  # applied at the next full reset: copy i gets seed + i

    def _reset(self, tensordict=None, **kwargs):
        if self.is_closed:  # used again after close(): new copies, as TorchRL's ParallelEnv starts new workers
            self.batch = self._make_batch()
            self.is_closed, self._started = False, False
            self._pending[:] = False
        to_reset = self._reset_mask(tensordict)
        if to_reset is None or not self._started:  # a full reset
            if self._seed is not None or not self._started:
                _, self._infos = self.batch.reset(seed=self._seed)
                self._seed = None
                self._started = True
            else:  # copies whose next episode already began keep it (their streams advance once per episode)
                self._restart(np.flatnonzero(~self._pending))
            self._pending[:] = False
        else:
            self._restart(np.flatnonzero(to_reset & ~self._pending))
            self._pending[to_reset] = False
        observations = self.batch.observations
        out = self._output(observations.copy(), self._infos)
        for key in DONE_KEYS:
            out.set(key, torch.zeros((self.batch.n_copies, 1), dtype=torch.bool, device=self.device))
            out.set(
                (GROUP, key), torch.zeros((*self.batch_size, self.n_agents, 1), dtype=torch.bool, device=self.device)
            )
        return out

    def _step(self, tensordict):
        action = tensordict.get((GROUP, "action"))
        if isinstance(self.batch.action_space, spaces.Discrete) and not self.categorical_actions:
            action = action.to(torch.int64).argmax(-1)  # one-hot vectors (bool) to indices
        step = self.batch.step(action.detach().cpu().numpy())
        self.last_final_metrics = step.final_metrics
        observations = step.observations.copy()
        infos = step.infos
        if step.final_observations:
            infos = {key: column.copy() for key, column in infos.items()}
            self._infos = {key: column.copy() for key, column in infos.items()}
            for i, final in step.final_observations.items():
                observations[i] = final
                for key, column in step.reset_infos[i].items():
                    self._infos[key][i] = column
            self._pending[list(step.final_observations)] = True
        else:
            self._infos = infos
        out = self._output(observations, infos)
        out.set(
            (GROUP, "reward"),
            torch.from_numpy(step.rewards.astype(np.float32)).unsqueeze(-1).to(self.device),
        )
        n = self.n_agents
        for key, flags in (
            ("done", step.terminated | step.truncated),
            ("terminated", step.terminated),
            ("truncated", step.truncated),
        ):
            column = torch.from_numpy(flags).unsqueeze(-1).to(self.device)
            out.set(key, column)
            out.set((GROUP, key), column.unsqueeze(-1).expand(-1, n, 1).clone())
        return out

    # ------------------------------------------------------------------ helpers
    def _reset_mask(self, tensordict) -> np.ndarray | None:
        """``(M,)`` bool: the copies a partial reset names (TorchRL's ``_reset`` at the root or in the group), or
        None for a full reset."""
        if tensordict is None:
            return None
        for key in ("_reset", (GROUP, "_reset")):
            flags = tensordict.get(key, None)
            if flags is not None:
                flags = flags.reshape(self.batch.n_copies, -1).any(-1).cpu().numpy()
                return None if flags.all() else flags
        return None

    def _restart(self, copies: np.ndarray) -> None:
        if copies.size == 0:
            return
        self._infos = {key: column.copy() for key, column in self._infos.items()}  # may be the world's own buffers
        for i, columns in self.batch.restart(copies.tolist()).items():
            for key, column in columns.items():
                self._infos[key][i] = column

    def _output(self, observations: np.ndarray, infos: dict[str, np.ndarray]):
        m, n = self.batch.n_copies, self.n_agents
        group = {
            "observation": torch.from_numpy(observations),
            "info": TensorDict(
                {key: torch.from_numpy(infos[key].astype(np.float32)) for key in self._info_keys},
                batch_size=(m, n),
            ),
        }
        if self._mask_keys:
            mask = torch.from_numpy(np.stack([infos[key] for key in self._mask_keys], axis=-1) > 0.5)
            group["action_mask"] = mask
            self.full_action_spec[GROUP, "action"].update_mask(mask.clone())
        out = TensorDict({GROUP: TensorDict(group, batch_size=(m, n))}, batch_size=(m,))
        if self.return_state:
            out.set("state", torch.from_numpy(observations.reshape(m, -1)))
        return out.to(self.device) if self.device != torch.device("cpu") else out

    def render(self, index: int = 0):
        """Copy ``index`` as an RGB array ``(H, W, 3)`` (what BenchMARL's evaluation videos record)."""
        return self.batch.render_copy(index)

    def close(self, *, raise_if_closed: bool = True) -> None:
        """Close every copy and end the stepping processes. The env may be reset again afterwards: it then begins new
        copies (seeded by ``set_seed``, or unseeded), as TorchRL's ``ParallelEnv`` starts new workers."""
        if not self.is_closed:
            self.batch.close()
        self.is_closed = True


def _bounded(space: spaces.Space, lead: tuple[int, ...], device):
    """A TorchRL spec of the Box ``space`` repeated over the leading axes ``lead`` (float32, as our Boxes are)."""
    if not isinstance(space, spaces.Box):  # every mrcomm observation and state space is a Box
        raise TypeError(f"a bounded spec needs a Box, got {space}")
    low = torch.as_tensor(np.broadcast_to(space.low, (*lead, *space.shape)).copy())
    high = torch.as_tensor(np.broadcast_to(space.high, (*lead, *space.shape)).copy())
    return _specs.Bounded(low=low, high=high, shape=(*lead, *space.shape), dtype=torch.float32, device=device)
