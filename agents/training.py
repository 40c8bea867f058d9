"""Parameter-shared training of one SB3 policy for every agent of an env (``mrcomm train``).

A run folder holds everything needed to evaluate, resume or reproduce it:

* ``config.json`` — env id and arguments, algorithm, hyperparameters, seed, package versions, git commit;
* ``model.zip`` and ``vecnormalize.json`` — the final policy and its observation/return statistics, in formats
  that load without running code from the folder (``agents/artifacts.py``);
* ``checkpoints/step-<agent-steps>/`` — the last two checkpoints (model with optimizer state, statistics,
  timestep count), so that one damaged by a crash mid-write still leaves the other;
* ``progress.csv`` and TensorBoard event files — SB3's own logger;
* ``done.json`` — written last, when the run finished;
* ``.lock`` — held (``flock``) by the process training the run, with its pid: a second one is refused, and the
  lock goes with its holder however it ends (``kill -9`` included).

``--resume`` continues from the newest loadable checkpoint with the same timestep count, optimizer state and
normalisation statistics, and appends to ``progress.csv`` (rows past the checkpoint, logged by the interrupted
process, are dropped so that the log stays continuous). ``--resume --timesteps N`` extends a finished run to N
agent-steps. A run stopped before its first checkpoint has nothing to resume: a fresh ``train`` starts it over.
"""

from __future__ import annotations

import contextlib
import csv
import fcntl
import importlib
import io
import json
import math
import os
import platform
import shutil
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from functools import partial
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import CSVOutputFormat, Logger, make_output_format
from stable_baselines3.common.vec_env import VecMonitor, VecNormalize
from tqdm.auto import tqdm

from mrcomm_agents import batched_ppo
from mrcomm_agents.artifacts import (
    MODEL_FILE,
    PICKLED_STATISTICS_FILE,
    STATISTICS_FILE,
    ModelSpec,
    PickleRefused,
    RunError,
    load_model,
    pickle_refusal,
    pickled_entries,
    read_json,
    read_statistics,
    refuse_pickles,
    save_model,
    save_statistics,
    sb3_settings,
    schedule_start,
    strip_pickles,
    unpickle_statistics,
    write_bytes_atomically,
    write_json,
)
from mrcomm_agents.batched_ppo import (
    BATCHED_ALGORITHMS,
    BatchedPPO,
    build_model,
    default_copies,
    detached_normalizer,
    make_critic,
    masks_actions,
)
from mrcomm_agents.heldout import SECONDS_KEY, TRAINING_SECONDS_KEY, HeldOutEvaluation, TrainingClock, record_heldout
from mrcomm_agents.policies import CandidatePolicy, MaskableCandidatePolicy
from mrcomm_agents.vecenv import AgentSlotVecEnv
from mrcomm_agents.warm_start import CriticWarmup, clone
from mrcomm_env.core.batched import BatchedEnv
from mrcomm_env.core.config import Int, Optional, Real
from mrcomm_env.core.policy import Policy
from mrcomm_env.core.sharded import stepping_batch
from mrcomm_env.registry import canonical_id, make, short_name

CONFIG_DIR = Path(__file__).with_name("configs")
POLICY_NAMES = ("mlp", "candidates", "candidate_set", "candidate_subset")
#: algorithms ``mrcomm train`` knows: name → (module, class); MaskablePPO needs the env's action masks. ``ippo``
#: and ``mappo`` are the batched trainer (``agents/batched_ppo.py``): their model is an SB3 PPO (MaskablePPO where
#: the env masks actions, :func:`algorithm_class`) whose policy that trainer trains
ALGORITHMS = {
    "ppo": ("stable_baselines3", "PPO"),
    "maskable_ppo": ("sb3_contrib", "MaskablePPO"),
    "dqn": ("stable_baselines3", "DQN"),
    "ippo": ("stable_baselines3", "PPO"),
    "mappo": ("stable_baselines3", "PPO"),
}
#: the file beside ``model.zip`` holding MAPPO's centralised critic and its optimizer (tensors only)
CRITIC_FILE = "critic.pt"
#: the run folder's copy of the warm start's clone as cloned, the frozen teacher of kickstarting (SB3's archive,
#: without pickles); a resumed run reads it again
KICKSTART_TEACHER_FILE = "warm_start_model.zip"
#: arguments of ``train`` that are not the algorithm's own hyperparameters
RUN_KEYS = (
    "n_envs",
    "normalize",
    "checkpoint_every",
    "net_arch",
    "critic_arch",
    "policy",
    "init_from",
    "eval_every",
    "eval_episodes",
    "eval_deterministic",
    "critic_warmup",
    "freeze_normalization",
    "update_threads",
    "env_workers",
    "kickstart_coef",
    "kickstart_steps",
)
#: the documented ranges of the SB3 hyperparameters (a value outside is refused before any training)
HYPERPARAMETER_RANGES = {
    "learning_rate": Real(0.0, lo_open=True),
    "gamma": Real(0.0, 1.0),
    "gae_lambda": Real(0.0, 1.0),
    "clip_range": Real(0.0, lo_open=True),
    "clip_range_vf": Optional(Real(0.0, lo_open=True)),
    "ent_coef": Real(0.0),
    "vf_coef": Real(0.0),
    "max_grad_norm": Real(0.0, lo_open=True),
    "target_kl": Optional(Real(0.0, lo_open=True)),
    "n_steps": Int(lo=1),
    "batch_size": Int(lo=1),
    "n_epochs": Int(lo=1),
    "buffer_size": Int(lo=1),
    "learning_starts": Int(lo=0),
    "tau": Real(0.0, 1.0),
    "train_freq": Int(lo=1),
    "gradient_steps": Int(lo=-1),
    "target_update_interval": Int(lo=1),
    "exploration_fraction": Real(0.0, 1.0),
    "exploration_initial_eps": Real(0.0, 1.0),
    "exploration_final_eps": Real(0.0, 1.0),
}
#: checkpoints kept: the newest may be damaged by a crash while it is written; the one before it then serves
KEEP_CHECKPOINTS = 2
#: which checkpoint holds the run's best policy by held-out return (:class:`BestCheckpoint`), and its evaluation
BEST_FILE = "best.json"
#: the held-out mean that ranks the checkpoints: the return, the env's reward with the price of its bits, which is
#: what PPO maximises and what rl-zoo3's ``best_model`` is chosen by
BEST_BY = "episode_return"
LOCK_NAME = ".lock"


