"""Scripted baseline policies: the papers' own decision algorithms, one module per environment."""

from __future__ import annotations

import importlib

from baselines.common import Policy, RandomPolicy

#: environment id -> module holding its policies (each defines ENV_ID, DEFAULT_POLICY and POLICIES)
_MODULES = {
    "mrcomm/AsyncCL-v0": "baselines.asynccl",
    "mrcomm/ChannelAssociation-v0": "baselines.channel_association",
    "mrcomm/MultiHop-v0": "baselines.multihop",
}


def _module(env_id: str):
    from mrcomm_env.registry import canonical_id

    env_id = canonical_id(env_id)
    return importlib.import_module(_MODULES[env_id])


def policy_names(env_id: str) -> list[str]:
    return list(_module(env_id).POLICIES)


def default_policy(env_id: str) -> str:
    return _module(env_id).DEFAULT_POLICY


def make_policy(env_id: str, name: str, **params) -> Policy:
    """Build policy ``name`` for ``env_id``; unknown names raise ``ValueError`` listing the valid ones."""
    policies = _module(env_id).POLICIES
    if name not in policies:
        raise ValueError(f"unknown policy {name!r} for {env_id}; valid policies are: {', '.join(policies)}")
    return policies[name](**params)


__all__ = ["Policy", "RandomPolicy", "policy_names", "default_policy", "make_policy"]
