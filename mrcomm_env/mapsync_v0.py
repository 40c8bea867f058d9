from mrcomm_env.core.shim import make_constructors
from mrcomm_env.mapsync.env import MapSyncEnv

parallel_env, raw_env, env = make_constructors(MapSyncEnv)
__all__ = ["parallel_env", "raw_env", "env"]
