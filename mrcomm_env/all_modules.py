"""The one list of every environment of the library: id → versioned shim module.

Modules are named, not imported, so ``import mrcomm_env`` stays light; ``all_environments()``
imports them.
"""

import importlib

ENV_MODULES = {
    "mrcomm/AsyncCL-v0": "mrcomm_env.asynccl_v0",
    "mrcomm/ChannelAssociation-v0": "mrcomm_env.channel_association_v0",
    "mrcomm/MultiHop-v0": "mrcomm_env.multihop_v0",
}


def all_environments() -> dict:
    """Id → imported shim module, for every environment."""
    return {env_id: importlib.import_module(name) for env_id, name in ENV_MODULES.items()}
