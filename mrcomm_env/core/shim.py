"""The three constructors a versioned shim ``<name>_v0.py`` re-exports, as MPE2's shims do.

The environments are parallel-native (as in MAgent2): ``parallel_env`` is the class itself, ``env`` is
PettingZoo's own ``aec_wrapper_fn`` (``parallel_to_aec`` plus order enforcing) and ``raw_env`` the bare
``parallel_to_aec_wrapper``.
"""

from __future__ import annotations

from pettingzoo.utils.conversions import aec_wrapper_fn, parallel_to_aec_wrapper


def make_constructors(env_cls):
    def raw_env(**kwargs):
        return parallel_to_aec_wrapper(env_cls(**kwargs))

    env = aec_wrapper_fn(env_cls)
    for fn, kind in ((raw_env, "bare AEC"), (env, "AEC")):
        fn.__doc__ = f"{env_cls.ENV_ID} as a {kind} environment. Arguments: {', '.join(env_cls.PARAMS)}."
    return env_cls, raw_env, env
