"""mrcomm-env: PettingZoo environments for multi-robot communication, one per paper.

Importing the package registers every environment with PettingZoo's registry::

    import mrcomm_env, pettingzoo
    env = pettingzoo.make("parallel", "mrcomm/AsyncCL-v0")
    env = mrcomm_env.make("AsyncCL-v0", n_robots=10)
    batch = mrcomm_env.make_batched("AsyncCL-v0", 64)  # 64 copies as arrays (M, N, ...)
"""

from mrcomm_env.registry import canonical_id, env_ids, make, make_batched, register_all

__version__ = "0.1.0"

register_all()

__all__ = ["make", "make_batched", "env_ids", "canonical_id", "__version__"]
