"""TorchRL: ``make_env(env_id, **env_kwargs)`` → a ``torchrl.envs.PettingZooWrapper`` over one of our envs, and
``make_batched_env(env_id, num_envs=M, **env_kwargs)`` → M copies as one ``EnvBase`` with ``batch_size=[M]``
(``torchrl_batched.py``), which is what collectors and BenchMARL should step.

    from mrcomm_env.integrations.torchrl import make_env
    env = make_env("MapSync-v0", n_robots=3)          # TensorDict in, TensorDict out
    env.rollout(100)                                  # random actions, feasible ones where the env masks

All robots form one group ``"robot"`` (they share spaces, so one policy or critic can read the stacked group);
the global ``state()`` is returned under ``"state"`` for centralised critics (MAPPO); every info key is one
float per robot under ``("robot", "info", key)``; envs with action masks (RendezvousMapping-v0) get
``("robot", "action_mask")`` and a masked action spec, as TorchRL's own masked envs do.
"""

from __future__ import annotations

import importlib

from mrcomm_env.integrations import make_parallel_env, require

EXTRA = "torchrl"
GROUP = "robot"


def make_env(
    env_id: str,
    *,
    device: str = "cpu",
    seed: int | None = None,
    categorical_actions: bool = True,
    return_state: bool = True,
    **env_kwargs,
):
    """A TorchRL env for ``env_id`` (``"MapSync-v0"`` or ``"mrcomm/MapSync-v0"``); ``env_kwargs`` go to the env.

    ``categorical_actions=False`` gives one-hot discrete actions (what some TorchRL losses expect).
    """
    envs = require("torchrl.envs", EXTRA)
    base = make_parallel_env(env_id, **env_kwargs)
    return envs.PettingZooWrapper(
        base,
        group_map={GROUP: list(base.possible_agents)},
        return_state=return_state,
        use_mask=False,  # every robot acts at every step: no agent mask needed
        categorical_actions=categorical_actions,
        seed=seed,
        device=device,
    )


def make_batched_env(env_id: str, num_envs: int, **kwargs):
    """``num_envs`` copies of ``env_id`` as one TorchRL ``EnvBase`` with ``batch_size=[num_envs]``, stepped in one
    call (``torchrl_batched.BatchedTorchRLEnv``): the keys of :func:`make_env` with a leading copy axis.

    ``kwargs``: ``device``, ``seed``, ``categorical_actions`` and ``return_state`` as for :func:`make_env`, and
    ``env_workers``, the processes that step the copies (None: two on two or more cores where the copies step one
    after another, as AsyncCL's and RendezvousMapping's do, else one; the numbers do not depend on it); every other
    keyword goes to the env. Copy i of a batch seeded s is the PettingZoo env seeded s + i, episode after
    episode.
    """
    require("torchrl.envs", EXTRA)
    # the adapter module subclasses TorchRL's EnvBase, so it can only be imported once TorchRL is known present
    batched = importlib.import_module("mrcomm_env.integrations.torchrl_batched")
    return batched.BatchedTorchRLEnv(env_id, num_envs, **kwargs)
