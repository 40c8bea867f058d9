"""Builds the three constructors a versioned shim ``<name>_v0.py`` re-exports.

The environments are parallel-native (as in MAgent2); the AEC form is derived with PettingZoo's own
``parallel_to_aec``: ``raw_env`` is the bare conversion, ``env`` adds PettingZoo's order enforcing.
"""

from __future__ import annotations

from pettingzoo.utils.conversions import parallel_to_aec, parallel_to_aec_wrapper


def make_constructors(env_cls):
    def parallel_env(**kwargs):
        return env_cls(**kwargs)

    def raw_env(**kwargs):
        return parallel_to_aec_wrapper(env_cls(**kwargs))

    def env(**kwargs):
        return parallel_to_aec(env_cls(**kwargs))

    for fn, kind in ((parallel_env, "parallel"), (raw_env, "bare AEC"), (env, "AEC")):
        fn.__doc__ = f"{env_cls.ENV_ID} as a {kind} environment. Arguments: {', '.join(env_cls.PARAMS)}."
        fn.env_cls = env_cls
    return parallel_env, raw_env, env
