from mrcomm_env.core.shim import make_constructors
from mrcomm_env.rendezvous.env import RendezvousMappingEnv

parallel_env, raw_env, env = make_constructors(RendezvousMappingEnv)
__all__ = ["parallel_env", "raw_env", "env"]
