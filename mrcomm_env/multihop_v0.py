from mrcomm_env.core.shim import make_constructors
from mrcomm_env.multihop.env import MultiHopEnv

parallel_env, raw_env, env = make_constructors(MultiHopEnv)
__all__ = ["parallel_env", "raw_env", "env"]
