"""MultiHop-v0's ``mask_unheld``: the select bit of a candidate the robot holds no estimate of is masked, in
``action_masks()``, the infos and the local view alike, on static scenes (the copy-axis world) and moving ones."""

from __future__ import annotations

import numpy as np
import pytest

from mrcomm_env.core.base import mask_info_keys
from mrcomm_env.multihop.env import MultiHopEnv

STATIC = dict(grid_side=4, slot_size=3, max_cycles=10, observe_heard=True)
MOVING = dict(scene="field", n_robots=10, speed=2.0, comm_range=35.0, slot_size=3, max_cycles=10)


def held_from_the_tables(env) -> np.ndarray:
    """(N, N − 1): whether robot i has a stamp of the robot at each of its candidate ranks (from the local view)."""
    views = env.local_views()
    stamps, candidates = views.team("stamps"), views.team("candidates")
    return np.isfinite(np.take_along_axis(stamps, candidates, axis=1))


@pytest.mark.parametrize("kwargs", [STATIC, MOVING], ids=["static", "moving"])
def test_the_masks_are_the_held_candidates_in_every_place_a_policy_reads_them(kwargs):
    env = MultiHopEnv(mask_unheld=True, **kwargs)
    observations, infos = env.reset(seed=4)
    features = env.observation_layout()["features"]
    k = env.n_agents - 1
    rng = np.random.default_rng(4)
    masked_some = False
    while env.agents:
        held = held_from_the_tables(env)
        obs = np.stack([observations[a] for a in env.agents])
        assert np.array_equal(obs[:, 0 : features * k : features] > 0.5, held)  # the observation's "held" feature
        assert np.array_equal(env.action_masks(), held)
        assert np.array_equal(env.local_views().team("action_mask"), held)
        keys = mask_info_keys(infos[env.agents[0]])
        assert len(keys) == k
        assert np.array_equal(np.array([[infos[a][key] for key in keys] for a in env.agents]) > 0.5, held)
        masked_some |= bool((~held).any())
        actions = {a: rng.integers(0, 2, k).astype(np.int8) for a in env.agents}
        observations, _, _, _, infos = env.step(actions)
    assert masked_some  # the cold start leaves candidates unheld: the check above saw masked bits


def test_without_mask_unheld_nothing_is_masked_and_nothing_is_added_to_the_infos():
    env = MultiHopEnv(**STATIC)
    _, infos = env.reset(seed=1)
    assert not hasattr(env, "action_masks")  # the trainers and adapters then treat the env as unmasked
    assert mask_info_keys(infos["robot_0"]) == []
    assert env.local_views().team("action_mask").all()


def test_mask_unheld_is_refused_in_the_absolute_layout():
    with pytest.raises(ValueError, match="argument 'mask_unheld' needs the 'relative' layout"):
        MultiHopEnv(layout="absolute", mask_unheld=True)
