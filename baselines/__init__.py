"""Scripted baseline policies, one module per environment: the papers' own decision algorithms, and rules of
ours beside them (a policy's ``FROM_PAPER`` says which: :func:`from_paper`).

Which module belongs to which environment is the registry's ``EnvEntry.policies``
(``mrcomm_env/registry.py``); each module defines ``ENV_ID``, ``DEFAULT_POLICY`` and ``POLICIES``.
"""

from __future__ import annotations

import importlib

from mrcomm_baselines.common import RandomPolicy
from mrcomm_env.core.policy import LocalViews, Policy
from mrcomm_env.registry import canonical_id, entry


def policy_module(env_id: str):
    """The module holding ``env_id``'s scripted policies."""
    return importlib.import_module(entry(env_id).policies)


def policy_names(env_id: str) -> list[str]:
    return list(policy_module(env_id).POLICIES)


def default_policy(env_id: str) -> str:
    return policy_module(env_id).DEFAULT_POLICY


def policy_class(env_id: str, name: str) -> type[Policy]:
    """The class of ``env_id``'s policy ``name``; unknown names raise ``ValueError`` listing the valid ones."""
    policies = policy_module(env_id).POLICIES
    if name not in policies:
        raise ValueError(
            f"unknown policy {name!r} for {canonical_id(env_id)}; valid policies are: {', '.join(policies)}"
        )
    return policies[name]


def from_paper(env_id: str, name: str) -> str:
    """Where ``env_id``'s paper describes policy ``name`` (its ``FROM_PAPER``); empty for a rule that is not the
    paper's."""
    return policy_class(env_id, name).FROM_PAPER


def make_policy(env_id: str, name: str, **params) -> Policy:
    """Build policy ``name`` for ``env_id``; unknown names raise ``ValueError`` listing the valid ones."""
    return policy_class(env_id, name)(**params)


__all__ = [
    "LocalViews",
    "Policy",
    "RandomPolicy",
    "policy_module",
    "policy_names",
    "default_policy",
    "policy_class",
    "from_paper",
    "make_policy",
]
