"""AsyncCL-v0: the batched common-case step of the estimator equals its general path.

``Estimators._step_recent`` runs the usual step (every robot exact) as a fixed sequence of batched calls;
``Estimators._step_general`` runs the same column steps through ``_advance``. Here both are evaluated on the
same state at every step of random-mode episodes and must agree (the chain then continues with the fast one).
"""

from __future__ import annotations

import numpy as np
import pytest

from mrcomm_env.asynccl import estimator as est_mod
from mrcomm_env.asynccl_v0 import parallel_env


@pytest.mark.parametrize("seed,kw", [(0, {}), (1, {"link_probability": 0.25, "packet_loss": 0.3}),
                                     (2, {"n_robots": 3, "trajectory": "waypoint", "sensing_radius": 3.0})])
def test_fast_step_equals_general_step(seed, kw, monkeypatch):
    compared = []
    fast = est_mod.Estimators._step_recent

    def checked(self, t, L, valid, groups):
        out = fast(self, t, L, valid, groups)
        if out is not None:
            X, P, res_of = self._step_general(t, L, valid, groups)
            Xf, Pf, res_f = out
            np.testing.assert_allclose(Xf[res_f], np.array(X)[res_of], rtol=0, atol=1e-9)
            np.testing.assert_allclose(Pf[res_f], np.array(P)[res_of], rtol=0, atol=1e-9)
            compared.append(len(set(res_of)))
        return out

    monkeypatch.setattr(est_mod.Estimators, "_step_recent", checked)
    env = parallel_env(max_cycles=120, **kw)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    n_modes = env.action_space("robot_0").n
    while env.agents:
        env.step({a: int(rng.integers(n_modes)) for a in env.agents})
    assert len(compared) > 60
    assert max(compared) >= 3  # steps with several distinct causal filters were compared