@dataclass
class TrainConfig:
    env_id: str
    algo: str = "ppo"
    timesteps: int = 200_000  #: agent-steps (each agent slot's step counts once, as SB3 counts them)
    seed: int = 0
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    hyperparams: dict[str, Any] = field(default_factory=dict)
    #: copies of the parallel env (the VecEnv has n_envs × N agent slots; ippo/mappo step them as one world);
    #: None: 4 for the SB3 algorithms, :func:`~mrcomm_agents.batched_ppo.default_copies` for ippo/mappo
    n_envs: int | None = None
    normalize: bool = True  #: VecNormalize on observations and returns
    net_arch: list[int] = field(default_factory=lambda: [64, 64])
    #: mappo: the hidden layers of the centralised critic (None: ``net_arch``). The critic reads every robot's
    #: observation (MultiHop's 36 robots: 7,668 numbers) through its first layer, where the actor reads one robot's
    critic_arch: list[int] | None = None
    #: ``mlp`` (SB3's MlpPolicy), ``candidates`` (one shared scorer per candidate, ``agents/policies.py``; needs
    #: an env whose ``observation_layout()`` lists candidates), ``candidate_set`` (the same, each candidate also
    #: scored against a summary of the whole list) or ``candidate_subset`` (``candidate_set`` whose select bits are
    #: one draw of at most ``choose`` candidates, ``SubsetDistribution``)
    policy: str = "mlp"
    checkpoint_every: int = 50_000  #: agent-steps between checkpoints
    #: ``baseline:NAME``: clone that scripted policy's decisions before PPO (``agents/warm_start.py``); the caller
    #: passes the policy itself to :func:`train` as ``teacher``
    init_from: str | None = None
    #: held-out evaluation while training (``agents/heldout.py``): every ``eval_every`` agent-steps (0: only at
    #: the end), ``eval_episodes`` episodes (0: none), the policy acting deterministically or not
    eval_every: int = 50_000
    eval_episodes: int = 2
    eval_deterministic: bool = True
    #: agent-steps at the start of PPO during which only the critic learns (the actor is frozen); meant for a
    #: warm start, whose critic was fitted to the rollouts of other policies
    critic_warmup: int = 0
    #: after a warm start, keep VecNormalize's statistics as the clone was fitted with them (else PPO keeps
    #: updating them, which moves a fitted policy's inputs)
    freeze_normalization: bool = False
    #: ippo/mappo: torch threads of the update (None: min(2, cores), ``batched_ppo.BatchedPPO``). The trained bits
    #: depend on it (torch splits its sums by thread), so it is a setting of the run, kept on ``--resume``. Two
    #: trainings started by hand on two cores each want 1: with two each, their spinning threads made them slower
    #: together than one after the other (docs/performance.md, "update threads")
    update_threads: int | None = None
    #: ippo/mappo: processes that step the copies, this one included (None: ``core.sharded.default_workers``, two
    #: on two or more cores where the env's copies step one after another, as AsyncCL's and RendezvousMapping's
    #: do, else one). Every copy steps the same either way, so the run's numbers do not depend on it: only its speed
    env_workers: int | None = None
    #: ippo/mappo after a warm start: kickstarting (Schmitt et al. 2018). The policy's negative log-likelihood of
    #: what the warm start's clone, frozen as cloned (:data:`KICKSTART_TEACHER_FILE`), chooses (its mode) at every
    #: state of the rollout is added to PPO's loss with this weight, which falls linearly to 0 over the first
    #: ``kickstart_steps`` agent-steps: the policy starts near its teacher and is then free to leave it. It needs
    #: ``freeze_normalization`` (with ``normalize``): the teacher reads observations as it was fitted to them
    kickstart_coef: float = 0.0
    kickstart_steps: int = 0

    def _validate_kickstart(self) -> None:
        coef = self.kickstart_coef
        if isinstance(coef, bool) or not isinstance(coef, (int, float)) or not 0.0 <= coef < math.inf:
            raise ValueError(f"argument 'kickstart_coef' must be a number ≥ 0, got {coef!r}")
        if coef == 0:
            if self.kickstart_steps:
                raise ValueError("argument 'kickstart_steps' needs 'kickstart_coef' > 0 (the weight it lowers to 0)")
            return
        if self.algo not in BATCHED_ALGORITHMS or self.init_from is None:
            raise ValueError(
                f"argument 'kickstart_coef' needs algo ippo or mappo and a warm start ('init_from'), whose clone is "
                f"the teacher; got algo={self.algo!r}, init_from={self.init_from!r}"
            )
        if self.kickstart_steps < 1:
            raise ValueError(
                f"argument 'kickstart_steps' must be an integer ≥ 1 with 'kickstart_coef' > 0 (the agent-steps over "
                f"which its weight falls to 0), got {self.kickstart_steps!r}"
            )
        if self.normalize and not self.freeze_normalization:
            # the frozen clone reads its observations through the statistics it was fitted with; while PPO updated
            # them, the clone's own choices moved (MultiHop: 43.0 s → 54.1 s with the same network, docs/learning.md)
            raise ValueError(
                "argument 'kickstart_coef' needs 'freeze_normalization': true when 'normalize' is on, so that the "
                "clone it pulls toward reads the observations as it was fitted to them"
            )

    def validate(self) -> TrainConfig:
        self.env_id = canonical_id(self.env_id)
        if self.algo not in ALGORITHMS:
            raise ValueError(f"argument 'algo' must be one of {', '.join(ALGORITHMS)}, got {self.algo!r}")
        if self.n_envs is None and self.algo not in BATCHED_ALGORITHMS:
            self.n_envs = 4
        for name in ("timesteps", "n_envs", "checkpoint_every"):
            value = getattr(self, name)
            unset = value is None and name == "n_envs"  # ippo/mappo: default_copies, once the env is made
            if not unset and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
                raise ValueError(f"argument '{name}' must be an integer ≥ 1, got {value!r}")
        for name in ("seed", "eval_every", "eval_episodes", "critic_warmup", "kickstart_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"argument '{name}' must be an integer ≥ 0, got {value!r}")
        self._validate_batched_count("update_threads", f"SB3's {self.algo} trains on one torch thread")
        self._validate_batched_count("env_workers", "SB3's VecEnv steps its copies in one process")
        self._validate_critic_arch()
        self._validate_kickstart()
        if not isinstance(self.freeze_normalization, bool):
            raise ValueError(
                f"argument 'freeze_normalization' must be true or false, got {self.freeze_normalization!r}"
            )
        if self.freeze_normalization and (self.init_from is None or not self.normalize):
            raise ValueError(
                "argument 'freeze_normalization' needs a warm start ('init_from') and 'normalize': it keeps the "
                "statistics the clone was fitted with"
            )
        if not isinstance(self.eval_deterministic, bool):
            raise ValueError(f"argument 'eval_deterministic' must be true or false, got {self.eval_deterministic!r}")
        if self.init_from is not None and not (
            isinstance(self.init_from, str) and self.init_from.startswith("baseline:")
        ):
            raise ValueError(f"argument 'init_from' must be None or 'baseline:NAME', got {self.init_from!r}")
        if self.policy not in POLICY_NAMES:
            raise ValueError(f"argument 'policy' must be one of {', '.join(POLICY_NAMES)}, got {self.policy!r}")
        for name, value in self.hyperparams.items():
            if name in HYPERPARAMETER_RANGES and not callable(value):
                HYPERPARAMETER_RANGES[name](name, schedule_start(name, value))
        env = make(self.env_id, **self.env_kwargs)  # the env's own arguments are checked before any work
        if self.algo in BATCHED_ALGORITHMS:
            self._validate_batched(env)
        if self.policy != "mlp" and env.observation_layout() is None:
            raise ValueError(
                f"policy {self.policy!r} needs an observation of candidates; {self.env_id} with "
                f"{self.env_kwargs} has a flat one"
            )
        if self.policy == "candidate_subset" and not (env.observation_layout() or {}).get("choose"):
            raise ValueError(
                f"policy 'candidate_subset' needs actions that choose a few candidates; {self.env_id} with "
                f"{self.env_kwargs} declares no 'choose' in its observation_layout()"
            )
        env.close()
        return self

    def _validate_critic_arch(self) -> None:
        value = self.critic_arch
        if value is None:
            return
        if (
            not isinstance(value, list | tuple)
            or not value
            or not all(isinstance(h, int) and not isinstance(h, bool) and h >= 1 for h in value)
        ):
            raise ValueError(f"argument 'critic_arch' must be None or a non-empty list of integers ≥ 1, got {value!r}")
        if self.algo != "mappo":
            raise ValueError(
                f"argument 'critic_arch' applies to mappo only (its centralised critic; {self.algo}'s value head "
                f"shares 'net_arch'), got {self.critic_arch!r}"
            )

    def _validate_batched_count(self, name: str, why_not_sb3: str) -> None:
        """``update_threads`` and ``env_workers``: None, or a count ≥ 1 of a batched trainer's run."""
        value = getattr(self, name)
        if value is None:
            return
        if self.algo not in BATCHED_ALGORITHMS:
            raise ValueError(
                f"argument '{name}' applies to {' and '.join(BATCHED_ALGORITHMS)} only ({why_not_sb3}), got {value!r}"
            )
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"argument '{name}' must be None or an integer ≥ 1, got {value!r}")

    def _validate_batched(self, env) -> None:
        """ippo/mappo: the env's spaces (and for mappo its state), the copies' memory and the rollout's sizes."""
        batched_ppo.check_env(env, self.algo)
        if self.n_envs is None:
            self.n_envs = default_copies(env.n_agents)
        BatchedEnv.check_memory(env, int(self.n_envs or 1), "n_envs")  # the copies together, before any work
        if self.env_workers is not None and self.env_workers > int(self.n_envs or 1):
            raise ValueError(
                f"argument 'env_workers' must be at most n_envs = {self.n_envs} (each process steps at least one "
                f"copy), got {self.env_workers}"
            )
        for name in ("n_steps", "batch_size", "n_epochs"):
            value = self.hyperparams.get(name, batched_ppo.DEFAULTS[name])
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"argument '{name}' must be an integer ≥ 1, got {value!r}")


