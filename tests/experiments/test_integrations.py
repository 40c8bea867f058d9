"""The framework adapters without their frameworks (the base install): a missing extra or an unknown env id
fails in one line that says what to do, and the action-mask wrapper the adapters share reports the env's mask.
The adapters with their frameworks are tested in tests/integrations/ by ``make test-<framework>``."""

from __future__ import annotations

import importlib
import sys

import numpy as np
import pytest

import mrcomm_env
from mrcomm_env.integrations import make_parallel_env, require


@pytest.mark.parametrize(
    ("module", "framework", "call", "extra"),
    [
        ("mrcomm_env.integrations.torchrl", "torchrl", lambda m: m.make_env("MapSync-v0"), "torchrl"),
        ("mrcomm_env.integrations.torchrl", "torchrl", lambda m: m.make_batched_env("MapSync-v0", 2), "torchrl"),
        ("mrcomm_env.integrations.rllib", "ray", lambda m: m.register_all(), "rllib"),
        ("mrcomm_env.integrations.rllib", "ray", lambda m: m.env_creator("MapSync-v0"), "rllib"),
    ],
)
def test_a_missing_framework_names_the_extra_in_one_line(monkeypatch, module, framework, call, extra):
    adapter = importlib.import_module(module)  # the adapter modules themselves import no framework
    # a None entry in sys.modules makes any import of the framework fail, installed or not
    for name in [m for m in list(sys.modules) if m == framework or m.startswith(framework + ".")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, framework, None)
    with pytest.raises(ImportError) as error:
        call(adapter)
    message = str(error.value)
    assert f"pip install 'mrcomm-env[{extra}]'" in message and "\n" not in message


def test_require_returns_the_module_when_present():
    assert require("numpy", "none") is np


def test_unknown_env_id_fails_before_any_framework_is_needed():
    with pytest.raises(ValueError, match="unknown environment id 'NoSuchEnv-v0'.*MapSync-v0"):
        make_parallel_env("NoSuchEnv-v0")


def test_action_mask_wrapper_reports_the_env_mask_as_one_array():
    kwargs = {"n_vehicles": 3, "n_landmarks": 4, "k_candidates": 5, "max_cycles": 5}
    env = make_parallel_env("RendezvousMapping-v0", **kwargs)
    bare = mrcomm_env.make("RendezvousMapping-v0", **kwargs)
    _, infos = env.reset(seed=2)
    _, bare_infos = bare.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(5):
        masks = bare.action_masks()
        assert not masks.all(), "the configuration must leave some candidate slots empty"
        for i, agent in enumerate(bare.possible_agents):
            np.testing.assert_array_equal(infos[agent]["action_mask"], masks[i])
            assert infos[agent]["action_mask"].dtype == bool
            scalar_keys = {k for k in bare_infos[agent] if k.startswith("action_mask_")}
            assert len(scalar_keys) == masks.shape[1] and not scalar_keys & set(infos[agent])
            assert {k: v for k, v in bare_infos[agent].items() if k not in scalar_keys} == {
                k: v for k, v in infos[agent].items() if k != "action_mask"
            }
        actions = {a: int(rng.integers(masks.shape[1])) for a in bare.agents}
        *_, infos = env.step(actions)
        *_, bare_infos = bare.step(actions)
        if not bare.agents:
            break


def test_action_mask_wrapper_leaves_unmasked_envs_alone():
    env = make_parallel_env("MapSync-v0", max_cycles=3)
    bare = mrcomm_env.make("MapSync-v0", max_cycles=3)
    assert env.reset(seed=0)[1] == bare.reset(seed=0)[1]
    assert env.state_space == bare.state_space and np.array_equal(env.state(), bare.state())


def test_the_adapters_refuse_masks_over_multibinary_select_bits():
    """TorchRL masks Discrete specs only: MultiHop's ``mask_unheld`` (masked select bits) is refused by name, rather
    than sampled as if unmasked; without it the same env passes."""
    kwargs = {"grid_side": 3, "max_cycles": 3}
    with pytest.raises(ValueError, match="MultiBinary actions.*'mask_unheld'"):
        make_parallel_env("MultiHop-v0", mask_unheld=True, **kwargs)
    env = make_parallel_env("MultiHop-v0", **kwargs)
    assert "action_mask" not in env.reset(seed=0)[1]["robot_0"]


def test_benchmarl_task_family_without_benchmarl_names_the_extra(monkeypatch):
    # the task family subclasses BenchMARL's classes, so the module itself needs the framework
    for name in [
        m for m in list(sys.modules) if m.split(".")[0] == "benchmarl" or m == "mrcomm_env.integrations.benchmarl"
    ]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "benchmarl", None)
    with pytest.raises(ImportError) as error:
        importlib.import_module("mrcomm_env.integrations.benchmarl")
    message = str(error.value)
    assert "pip install 'mrcomm-env[benchmarl]'" in message and "\n" not in message
