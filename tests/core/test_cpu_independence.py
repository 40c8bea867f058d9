"""Seeded episodes do not depend on the CPU: numpy runs some functions through SIMD code it picks by CPU at import
(``np.show_runtime()``'s "found" features), and a choice among equal values there, e.g. which of a row's tied
entries ``np.argpartition`` or an unstable ``np.argsort`` puts first, differs from one CPU to another. An env that
let such a choice decide anything would play another episode from the same seed on another machine.

``NPY_DISABLE_CPU_FEATURES`` makes numpy dispatch as on a CPU without the named features, so the test plays every
documented configuration of every env twice in fresh interpreters, as this CPU and as one without its dispatched
features, and compares every observation, reward, termination, info and metric.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

#: every documented configuration of every registered env: a digest of two seeded random-action episodes, and of
#: numpy's own tie choices (which must differ between the two runs for the comparison to mean anything)
PLAY = """
import hashlib, json, numpy as np
from mrcomm_env import registry
from mrcomm_env.testing import flat_values, rollout

digests = {}
ties = np.random.default_rng(0).integers(0, 4, size=(200, 40)).astype(np.float64)
digests["numpy argpartition on ties"] = hashlib.sha1(np.argpartition(ties, 9, axis=1)[:, :10].tobytes()).hexdigest()
for env_id in registry.env_ids():
    cls = registry.env_class(env_id)
    for name, kwargs in cls.DOCUMENTED_CONFIGS.items():
        cycles = min(kwargs.get("max_cycles", cls.PARAMS["max_cycles"].default), STEPS)
        env = registry.make(env_id, **{**kwargs, "max_cycles": cycles})
        digest = hashlib.sha1()
        for seed in range(2):
            for item in rollout(env, seed=seed, steps=STEPS, action_seed=seed):
                for value in flat_values(item):
                    digest.update(value.tobytes() if isinstance(value, np.ndarray) else repr(value).encode())
            digest.update(repr(sorted(env.metrics().items())).encode())
        env.close()
        digests[f"{env_id} {name}"] = digest.hexdigest()
print(json.dumps(digests))
"""
STEPS = 30


def _dispatched_features() -> list[str]:
    """numpy's dispatch targets this CPU has beyond numpy's baseline (``np.show_runtime()``'s "found")."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:  # numpy < 2 keeps them elsewhere; the pinned numpy has them here
        return []
    return [feature for feature in __cpu_dispatch__ if __cpu_features__.get(feature)]


def _play(**environment: str) -> dict[str, str]:
    done = subprocess.run(
        [sys.executable, "-c", f"STEPS = {STEPS}\n{PLAY}"],
        env={**os.environ, **environment},
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_seeded_episodes_are_the_same_whatever_simd_code_numpy_dispatches_to():
    found = _dispatched_features()
    if not found:
        pytest.skip("numpy dispatches to no SIMD code beyond its baseline on this CPU: nothing to switch off")
    here = _play()
    elsewhere = _play(NPY_DISABLE_CPU_FEATURES=" ".join(found))
    probe = "numpy argpartition on ties"
    if here.pop(probe) == elsewhere.pop(probe):
        pytest.skip(f"switching off {found} leaves numpy's tie choices as they were: the runs cannot differ by them")
    assert len(here) >= 25  # every env's documented configurations (29 when written)
    differ = sorted(name for name in here if here[name] != elsewhere[name])
    assert not differ, f"these episodes change when numpy dispatches as on a CPU without {found}: {differ}"
