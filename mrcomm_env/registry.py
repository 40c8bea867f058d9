"""The one list of every environment, and construction and registration with PettingZoo's own registry.

Each entry names, as module paths (nothing is imported here), the three pieces of one environment, one per
layer: its versioned env shim (``mrcomm_env``), its scripted baselines (``baselines``) and its
reproduction (``mrcomm_env.experiments.reproductions``). ``import mrcomm_env`` stays light, and the env
layer never imports the layers above it: those resolve their own entries (``mrcomm_baselines.policy_module``,
``mrcomm_env.experiments.reproductions.module``). ``tests/experiments/test_architecture.py`` compares the entries with
the files on disk.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from types import ModuleType
from typing import TYPE_CHECKING, Any

import pettingzoo

if TYPE_CHECKING:  # annotations only: the registry imports no environment code
    from mrcomm_env.core.base import MrcommParallelEnv
    from mrcomm_env.core.batched import BatchedEnv

NAMESPACE = "mrcomm/"


@dataclass(frozen=True)
class EnvEntry:
    env: str  #: versioned shim module: ``parallel_env``, ``env`` (AEC), ``raw_env``
    policies: str  #: scripted baselines: ``ENV_ID``, ``DEFAULT_POLICY``, ``POLICIES``
    reproduction: str  #: ``EXPERIMENTS`` and ``run(out_dir, quick)``
    paper: str = ""  #: the paper to cite, "Authors, *Title*" (its full reference is in CITATION.cff)


ENTRIES: dict[str, EnvEntry] = {
    "mrcomm/AsyncCL-v0": EnvEntry(
        "mrcomm_env.asynccl_v0",
        "mrcomm_baselines.asynccl",
        "mrcomm_env.experiments.reproductions.asynccl",
        "Nerurkar & Roumeliotis, *Asynchronous Multi-Centralized Cooperative Localization*",
    ),
    "mrcomm/ChannelAssociation-v0": EnvEntry(
        "mrcomm_env.channel_association_v0",
        "mrcomm_baselines.channel_association",
        "mrcomm_env.experiments.reproductions.channel_association",
        "Ivanov & Shell, *Hark! Who goes there? Concurrent Association of Communication Channels for Multiple "
        "Mobile Robots*",
    ),
    "mrcomm/MapSync-v0": EnvEntry(
        "mrcomm_env.mapsync_v0",
        "mrcomm_baselines.mapsync",
        "mrcomm_env.experiments.reproductions.mapsync",
        "Alsayegh, Dutta, Vanegas & Bobadilla, *Lightweight Multi-robot Communication Protocols for Information "
        "Synchronization*",
    ),
    "mrcomm/MultiHop-v0": EnvEntry(
        "mrcomm_env.multihop_v0",
        "mrcomm_baselines.multihop",
        "mrcomm_env.experiments.reproductions.multihop",
        "Julian, Schwager, Angermann & Rus, *A Location-Based Algorithm for Multi-hopping State Estimates within a "
        "Distributed Robot Team*",
    ),
    "mrcomm/RendezvousMapping-v0": EnvEntry(
        "mrcomm_env.rendezvous_mapping_v0",
        "mrcomm_baselines.rendezvous_mapping",
        "mrcomm_env.experiments.reproductions.rendezvous_mapping",
        "Chapman & Sukkarieh, *A Protocol for Decentralized Multi-Vehicle Mapping with Limited Communication "
        "Connectivity*",
    ),
}


def register(env_id: str, item: EnvEntry) -> None:
    """Add an environment to the registry: ``register("mrcomm/Name-v0", EnvEntry(shim, policies, reproduction))``.

    The entry's three module paths must be importable wherever the env runs (sweep workers and the limit
    measurements import them in fresh processes). Every command, the docs generator, the integrations and the
    tests then see it like the five built in (docs/adding-an-environment.md). Also registers it with
    PettingZoo when :func:`register_all` has run."""
    if not isinstance(env_id, str) or not env_id.startswith(NAMESPACE) or not env_id[len(NAMESPACE) :]:
        raise ValueError(f"argument 'env_id' must be '{NAMESPACE}<Name>-v<version>', got {env_id!r}")
    if env_id in ENTRIES:
        raise ValueError(f"argument 'env_id': {env_id} is already registered")
    if not isinstance(item, EnvEntry):
        raise ValueError(f"argument 'item' must be an EnvEntry, got {type(item).__name__}")
    ENTRIES[env_id] = item
    if _registered:
        register_all()


def unregister(env_id: str) -> None:
    """Remove an environment added by :func:`register` (PettingZoo's registry keeps its entry point)."""
    del ENTRIES[canonical_id(env_id)]


def env_ids() -> list[str]:
    return list(ENTRIES)


def canonical_id(env_id: str) -> str:
    """``"MapSync-v0"`` and ``"mrcomm/MapSync-v0"`` name the same env; unknown ids raise ``ValueError``."""
    name = env_id if isinstance(env_id, str) and env_id.startswith(NAMESPACE) else f"{NAMESPACE}{env_id}"
    if name not in ENTRIES:
        raise ValueError(f"unknown environment id {env_id!r}; valid ids are: {', '.join(ENTRIES)}")
    return name


def short_name(env_id: str) -> str:
    """``"mrcomm/AsyncCL-v0"`` → ``"AsyncCL-v0"``."""
    return canonical_id(env_id)[len(NAMESPACE) :]


def entry(env_id: str) -> EnvEntry:
    return ENTRIES[canonical_id(env_id)]


def env_module(env_id: str) -> ModuleType:
    """The versioned shim module (``parallel_env``, ``env``, ``raw_env``) of ``env_id``."""
    return importlib.import_module(entry(env_id).env)


def env_class(env_id: str) -> type[MrcommParallelEnv]:
    """The environment class behind ``env_id`` (its PARAMS, METRICS, … describe it)."""
    cls: type[MrcommParallelEnv] = env_module(env_id).parallel_env
    return cls


def env_revision(env_id: str) -> str:
    """The env's current revision, the last of its ``VERSION_HISTORY`` (e.g. ``"v0 rev 4"``): what a recorded result
    names so that a later change of the env's episodes shows."""
    return env_class(env_id).VERSION_HISTORY[-1][0]


def make(env_id: str, **kwargs: Any) -> MrcommParallelEnv:
    """Build the parallel form of any registered environment: ``mrcomm_env.make("MapSync-v0", n_robots=3)``."""
    return env_class(env_id)(**kwargs)


def make_batched(env_id: str, n_copies: int, **kwargs: Any) -> BatchedEnv:
    """``n_copies`` copies of ``make(env_id, **kwargs)`` stepped as arrays with a leading copy axis
    (:class:`~mrcomm_env.core.batched.BatchedEnv`): ``mrcomm_env.make_batched("MapSync-v0", 64)``."""
    from mrcomm_env.core.batched import BatchedEnv  # on use: the registry imports no environment code

    cls = env_class(env_id)
    return BatchedEnv(lambda: cls(**kwargs), n_copies)


_registered: set[str] = set()


def register_all() -> None:
    """Register every env with PettingZoo, so ``pettingzoo.make("parallel", "mrcomm/<Name>-v0")`` works.

    Entry points are strings, so registering imports no environment code.
    """

    for env_id, item in ENTRIES.items():
        if env_id in _registered:
            continue
        pettingzoo.register("parallel", env_id, entry_point=f"{item.env}:parallel_env")
        pettingzoo.register("aec", env_id, entry_point=f"{item.env}:env")
        _registered.add(env_id)
