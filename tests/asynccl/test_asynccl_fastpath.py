"""AsyncCL-v0: the batched common-case step of the estimator equals its general path.

``Estimators._step_recent`` runs the usual step (every robot exact) as two compiled calls;
``Estimators._step_general`` runs the same column steps through ``_advance``. Here both are evaluated on the
same state at every step of random-mode episodes and must agree (the chain then continues with the fast one),
and so must the oracle's common step (``asynccl_reference.ReferenceEstimators``: the robots grouped in Python, the
restarts a loop of batched calls). They batch the same column steps differently (shared priors broadcast or
indexed, restarts split or fused), so they agree to the forward-error bound of ``tests/helpers/numerics.py`` for
the matrices that step inverts.
"""

from __future__ import annotations

import types

import numpy as np
import pytest
from helpers.asynccl_reference import ReferenceEstimators, use_reference
from helpers.numerics import HEADINGS, ConditionLog, assert_close_conditioned, tolerance

from mrcomm_env.asynccl import ekf
from mrcomm_env.asynccl.estimator import Estimators
from mrcomm_env.asynccl_v0 import parallel_env

LOOP_KERNELS = types.SimpleNamespace(**{**vars(ekf.KERNELS), "recent_column": None})  # the oracle's restart loop


@pytest.mark.parametrize("oracle", [False, True], ids=["compiled", "oracle"])
@pytest.mark.parametrize(
    "seed,kw",
    [
        (0, {}),
        (1, {"link_probability": 0.25, "packet_loss": 0.3}),
        (2, {"n_robots": 3, "trajectory": "waypoint", "sensing_radius": 3.0}),
    ],
)
def test_fast_step_equals_general_step(seed, kw, oracle, monkeypatch):
    compared = []
    cls = ReferenceEstimators if oracle else Estimators
    fast = cls._step_recent
    log = ConditionLog()  # κ of the matrices each path inverts in this step (columns of a restart add up)

    def checked(self, t, c, L, cache_ok):
        log.kappa.clear()
        log.step = "fast"  # the compiled step's inversions are inside one call: the general path's count for both
        out = fast(self, t, c, L, cache_ok)
        if out is not None:
            log.step = "general"
            X, P, res_of = self._step_general(t, L, *self._groups(t, c.tolist(), L, cache_ok, True))
            Xf, Pf, res_f = out
            Xg, Pg = np.array(X)[res_of], np.array(P)[res_of]
            kappa, ops = max(log.kappa.values()), 3 * self.n + 2 * self.n * (self.n - 1)
            assert_close_conditioned(
                Xf[res_f], Xg, tolerance(np.linalg.norm(Xg, axis=1).max(), ops, kappa), HEADINGS, f"x at step {t}"
            )
            assert_close_conditioned(
                Pf[res_f], Pg, tolerance(np.linalg.norm(Pg, 2, axis=(1, 2)).max(), ops, kappa), err_msg=f"P at step {t}"
            )
            compared.append(len(set(res_of)))
        return out

    monkeypatch.setattr(cls, "_step_recent", checked)
    env = parallel_env(max_cycles=120, **kw)
    log.kernels = LOOP_KERNELS if oracle else ekf.KERNELS  # record what the kernels invert
    if oracle:
        use_reference(env, log.namespace())
    else:
        env.unwrapped.est.k = log.namespace()
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    n_modes = env.action_space("robot_0").n
    while env.agents:
        env.step({a: int(rng.integers(n_modes)) for a in env.agents})
    assert len(compared) > 60
    assert max(compared) >= 3  # steps with several distinct causal filters were compared


@pytest.mark.parametrize(
    "seed,kw,before_every_source",
    [
        (0, {}, False),
        (1, {"link_probability": 0.25, "packet_loss": 0.3}, True),  # many restarts, from checkpoints far back
        (2, {"n_robots": 3, "max_history": 4, "packet_loss": 0.4}, True),  # columns leave memory
        (3, {"n_robots": 8, "link_model": "disk", "comm_radius": 3.0}, True),
    ],
)
def test_compiled_common_step_is_the_loop_bit_for_bit(seed, kw, before_every_source):
    """The common step in two compiled calls (``ekf_numba.group_filters``, then ``recent_column``: the restarts, the
    extended estimates and column t) runs each filter through the very kernel calls of the oracle's loop, and the
    robots share filters as ``Estimators._groups`` groups them: three envs, the env's own, the oracle's Python
    grouping before the fused call, and the oracle's loop of batched compiled calls, give the same bytes.
    ``before_every_source``: some restart runs while a robot has no odometry yet (the ring's standstill slot)."""
    calls = []

    def counted(Lx, c_r, src_e, t, *rest):
        if c_r:  # filters restarting, columns back, every source known
            calls.append((len(c_r), t - min(c_r), bool(rest[5])))
        return ekf.KERNELS.recent_column(Lx, c_r, src_e, t, *rest)

    envs = [parallel_env(max_cycles=100, **kw) for _ in range(3)]
    envs[0].unwrapped.est.k = types.SimpleNamespace(**{**vars(ekf.KERNELS), "recent_column": counted})
    use_reference(envs[1], ekf.KERNELS)
    use_reference(envs[2], LOOP_KERNELS)
    for env in envs:
        env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    n_modes = envs[0].action_space("robot_0").n
    while envs[0].agents:
        actions = {a: int(rng.integers(n_modes)) for a in envs[0].agents}
        (obs_a, rew_a, *_), *others = (env.step(actions) for env in envs)
        est_a = envs[0].unwrapped.est
        for env, (obs_b, rew_b, *_) in zip(envs[1:], others, strict=True):
            est_b = env.unwrapped.est
            assert est_a.X.tobytes() == est_b.X.tobytes() and est_a.P.tobytes() == est_b.P.tobytes()
            assert all(obs_a[a].tobytes() == obs_b[a].tobytes() and rew_a[a] == rew_b[a] for a in obs_b)
    assert len(calls) >= 5
    assert max(filters for filters, _, _ in calls) >= 3 and max(back for _, back, _ in calls) >= 4
    assert any(not known for _, _, known in calls) == before_every_source
