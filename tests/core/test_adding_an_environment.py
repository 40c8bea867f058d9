"""A sixth environment, added as docs/adding-an-environment.md says, with no edit anywhere in the package.

The env below (``Gossip-v0``: each robot holds a token and decides when to broadcast it over lossy links) is
defined here, in this test module, which also serves as its shim (``parallel_env``), its scripted baselines
(``POLICIES``) and its reproduction (``EXPERIMENTS``, ``run``): the three modules an ``EnvEntry`` names. It is
registered through the public API (``mrcomm_env.registry.register``), and then

* the suite's own conformance, determinism, seed, action, limits and memory tests run on it, unchanged: in a
  pytest process that loads this module as a plugin (``-p``), which registers the env before collection, so
  every test parametrized over ``env_ids()`` gets a ``Gossip-v0`` case;
* its docs page is generated and lists every argument, metric and baseline, and the CLI lists, evaluates and
  reproduces it, in this process, with the env registered for the test's duration only.

It has no learning configuration and ships no pretrained model: nothing requires one of it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from gymnasium import spaces

from mrcomm_env.core.base import MrcommParallelEnv
from mrcomm_env.core.comm import BitLedger
from mrcomm_env.core.config import Int, Param, Real
from mrcomm_env.core.policy import LocalViews, Policy
from mrcomm_env.registry import EnvEntry, env_ids, register, unregister
from mrcomm_env.testing import DECLARED_CHECKS, GENERIC_CHECKS, check_env

ENV_ID = "mrcomm/Gossip-v0"
TOKEN_BITS = 32  #: a broadcast carries the sender's token and every token it has heard: 32 bits each
MAX_ROBOTS = 4096


class GossipEnv(MrcommParallelEnv):
    """Gossip: each of N robots holds a token; a robot that broadcasts sends every token it knows to each
    other robot, and each copy arrives with probability ``p_link``. Episodes last ``max_cycles`` steps. Reward per step, shared: minus the fraction of (robot, token) pairs still unknown, minus ``lam``
    times the bits sent per robot over ``TOKEN_BITS · N`` (a full broadcast of N tokens costs ``lam``)."""

    ENV_ID = ENV_ID
    DESCRIPTION = "Each robot decides when to broadcast the tokens it knows over lossy links."
    PARAMS = {
        "n_robots": Param(8, "number of robots N", Int(lo=2, hi=MAX_ROBOTS, fuzz=(2, 16))),
        "p_link": Param(0.5, "probability that one broadcast reaches one other robot", Real(0.0, 1.0)),
        "lam": Param(0.1, "price of a full broadcast (N tokens) in the reward", Real(0.0, 100.0, fuzz=(0.0, 1.0))),
        "max_cycles": Param(100, "steps per episode", Int(lo=1, hi=2**31, fuzz=(1, 50))),
    }
    METRICS = {
        "known_fraction": "fraction of (robot, token) pairs known",
        "bits_sent": "bits sent by all robots over the episode",
        "completion_step": "step at which every robot knew every token (−1: not yet)",
    }
    INFO_KEYS = {"known": "fraction of the tokens this robot knows", "bits_sent": "bits this robot sent this step"}
    LOCAL_VIEW = {"known_count": "how many tokens the robot knows"}
    DOCUMENTED_CONFIGS = {"default": {}, "small_team": {"n_robots": 3, "p_link": 0.9}}
    LIMIT_CONFIGS = {"most_robots": {"n_robots": MAX_ROBOTS, "max_cycles": 2**31}}
    VERSION_HISTORY = [("v0", "first version")]
    MEMORY_FORMULA = "1 MiB + 10·N² bytes for N robots (who knows which token; a step's random draws, 8 bytes per link)"
    MEMORY_ARGS = ("n_robots",)
    MEMORY_PROBES = {"small": {"n_robots": 1024}, "medium": {"n_robots": 2048}, "large": {"n_robots": 4096}}

    @classmethod
    def memory_estimate(cls, cfg) -> float:
        n = float(cfg["n_robots"])
        return 2.0**20 + 10.0 * n * n

    def _setup(self) -> None:
        self.n_agents = self.cfg.n_robots
        # own fraction known, team fraction known, link probability, clock: each in [0, 1]
        self._obs_space = spaces.Box(0.0, 1.0, shape=(4,), dtype=np.float32)
        self._act_space = spaces.Discrete(2)  # 0 silent, 1 broadcast

    def _reset_world(self) -> None:
        n = self.n_agents
        self.known = np.eye(n, dtype=bool)  # known[i, j]: robot i knows robot j's token
        self.ledger = BitLedger(n)
        self.completion_step = -1
        self._bits_now = np.zeros(n)

    def _step_world(self, actions) -> float:
        n = self.n_agents
        senders = np.flatnonzero(np.asarray(actions) == 1)
        bits = np.zeros(n)
        if senders.size:
            bits[senders] = TOKEN_BITS * self.known[senders].sum(axis=1)
            arrives = self.np_random.random((senders.size, n)) < self.cfg.p_link
            for k, sender in enumerate(senders):
                self.known[arrives[k]] |= self.known[sender]
        self.ledger.record(bits, messages=int(senders.size))
        self._bits_now = bits
        unknown = 1.0 - self.known.mean()
        if unknown == 0.0 and self.completion_step < 0:
            self.completion_step = self.step_count + 1
        return -unknown - self.cfg.lam * bits / (TOKEN_BITS * n)

    def _observe(self) -> np.ndarray:
        own = self.known.mean(axis=1)
        clock = min(self.step_count / self.cfg.max_cycles, 1.0)
        common = [self.known.mean(), self.cfg.p_link, clock]
        return np.column_stack([own, np.broadcast_to(common, (self.n_agents, 3))]).astype(np.float32)

    def _agent_infos(self) -> dict[str, Any]:
        return {"known": self.known.mean(axis=1), "bits_sent": self._bits_now}

    def _local_view(self) -> dict[str, Any]:
        return {"known_count": self.known.sum(axis=1)}

    def _metrics(self) -> dict[str, float]:
        return {
            "known_fraction": float(self.known.mean()),
            "bits_sent": self.bits_sent(),
            "completion_step": float(self.completion_step),
        }


# -------------------------------------------------------------------------------------------- the shim
parallel_env = raw_env = GossipEnv


def env(**kwargs):
    from pettingzoo.utils import parallel_to_aec

    return parallel_to_aec(GossipEnv(**kwargs))


# ---------------------------------------------------------------------------------------- the baselines
class BroadcastWhileLearning(Policy):
    """Broadcast on the first step, then whenever the robot learned a token since its last broadcast."""

    name = "broadcast_while_learning"

    def reset(self, views: LocalViews, seed: int | None = None) -> None:
        super().reset(views, seed)
        self._last = {agent: 0 for agent in views.possible_agents}

    def act(self, observations, views):
        actions = {}
        for agent in observations:
            count = int(views[agent]["known_count"])
            actions[agent] = int(count > self._last[agent])
            if actions[agent]:
                self._last[agent] = count
        return actions


class Silent(Policy):
    name = "silent"

    def act(self, observations, views):
        return dict.fromkeys(observations, 0)


POLICIES = {"broadcast_while_learning": BroadcastWhileLearning, "silent": Silent}
DEFAULT_POLICY = "broadcast_while_learning"


# -------------------------------------------------------------------------------------- the reproduction
EXPERIMENTS = {"completion": "steps until every robot knows every token, per link probability"}


def run(out_dir: Path, quick: bool, tiny: bool = False) -> str:
    from mrcomm_env.experiments.evaluation import run_episode
    from mrcomm_env.experiments.io import atomic_write_text

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for p_link in (0.5, 1.0):
        env = GossipEnv(p_link=p_link)
        metrics = run_episode(env, BroadcastWhileLearning(), seed=0)
        rows.append({"p_link": p_link, **metrics})
    atomic_write_text(out / "completion.json", json.dumps(rows) + "\n")
    table = "\n".join(f"| {r['p_link']} | {r['completion_step']:.0f} |" for r in rows)
    return f"## {ENV_ID}\n\n| p_link | completion step |\n| --- | --- |\n{table}\n"


# ----------------------------------------------------------------------------------------- registration
ENTRY = EnvEntry(env=__name__, policies=__name__, reproduction=__name__, paper="A test, *Gossip*")


def pytest_configure(config) -> None:
    """Loaded with ``-p``: register the env before the suite collects its tests over ``env_ids()``."""
    register(ENV_ID, ENTRY)


# ------------------------------------------------------------------------------------------------ tests
#: this folder: the suite's shared checks live here, and the subprocess imports this module from it as a plugin
CORE = Path(__file__).resolve().parent
REPO = CORE.parents[1]
#: the suite's checks that every env gets, parametrized over the registry (in ``CORE``)
SHARED_CHECKS = ["test_conformance.py", "test_actions_and_seeds.py", "test_limits.py", "test_memory.py"]


@pytest.fixture
def gossip_registered():
    register(ENV_ID, ENTRY)
    try:
        yield ENV_ID
    finally:
        unregister(ENV_ID)


def test_the_suites_checks_run_on_a_registered_sixth_env():
    run_env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(CORE), os.environ.get("PYTHONPATH")]))}
    command = [sys.executable, "-m", "pytest", "-p", __name__, "-q", "-p", "no:cacheprovider", "-n", "0"]
    command += ["-k", "Gossip", "--timeout", "600", *(str(CORE / name) for name in SHARED_CHECKS)]
    result = subprocess.run(command, cwd=REPO, env=run_env, capture_output=True, text=True, timeout=900)
    summary = result.stdout.strip().splitlines()[-1] if result.stdout.strip() else result.stderr[-2000:]
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    passed = int(summary.split(" passed")[0].split()[-1])
    # one case per shared check at least: API, seeds, AEC, state, render, determinism, fuzz, limits, memory …
    assert passed >= 30 and "failed" not in summary and "error" not in summary, summary


def test_register_refuses_bad_ids_and_duplicates(gossip_registered):
    with pytest.raises(ValueError, match="already registered"):
        register(ENV_ID, ENTRY)
    with pytest.raises(ValueError, match="argument 'env_id'"):
        register("Gossip-v1", ENTRY)


def test_its_docs_page_cli_and_reproduction_come_from_the_registry(gossip_registered, tmp_path, capsys):
    from mrcomm_env.experiments.cli import main
    from mrcomm_env.experiments.docs import expected_docs

    assert ENV_ID in env_ids()
    pages = {path.name: text for path, text in expected_docs(tmp_path).items()}
    page = pages["Gossip-v0.md"]
    assert all(f"`{name}`" in page for name in (*GossipEnv.PARAMS, *GossipEnv.METRICS, *POLICIES))
    assert ENV_ID in pages["index.md"]
    assert main(["list"]) == 0 and "Gossip-v0" in capsys.readouterr().out
    out = tmp_path / "eval.json"
    assert (
        main(["evaluate", "Gossip-v0", "--policy", DEFAULT_POLICY, "--episodes", "2", "--quiet", "--json", str(out)])
        == 0
    )
    metrics = json.loads(out.read_text())["metrics"]
    assert 1 / 8 < metrics["known_fraction"]["mean"] <= 1.0 and metrics["bits_sent"]["mean"] >= 8 * TOKEN_BITS
    assert main(["reproduce", "Gossip-v0", "--tiny", "--out", str(tmp_path / "results")]) == 0
    assert len(list((tmp_path / "results").rglob("completion.json"))) == 1
    # what a policy chooses beside another, with the base class's names for the actions (the index)
    profile_path = tmp_path / "actions.json"
    argv = ["actions", "Gossip-v0", "--policy", DEFAULT_POLICY, "--against", "silent", "--episodes", "2"]
    assert main([*argv, "--json", str(profile_path)]) == 0
    profile = json.loads(profile_path.read_text())
    assert profile["labels"] == ["0", "1"] and profile["counts"]["silent"] == {"0": profile["decisions"]}
    assert profile["same"]["silent"] == profile["counts"][DEFAULT_POLICY]["0"]  # agreeing with silence is silence
    assert profile["by_context"] == {}  # the env names no situations


def test_the_baseline_finishes_and_silence_never_does():
    from mrcomm_env.experiments.evaluation import run_episode

    env = GossipEnv(n_robots=6, p_link=1.0)
    done = run_episode(env, BroadcastWhileLearning(), seed=3)
    assert done["known_fraction"] == 1.0 and done["completion_step"] == 1  # lossless: one round of broadcasts
    # step 1: each robot sends its own token; step 2: each, having learned 5, sends all 6; then nobody learns more
    assert done["bits_sent"] == 6 * TOKEN_BITS + 6 * 6 * TOKEN_BITS
    silent = run_episode(GossipEnv(n_robots=6), Silent(), seed=3)
    assert silent["completion_step"] == -1 and silent["bits_sent"] == 0 and silent["known_fraction"] == 1 / 6


def test_the_conformance_kit_passes_on_the_sixth_env():
    # what docs/adding-an-environment.md tells a user to run on their own env, without our suite
    assert check_env(GossipEnv) == [*GENERIC_CHECKS, *DECLARED_CHECKS]