def default_config(env_id: str, algo: str = "ppo") -> dict[str, Any]:
    """The tuned settings shipped in ``agents/configs/<Name>-v0.json`` for ``algo``: empty when none, and for
    ippo/mappo the batched trainer's documented defaults under any shipped ones."""
    path = CONFIG_DIR / f"{short_name(env_id)}.json"
    shipped = json.loads(path.read_text()).get(algo, {}) if path.exists() else {}
    if algo in BATCHED_ALGORITHMS:
        return {**batched_ppo.DEFAULTS, **shipped}
    return shipped


def policy_choice(config: TrainConfig, probe=None) -> tuple[Any, dict[str, Any]]:
    """(policy, policy_kwargs) of a run: SB3's ``MlpPolicy`` with ``net_arch``, or :class:`CandidatePolicy` (its
    masked twin :class:`MaskableCandidatePolicy` under MaskablePPO) with the env's candidate layout; ``probe``: an
    env of the run's arguments (made when not given). Training builds its model from these, and loading rebuilds the
    model's pickled entries from them (``agents/artifacts.py``)."""
    policy_kwargs = dict(config.hyperparams.get("policy_kwargs", {}))
    if config.policy not in ("candidates", "candidate_set", "candidate_subset"):
        policy_kwargs.setdefault("net_arch", list(config.net_arch))
        return "MlpPolicy", policy_kwargs
    own_probe = probe is None
    probe = make(config.env_id, **config.env_kwargs) if own_probe else probe
    policy_kwargs.update(layout=probe.observation_layout(), hidden=int(config.net_arch[0]))
    # MaskablePPO (and the batched trainer on an env that masks actions) passes masks to its policy
    masked = algorithm_class(config.algo, probe).__name__ == "MaskablePPO"
    if own_probe:
        probe.close()
    if config.policy in ("candidate_set", "candidate_subset"):
        policy_kwargs.update(context=True)
    if config.policy == "candidate_subset":
        policy_kwargs.update(subset=True)
    return (MaskableCandidatePolicy if masked else CandidatePolicy), policy_kwargs


def model_spec(config: TrainConfig, venv=None) -> ModelSpec:
    """What :func:`~mrcomm_agents.artifacts.load_model` rebuilds a model of this run from: the algorithm, the
    policy and the spaces of ``venv`` (the run's training VecEnv when resuming), else of an env made with the run's
    arguments."""
    if venv is not None and config.policy == "mlp":  # nothing left to ask an env: the spaces are the VecEnv's
        policy, policy_kwargs = policy_choice(config)
        observation_space, action_space = venv.observation_space, venv.action_space
        algorithm = algorithm_class(config.algo)
    else:
        probe = make(config.env_id, **config.env_kwargs)
        try:
            policy, policy_kwargs = policy_choice(config, probe)
            agent = probe.possible_agents[0]
            observation_space, action_space = probe.observation_space(agent), probe.action_space(agent)
            if venv is not None:
                observation_space, action_space = venv.observation_space, venv.action_space
            algorithm = algorithm_class(config.algo, probe)
        finally:
            probe.close()
    return ModelSpec(
        algorithm=algorithm,
        policy=policy,
        policy_kwargs=policy_kwargs,
        observation_space=observation_space,
        action_space=action_space,
        hyperparams=dict(config.hyperparams),
    )


