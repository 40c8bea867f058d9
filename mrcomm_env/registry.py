"""Environment ids: normalisation, construction and registration with PettingZoo's own registry."""

from __future__ import annotations

import importlib

from mrcomm_env.all_modules import ENV_MODULES

NAMESPACE = "mrcomm/"


def env_ids() -> list[str]:
    return list(ENV_MODULES)


def canonical_id(env_id: str) -> str:
    """``"MapSync-v0"`` and ``"mrcomm/MapSync-v0"`` name the same env; unknown ids raise ``ValueError``."""
    ids = ENV_MODULES
    name = env_id if isinstance(env_id, str) and env_id.startswith(NAMESPACE) else f"{NAMESPACE}{env_id}"
    if name not in ids:
        raise ValueError(f"unknown environment id {env_id!r}; valid ids are: {', '.join(ids)}")
    return name


def env_module(env_id: str):
    """The versioned shim module (``parallel_env``, ``env``, ``raw_env``) of ``env_id``."""
    return importlib.import_module(ENV_MODULES[canonical_id(env_id)])


def env_class(env_id: str):
    """The environment class behind ``env_id`` (its PARAMS, METRICS, … describe it)."""
    return env_module(env_id).parallel_env.env_cls


def make(env_id: str, **kwargs):
    """Build the parallel form of any registered environment: ``mrcomm_env.make("MapSync-v0", n_robots=3)``."""
    return env_module(env_id).parallel_env(**kwargs)


_registered: set[str] = set()


def register_all() -> None:
    """Register every env with PettingZoo, so ``pettingzoo.make("parallel", "mrcomm/<Name>-v0")`` works.

    Entry points are strings, so registering imports no environment code.
    """
    import pettingzoo

    for env_id, module_name in ENV_MODULES.items():
        if env_id in _registered:
            continue
        pettingzoo.register("parallel", env_id, entry_point=f"{module_name}:parallel_env")
        pettingzoo.register("aec", env_id, entry_point=f"{module_name}:env")
        _registered.add(env_id)
