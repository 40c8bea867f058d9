from mrcomm_env.channel_association.env import ChannelAssociationEnv
from mrcomm_env.core.shim import make_constructors

parallel_env, raw_env, env = make_constructors(ChannelAssociationEnv)
__all__ = ["parallel_env", "raw_env", "env"]
