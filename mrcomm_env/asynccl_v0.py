from mrcomm_env.asynccl.env import AsyncCLEnv
from mrcomm_env.core.shim import make_constructors

parallel_env, raw_env, env = make_constructors(AsyncCLEnv)
__all__ = ["parallel_env", "raw_env", "env"]