def load_config_file(path: str | Path, algo: str) -> dict[str, Any]:
    """A user's ``--config`` file: the same JSON shape as ``agents/configs`` (algorithm → settings)."""
    try:
        data = json.loads(Path(path).read_text())
    except OSError as exc:
        raise RunError(f"cannot read --config {path}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise RunError(f"--config {path} is not valid JSON: {exc.msg} at line {exc.lineno}") from None
    if not isinstance(data, dict):
        raise RunError(f"--config {path} must hold a JSON object")
    if not isinstance(data.get(algo), dict):
        sections = ", ".join(repr(k) for k, v in data.items() if isinstance(v, dict) and k in ALGORITHMS) or "none"
        raise RunError(
            f"--config {path} has no section for algorithm '{algo}' (a JSON object under the key \"{algo}\", as in "
            f"agents/configs/); its algorithm sections: {sections}"
        )
    return data[algo]


def split_settings(settings: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(run settings, algorithm hyperparameters) of one config block."""
    run = {k: v for k, v in settings.items() if k in RUN_KEYS or k in ("timesteps", "env_kwargs")}
    hyper = {k: v for k, v in settings.items() if k not in run}
    return run, hyper


def make_training_env(config: TrainConfig, seed: int):
    """The agent-slot VecEnv under a VecMonitor (episode returns in the logs, counted once per agent slot)."""

    env_fns = [lambda: make(config.env_id, **config.env_kwargs) for _ in range(int(config.n_envs or 1))]
    venv = AgentSlotVecEnv(env_fns)
    venv.seed(seed)
    return VecMonitor(venv)


def algorithm_class(algo: str, env=None):
    """The SB3 class of ``algo``'s model; for ippo/mappo on an env that masks actions (``env``), MaskablePPO."""
    module, name = ALGORITHMS[algo]
    if algo in BATCHED_ALGORITHMS and env is not None and masks_actions(env):
        module, name = ALGORITHMS["maskable_ppo"]
    try:
        return getattr(importlib.import_module(module), name)
    except ImportError:
        raise RunError(f"algorithm '{algo}' needs {module}: pip install 'mrcomm-env[train]'") from None


# ------------------------------------------------------------------------------------------------ metadata
def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for dist in ("mrcomm-env", "stable-baselines3", "sb3-contrib", "torch", "gymnasium", "pettingzoo", "numpy"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


def git_commit() -> str | None:
    root = Path(__file__).resolve().parents[1]
    try:
        out = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


# ------------------------------------------------------------------------------------------------ training
class _Progress:
    """A tqdm bar over agent-steps plus periodic checkpoints (SB3's own bar needs ``rich``).

    Checkpoints are taken when a rollout starts, i.e. after the previous rollout has been trained on: a
    checkpoint taken mid-rollout would count steps whose data the optimizer never saw.
    """

    def __init__(self, total: int, start: int, every: int, save, enabled: bool):

        outer = self
        self.rollout_start = start
        self.bar: Any = None  # the callback's, from the start of training
        self.last = self.next_save = start

        class Callback(BaseCallback):
            def _on_training_start(self) -> None:
                outer.bar = tqdm(total=total, initial=start, desc="agent-steps", unit="step", disable=not enabled)
                outer.last = self.num_timesteps
                outer.next_save = (self.num_timesteps // every + 1) * every

            def _on_rollout_start(self) -> None:
                outer.rollout_start = self.num_timesteps
                if self.num_timesteps >= outer.next_save:
                    save(self.model)
                    outer.next_save = (self.num_timesteps // every + 1) * every

            def _on_step(self) -> bool:
                outer.bar.update(self.num_timesteps - outer.last)
                outer.last = self.num_timesteps
                return True

            def _on_training_end(self) -> None:
                outer.bar.close()

        self.callback = Callback()


def train(
    config: TrainConfig | None,
    out: str | Path,
    resume: bool = False,
    progress: bool = True,
    requested: dict[str, Any] | None = None,
    teacher: Policy | None = None,
    trust_pickle: bool = False,
) -> Path:
    """Train (or with ``resume``, continue) the run in folder ``out``; returns the folder.

    With ``resume``, ``requested`` holds the settings the caller named explicitly (``env_id``, ``algo``, ``seed``,
    ``env_kwargs``, ``timesteps``): each must agree with the run's ``config.json`` — except ``timesteps``, which
    may extend the run, a finished one included. ``teacher``: the policy ``config.init_from`` names, cloned
    before PPO starts (a new run only). ``trust_pickle``: resume a run written before ``agents/artifacts.py``'s
    formats (``vecnormalize.pkl``), unpickling its statistics; only for a run the user made."""
    out = Path(out)
    if not resume:
        if config is None:
            raise ValueError("argument 'config' is needed for a new run (only --resume reads it from the run)")
        config.validate()  # a bad setting leaves no folder behind
        if (config.init_from is None) != (teacher is None):
            raise ValueError("pass the policy that 'init_from' names as 'teacher' (and only then)")
    with run_lock(out):  # the folder is created and locked before any work: one that cannot be written fails here
        if resume:
            config = _resumable(out, requested or {}, trust_pickle)
        else:
            if (out / "done.json").exists() or checkpoints(out):
                raise RunError(f"{out} already holds a run; pass --resume to continue it or choose another --out")
            _clear_unstarted(out)  # a run that stopped before its first checkpoint starts over
        assert config is not None  # a new run was given one; a resumed run read its own
        return _train_locked(config, out, resume, progress, teacher, trust_pickle)


def _train_locked(
    config: TrainConfig, out: Path, resume: bool, progress: bool, teacher: Policy | None, trust_pickle: bool = False
) -> Path:

    torch.set_num_threads(1)
    if config.algo in BATCHED_ALGORITHMS:
        return _train_batched(config, out, resume, progress, teacher, trust_pickle)
    ckpt = _open_run_folder(config, out, resume)
    cls = algorithm_class(config.algo)

    venv = make_training_env(config, config.seed)
    clock = TrainingClock()
    if resume:
        model, venv, clock.before = _load_newest_checkpoint(config, ckpt, venv, trust_pickle)
        done_steps = model.num_timesteps
        if config.freeze_normalization and isinstance(venv, VecNormalize):
            venv.training = False  # as the run left them (the checkpoint holds the clone's statistics)
        _cut_progress_log(out / "progress.csv", done_steps)
    else:
        if config.normalize:
            venv = VecNormalize(venv, norm_obs=True, norm_reward=True, gamma=config.hyperparams.get("gamma", 0.99))
        kwargs = {k: v for k, v in sb3_settings(config.hyperparams).items() if k != "policy_kwargs"}
        policy, policy_kwargs = policy_choice(config)
        model = cls(policy, venv, seed=config.seed, device="cpu", verbose=0, policy_kwargs=policy_kwargs, **kwargs)
        done_steps = 0
        if teacher is not None:
            report = clone(model, venv, teacher, config.env_id, config.env_kwargs, config.seed)
            write_json(out / "warm_start.json", {"teacher": config.init_from, **report.as_dict()})
            if config.freeze_normalization and isinstance(venv, VecNormalize):
                # the clone was fitted to these statistics: PPO fine-tunes it in the same input units
                venv.training = False
    csv_log = resumed_csv_output(str(out / "progress.csv")) if resume else make_output_format("csv", str(out))
    model.set_logger(Logger(str(out), [csv_log, make_output_format("tensorboard", str(out))]))

    def save(m) -> None:
        _save_checkpoint(m, config, ckpt, clock=clock)

    bar = _Progress(config.timesteps, done_steps, config.checkpoint_every, save, progress)
    callbacks: list[BaseCallback] = [bar.callback]
    if config.eval_episodes:
        best = BestCheckpoint(out, done_steps if resume else None)

        def save_evaluated(final: bool) -> Path:
            # a rollout's evaluation scores the policy before the update on that rollout: it is saved under the
            # rollout's start, as an interrupted run is (its normalisation already counts the rollout's observations)
            steps = model.num_timesteps
            if not final:
                model.num_timesteps = bar.rollout_start
            try:
                return _save_checkpoint(model, config, ckpt, clock=clock)
            finally:
                model.num_timesteps = steps

        every = config.eval_every or config.timesteps + 1
        callbacks.append(
            HeldOutEvaluation(
                config.env_id,
                config.env_kwargs,
                every,
                config.eval_episodes,
                config.eval_deterministic,
                clock,
                on_evaluated=lambda means, final: best.offer(means, model.num_timesteps, lambda: save_evaluated(final)),
            )
        )
    if config.critic_warmup:
        callbacks.append(CriticWarmup(config.critic_warmup))
    remaining = config.timesteps - done_steps
    clock.start()
    try:
        model.learn(total_timesteps=remaining, callback=CallbackList(callbacks), reset_num_timesteps=not resume)
    except KeyboardInterrupt:
        # an interrupted run resumes from the start of the rollout it was collecting: those steps were not
        # trained on yet, so they are not counted
        model.num_timesteps = bar.rollout_start
        save(model)
        raise
    save(model)
    _save_files(model, config, out, clock=clock)
    write_json(out / "done.json", {"num_timesteps": int(model.num_timesteps)})
    venv.close()
    return out


def _open_run_folder(config: TrainConfig, out: Path, resume: bool) -> Path:
    """The run's checkpoint folder, made; a new run's ``config.json`` written first (with versions and commit)."""
    ckpt = out / "checkpoints"
    ckpt.mkdir(exist_ok=True)
    if not resume:
        record = {**asdict(config), "versions": package_versions(), "git_commit": git_commit()}
        write_json(out / "config.json", record)
    return ckpt


def _train_batched(
    config: TrainConfig, out: Path, resume: bool, progress: bool, teacher: Policy | None, trust_pickle: bool
) -> Path:
    """ippo/mappo: the same run folder, checkpoints, logs, held-out rows and interrupt handling as the SB3 path,
    with :class:`~mrcomm_agents.batched_ppo.BatchedPPO` stepping ``n_envs`` copies as one world."""
    ckpt = _open_run_folder(config, out, resume)
    model, normalizer, critic, critic_optimizer, clock = _batched_model(config, out, resume, teacher, trust_pickle)
    done_steps = int(model.num_timesteps)
    if resume:
        _cut_progress_log(out / "progress.csv", done_steps)
    # the copies' stepping processes (config.env_workers, or as many as pay off): the same numbers whatever their count
    batch = stepping_batch(
        partial(make, config.env_id, **config.env_kwargs), int(config.n_envs or 1), config.env_workers, copy=False
    )
    trainer = _batched_trainer(config, out, model, batch, normalizer, critic, critic_optimizer, trust_pickle)
    csv_log = resumed_csv_output(str(out / "progress.csv")) if resume else make_output_format("csv", str(out))
    model.set_logger(Logger(str(out), [csv_log, make_output_format("tensorboard", str(out))]))

    def save(again: bool = False) -> Path:
        # nothing changes the trainer's state between an update, its held-out evaluation and the next rollout's
        # start, so a checkpoint of the same step already written holds this very state
        return _save_checkpoint(model, config, ckpt, normalizer, trainer.critic_state(), clock, again)

    every = config.checkpoint_every
    next_save = [(done_steps // every + 1) * every]
    rollout_start = [done_steps]
    evaluate_every = config.eval_every or config.timesteps + 1
    next_eval = [(done_steps // evaluate_every + 1) * evaluate_every]

    evaluating = [0.0]  # seconds in held-out evaluations since training started (SECONDS_KEY)
    best = BestCheckpoint(out, done_steps if resume else None)

    def heldout() -> None:
        if config.eval_episodes:
            # evaluations run inside learn()'s clock: training's own time is that clock minus them
            model.logger.record(TRAINING_SECONDS_KEY, clock.seconds())
            spent, means = record_heldout(
                model.logger,
                model,
                normalizer,
                config.env_id,
                config.env_kwargs,
                config.eval_episodes,
                config.eval_deterministic,
            )
            evaluating[0] += spent
            if clock.started is not None:
                clock.evaluating += spent
            model.logger.record(SECONDS_KEY, evaluating[0])
            # after an update: the evaluated policy is the one a checkpoint taken now holds
            best.offer(means, model.num_timesteps, save)

    def on_rollout_start() -> None:
        rollout_start[0] = model.num_timesteps
        if model.num_timesteps >= next_save[0]:
            save()
            next_save[0] = (model.num_timesteps // every + 1) * every

    def on_rollout_end() -> None:
        if model.num_timesteps >= next_eval[0]:
            heldout()
            next_eval[0] = (model.num_timesteps // evaluate_every + 1) * evaluate_every

    if not resume and config.eval_episodes:  # the starting point of the curve (a warm start's clone, or chance)
        heldout()
        evaluating[0] = 0.0  # before training starts: not inside time/time_elapsed
        model.logger.record(SECONDS_KEY, 0.0)
        model.logger.record("time/total_timesteps", 0)
        model.logger.record("time/time_elapsed", 0.0)
        model.logger.dump(0)
    bar = tqdm(total=config.timesteps, initial=done_steps, desc="agent-steps", unit="step", disable=not progress)
    clock.start()
    try:
        trainer.learn(config.timesteps, on_rollout_start, on_rollout_end, bar.update)
    except KeyboardInterrupt:
        # as the SB3 path: the rollout being collected was not trained on, so its steps are not counted
        model.num_timesteps = rollout_start[0]
        save(again=True)  # the statistics may have seen part of the rollout: as before, they are kept
        raise
    finally:
        bar.close()
        batch.close()  # its worker processes too; the held-out evaluations below step envs of their own
    save()
    if config.eval_episodes:  # the final policy's row, as the SB3 path's last one
        before = evaluating[0]
        heldout()
        model.logger.record("time/total_timesteps", model.num_timesteps)
        model.logger.record("time/time_elapsed", trainer.elapsed + evaluating[0] - before)
        model.logger.dump(model.num_timesteps)
    _save_files(model, config, out, normalizer, trainer.critic_state(), clock)
    write_json(out / "done.json", {"num_timesteps": int(model.num_timesteps)})
    model.logger.close()
    return out


def _batched_model(config: TrainConfig, out: Path, resume: bool, teacher: Policy | None, trust_pickle: bool):
    """(model, normalizer, critic, critic optimizer, training clock) of an ippo/mappo run: new (with the warm start,
    if any) or from its newest checkpoint; the critic and its optimizer are None for ippo."""
    probe = make(config.env_id, **config.env_kwargs)
    agent = probe.possible_agents[0]
    observation_space, action_space = probe.observation_space(agent), probe.action_space(agent)
    critic_state = None
    clock = TrainingClock()
    if resume:
        model, normalizer, critic_state, clock.before = _load_newest_batched(config, out, trust_pickle)
        if config.freeze_normalization and normalizer is not None:
            normalizer.training = False
    else:
        policy, policy_kwargs = policy_choice(config, probe)
        model = build_model(
            algorithm_class(config.algo, probe),
            policy,
            policy_kwargs,
            observation_space,
            action_space,
            sb3_settings(config.hyperparams),
            config.seed,
        )
        normalizer = detached_normalizer(observation_space.shape, model.gamma) if config.normalize else None
        if teacher is not None:
            report = clone(model, normalizer, teacher, config.env_id, config.env_kwargs, config.seed)
            write_json(out / "warm_start.json", {"teacher": config.init_from, **report.as_dict()})
            if config.kickstart_coef:
                save_model(model, out / KICKSTART_TEACHER_FILE)  # kickstarting's teacher, as cloned
            if config.freeze_normalization and normalizer is not None:
                normalizer.training = False  # the clone was fitted to these statistics
    n_agents = probe.n_agents
    probe.close()
    critic = critic_optimizer = None
    if config.algo == "mappo":
        obs_dim = int(np.prod(observation_space.shape or (1,)))
        critic_arch = config.net_arch if config.critic_arch is None else config.critic_arch
        critic, critic_optimizer = make_critic(n_agents, obs_dim, critic_arch, model.lr_schedule(1), critic_state)
    return model, normalizer, critic, critic_optimizer, clock


def _batched_trainer(config: TrainConfig, out: Path, model, batch, normalizer, critic, critic_optimizer, trust_pickle):
    """The :class:`BatchedPPO` of a run, with its critic warm-up and kickstarting."""
    # a resumed run continues on other episodes than those it trained on before the interruption
    seed = config.seed + int(model.num_timesteps)
    trainer = BatchedPPO(model, batch, normalizer, seed, critic, critic_optimizer, config.update_threads)
    trainer.critic_warmup_until = config.critic_warmup
    if config.kickstart_coef:
        trainer.kickstart(_kickstart_teacher(config, out, trust_pickle), config.kickstart_coef, config.kickstart_steps)
    return trainer


def _kickstart_teacher(config: TrainConfig, out: Path, trust_pickle: bool):
    """The warm start's clone as cloned (:data:`KICKSTART_TEACHER_FILE`), frozen: kickstarting's teacher."""
    path = out / KICKSTART_TEACHER_FILE
    if not path.exists():
        raise RunError(f"{path} is missing (a run with 'kickstart_coef' keeps its warm start's clone there)")
    policy = load_model(path, model_spec(config), trust_pickle=trust_pickle).policy
    policy.set_training_mode(False)
    policy.requires_grad_(False)
    return policy


def _load_newest_batched(config: TrainConfig, out: Path, trust_pickle: bool):
    """(model, normalizer, critic state or None, training seconds) of an ippo/mappo run's newest checkpoint that
    loads."""
    spec = model_spec(config)

    def load(folder: Path):
        normalizer = read_statistics(folder, trust_pickle=trust_pickle) if config.normalize else None
        model = load_model(folder / MODEL_FILE, spec, trust_pickle=trust_pickle)
        model.num_timesteps, seconds = read_state(folder)
        critic_state = _load_critic(folder) if config.algo == "mappo" else None
        if normalizer is not None:
            normalizer.training = True  # saved as they were used; training goes on updating them
        return model, normalizer, critic_state, seconds

    return _newest_loadable(out, trust_pickle, load)


def _load_critic(folder: Path) -> dict[str, Any]:
    """MAPPO's critic and its optimizer, through ``torch.load(weights_only=True)``: tensors and plain containers
    only, nothing that runs code."""
    path = folder / CRITIC_FILE
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise RunError(f"{path} is missing (a mappo run keeps its critic there)") from None
    except Exception as exc:  # torch raises UnpicklingError (refused content) or RuntimeError (a damaged archive)
        raise RunError(f"cannot load {path}: {type(exc).__name__}: {str(exc).splitlines()[0][:200]}") from None
    if not isinstance(state, dict) or not {"critic", "optimizer"} <= set(state):
        raise RunError(f"{path} is corrupt: it must hold 'critic' and 'optimizer'")
    return state


# ------------------------------------------------------------------------------------------------ run folders
@contextlib.contextmanager
def run_lock(out: Path) -> Iterator[None]:
    """Hold ``out/.lock`` while training: a second process on the same run is refused, naming the holder."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd = os.open(out / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise RunError(f"cannot write the run folder {out}: {exc.strerror or exc}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            raise RunError(
                f"{out} is being trained by another process (pid {holder}); wait for it to end or use another --out"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock (the kernel does the same when the process dies)


def convert_run(out: Path, trust_pickle: bool = False) -> list[str]:
    """Rewrite a run folder written before ``agents/artifacts.py`` (its final files and every checkpoint) in the
    formats that load without running code; returns what was rewritten. ``model.zip``'s pickled entries are
    dropped unread (they are rebuilt on load); ``vecnormalize.pkl`` has to be unpickled to be converted, so that
    needs ``trust_pickle``: only for a run the user made. Holds the run's lock while it works."""
    out = Path(out)
    if not (out / "config.json").exists():
        raise RunError(f"{out} is not a training run (no config.json)")
    with run_lock(out):
        folders = [out, *checkpoints(out)]
        pickles = [f / PICKLED_STATISTICS_FILE for f in folders if (f / PICKLED_STATISTICS_FILE).exists()]
        if pickles and not trust_pickle:
            raise pickle_refusal(pickles[0], f" (and {len(pickles) - 1} more)" if len(pickles) > 1 else "")
        done = []
        for folder in folders:
            model = folder / MODEL_FILE
            if model.exists() and pickled_entries(model):
                write_bytes_atomically(model, strip_pickles(model.read_bytes(), model))
                done.append(str(model))
            pickled = folder / PICKLED_STATISTICS_FILE
            if pickled.exists():
                save_statistics(unpickle_statistics(pickled), folder / STATISTICS_FILE)
                pickled.unlink()  # after its JSON twin is in place: a crash between the two leaves both, which loads
                done.append(str(pickled))
        return done


def has_checkpoint(out: Path) -> bool:
    """Whether the run in ``out`` wrote a checkpoint (it can be resumed; without one it starts over)."""
    return bool(checkpoints(out))


def checkpoints(out: Path) -> list[Path]:
    """The run's checkpoint folders, newest first (the layout before step folders: one in ``checkpoints/``)."""
    ckpt = out / "checkpoints"
    found = sorted(ckpt.glob("step-*/state.json"), key=lambda p: p.parent.name, reverse=True)
    folders = [p.parent for p in found]
    if (ckpt / "state.json").exists():
        folders.append(ckpt)
    return folders


def _clear_unstarted(out: Path) -> None:
    """Remove what a run that never reached a checkpoint left (its config, logs, half-written checkpoint)."""
    for path in out.iterdir():
        if path.name == LOCK_NAME:
            continue
        if path.name in ("config.json", "progress.csv", "checkpoints") or path.name.startswith("events.out.tfevents"):
            shutil.rmtree(path) if path.is_dir() else path.unlink()


def read_state(folder: Path) -> tuple[int, float]:
    """(agent-steps, training seconds) of a saved model from its ``state.json``; 0 seconds for a folder written
    before the seconds were kept."""
    state = read_json(folder / "state.json")
    return int(state["num_timesteps"]), float(state.get("training_seconds", 0.0))


def _save_files(
    m, config: TrainConfig, folder: Path, normalizer=None, critic_state=None, clock: TrainingClock | None = None
) -> None:
    """``normalizer``: the batched trainer's statistics (the SB3 path's are its model's VecNormalize);
    ``critic_state``: MAPPO's critic and optimizer (:data:`CRITIC_FILE`); ``clock``: training's own time so far,
    kept so that a resumed run's ``time/training_seconds`` goes on from it."""
    # model first, then statistics and critic, then the step count: a reader trusts state.json only when all exist
    save_model(m, folder / MODEL_FILE)
    if config.normalize:
        save_statistics(normalizer if normalizer is not None else m.get_vec_normalize_env(), folder / STATISTICS_FILE)
    if critic_state is not None:
        buffer = io.BytesIO()
        torch.save(critic_state, buffer)
        write_bytes_atomically(folder / CRITIC_FILE, buffer.getvalue())
    state = {"num_timesteps": int(m.num_timesteps)}
    if clock is not None:
        state["training_seconds"] = clock.seconds()
    write_json(folder / "state.json", state)


def _save_checkpoint(
    m,
    config: TrainConfig,
    ckpt: Path,
    normalizer=None,
    critic_state=None,
    clock: TrainingClock | None = None,
    again: bool = True,
) -> Path:
    """A new ``step-<n>`` folder, written whole under a temporary name and renamed, and returned; then all but the
    newest :data:`KEEP_CHECKPOINTS` are removed, except the run's best (:class:`BestCheckpoint`). ``again=False``
    keeps a whole folder of the same step as it is (the batched trainer saves the same state twice when a
    held-out evaluation's best falls on a checkpoint's step: replacing it would leave ``best.json`` naming a
    folder that is, for a moment, gone)."""
    name = f"step-{int(m.num_timesteps):012d}"
    if not again and (ckpt / name / "state.json").exists():
        return ckpt / name
    tmp = ckpt / f".{name}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    _save_files(m, config, tmp, normalizer, critic_state, clock)
    shutil.rmtree(ckpt / name, ignore_errors=True)
    os.replace(tmp, ckpt / name)
    _prune_checkpoints(ckpt.parent)
    return ckpt / name


def _prune_checkpoints(out: Path) -> None:
    """Remove all checkpoints but the newest :data:`KEEP_CHECKPOINTS` and the one ``best.json`` names."""
    ckpt = out / "checkpoints"
    kept = BestCheckpoint.named(out)
    for old in checkpoints(out)[KEEP_CHECKPOINTS:]:
        if old == ckpt:  # the single checkpoint of the old layout
            for stale in (MODEL_FILE, STATISTICS_FILE, PICKLED_STATISTICS_FILE, CRITIC_FILE, "state.json"):
                (ckpt / stale).unlink(missing_ok=True)
        elif old.name != kept:
            shutil.rmtree(old, ignore_errors=True)


class BestCheckpoint:
    """The run's best policy by held-out evaluation, as rl-zoo3 keeps ``best_model.zip`` beside the last model.

    After each held-out evaluation (every ``eval_every`` agent-steps, and the last), :meth:`offer` keeps the policy
    just evaluated as a checkpoint when the mean of :data:`BEST_BY` over the evaluation's episodes is higher than
    every earlier evaluation's of the run (the first on a tie), and writes ``best.json`` (after the checkpoint is
    whole) naming it with its evaluation; that checkpoint is then spared by the rotation of :data:`KEEP_CHECKPOINTS`.
    The held-out episodes are the training's own (``heldout.HELDOUT_SEEDS``), apart from every comparison's and
    sweep's, so a policy chosen by them is still scored on episodes its choice never saw. Keeping it changes
    nothing in training.

    ``resumed_at``: the agent-steps of the checkpoint a resumed run goes on from. A best kept after it belongs to
    the stretch the interrupted process trained and the resumed one will train again on other episodes, so it is
    forgotten (its checkpoint then rotates away), as the log rows after it are (``_cut_progress_log``)."""

    def __init__(self, out: Path, resumed_at: int | None = None):
        self.out = Path(out)
        self.path = self.out / BEST_FILE
        self.record: dict[str, Any] | None = None
        with contextlib.suppress(OSError, RunError):  # none yet, or cut short: the next evaluation writes one
            self.record = read_json(self.path)
        if not (isinstance(self.record, dict) and isinstance(self.record.get(BEST_BY), float)):
            self.record = None
        elif resumed_at is not None and self.record.get("num_timesteps", 0) > resumed_at:
            self.path.unlink()
            self.record = None

    @staticmethod
    def named(out: Path) -> str | None:
        """The checkpoint folder's name that ``out/best.json`` names, or None (no evaluation yet, or unreadable)."""
        try:
            name = read_json(Path(out) / BEST_FILE).get("checkpoint")
        except (OSError, RunError, AttributeError):
            return None
        return name if isinstance(name, str) else None

    def offer(self, means: dict[str, float], steps: int, save) -> None:
        """``means``: an evaluation of the policy after ``steps`` agent-steps; ``save()`` writes that policy as a
        checkpoint and returns its folder, called only for a new best. The evaluation before any update (agent-step
        0: random weights, or a warm start's clone) is the curve's start, not a candidate."""
        score = float(means[BEST_BY])
        if steps <= 0 or (self.record is not None and not score > self.record[BEST_BY]):
            return
        folder = save()
        self.record = {
            "checkpoint": folder.name,
            "num_timesteps": read_state(folder)[0],
            BEST_BY: score,
            "heldout": {key: float(value) for key, value in means.items()},
        }
        write_json(self.path, self.record)
        _prune_checkpoints(self.out)


def best_checkpoint(out: Path) -> Path:
    """The checkpoint folder of the run's best policy by held-out return (:class:`BestCheckpoint`); a run without
    one (no held-out evaluation, or trained before runs kept it) is a :class:`RunError` saying so."""
    out = Path(out)
    name = BestCheckpoint.named(out)
    if name is None:
        raise RunError(
            f"{out} names no best checkpoint ({BEST_FILE}): its run had no held-out evaluation (eval_episodes 0) or "
            "was trained before runs kept one; use its final model"
        )
    folder = out / "checkpoints" / name
    if not (folder / "state.json").exists():
        raise RunError(f"{out / BEST_FILE} names {name}, which {out / 'checkpoints'} does not hold")
    return folder


def _load_newest_checkpoint(config: TrainConfig, ckpt: Path, venv, trust_pickle: bool = False):
    """(model, venv, training seconds) from the newest checkpoint that loads (see :func:`_newest_loadable`)."""
    base = venv

    def load(folder: Path):
        env = read_statistics(folder, base, trust_pickle) if config.normalize else base
        model = load_model(folder / MODEL_FILE, model_spec(config, base), env=env, trust_pickle=trust_pickle)
        model.num_timesteps, seconds = read_state(folder)
        return model, env, seconds

    return _newest_loadable(ckpt.parent, trust_pickle, load)


def _newest_loadable(out: Path, trust_pickle: bool, load):
    """``load(folder)`` of the run's newest checkpoint that loads; a damaged one (a crash mid-write) is reported and
    the older one used. A pickle (a run written before ``agents/artifacts.py``) is refused before anything is read,
    unless ``trust_pickle``; a file that asks to run code is refused outright, not skipped as damage."""
    folders = checkpoints(out)
    for folder in folders:
        refuse_pickles(folder, trust_pickle)
    problems = []
    for folder in folders:
        try:
            loaded = load(folder)
        except PickleRefused:
            raise
        except RunError as exc:
            problems.append(f"{folder.name}: {exc}")
            continue
        except (KeyError, TypeError, ValueError) as exc:  # a state.json without its count
            problems.append(f"{folder.name}: {type(exc).__name__}")
            continue
        if problems:
            print(f"resuming from {folder} ({'; '.join(problems)}: damaged, skipped)", file=sys.stderr)
        return loaded
    raise RunError(f"cannot resume {out}: no checkpoint loads ({'; '.join(problems)}); start it over")


def resumed_csv_output(filename: str):
    """SB3's CSV log continued in place: SB3's own ``CSVOutputFormat`` opens ``progress.csv`` with ``w+``, which
    erases the rows of the run being resumed. The header's keys are kept; a new key rewrites it, as SB3 does."""

    output = CSVOutputFormat.__new__(CSVOutputFormat)
    output.file = open(filename, "r+" if os.path.exists(filename) else "w+")  # noqa: SIM115 - the logger closes it
    header = output.file.readline().rstrip("\n")
    output.keys = header.split(",") if header else []
    output.file.seek(0, os.SEEK_END)
    output.separator, output.quotechar = ",", '"'
    return output


def _cut_progress_log(path: Path, steps: int) -> None:
    """Drop the rows logged after the checkpoint a run resumes from (the interrupted process got further than
    what it saved): the resumed rows then continue the log with increasing ``time/total_timesteps``."""
    if not path.exists():
        return
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        return
    header, body = rows[0], rows[1:]
    column = header.index("time/total_timesteps") if "time/total_timesteps" in header else None
    if column is not None:
        body = [r for r in body if len(r) > column and r[column] and float(r[column]) <= steps]
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows([header, *body])
    os.replace(tmp, path)


def _resumable(out: Path, requested: dict[str, Any], trust_pickle: bool = False) -> TrainConfig:
    config_path = out / "config.json"
    if not config_path.exists():
        raise RunError(f"cannot resume {out}: it holds no run (config.json is missing)")
    for folder in checkpoints(out):  # before anything of the run is read
        refuse_pickles(folder, trust_pickle)
    try:
        record = read_json(config_path)
    except RunError as exc:
        raise RunError(f"cannot resume {out}: {exc}; start the run over") from None
    config = config_from_record(record)
    _check_agreement(config, requested, out)
    finished = (out / "done.json").exists()
    if not checkpoints(out):
        raise RunError(
            f"nothing to resume in {out}: it stopped before its first checkpoint; run the same `mrcomm train` "
            "without --resume to start it over"
        )
    wanted = requested.get("timesteps")
    if finished:
        done = _finished_steps(out / "done.json")
        if wanted is None or wanted <= done:
            raise RunError(
                f"cannot resume {out}: the run has finished ({done} agent-steps); pass --timesteps larger than "
                f"{done} to extend it"
            )
    if wanted is not None and wanted != config.timesteps:
        config.timesteps = int(wanted)
        write_json(config_path, {**record, "timesteps": config.timesteps})
    if finished:
        (out / "done.json").unlink()
    return config


def _check_agreement(config: TrainConfig, requested: dict[str, Any], out: Path) -> None:
    """A resumed run keeps its own settings: any named setting that differs is refused, naming it."""
    named = {k: v for k, v in requested.items() if k != "timesteps" and v is not None}
    if "env_id" in named:
        named["env_id"] = canonical_id(named["env_id"])
    clashes = [
        f"'{key}' is {named[key]!r} but the run has {getattr(config, key)!r}"
        for key in ("env_id", "algo", "seed")
        if key in named and named[key] != getattr(config, key)
    ]
    for key, value in named.get("env_kwargs", {}).items():
        if config.env_kwargs.get(key, _UNSET) != value:
            clashes.append(
                f"env argument '{key}' is {value!r} but the run has {config.env_kwargs.get(key, 'its default')!r}"
            )
    if clashes:
        raise RunError(f"cannot resume {out} with other settings: {'; '.join(clashes)}")


_UNSET = object()


def _finished_steps(path: Path) -> int:
    steps = read_json(path).get("num_timesteps")
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        raise RunError(f"{path} is corrupt: 'num_timesteps' is not a count of agent-steps")
    return steps


def config_from_record(record: dict) -> TrainConfig:
    fields = TrainConfig.__dataclass_fields__
    return TrainConfig(**{k: v for k, v in record.items() if k in fields})
