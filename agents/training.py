"""Parameter-shared training of one SB3 policy for every agent of an env (``mrcomm train``).

A run folder holds everything needed to evaluate, resume or reproduce it:

* ``config.json`` — env id and arguments, algorithm, hyperparameters, seed, package versions, git commit;
* ``model.zip`` and ``vecnormalize.pkl`` — the final policy and its observation/return statistics;
* ``checkpoints/`` — the latest checkpoint (model with optimizer state, statistics, timestep count);
* ``progress.csv`` and TensorBoard event files — SB3's own logger;
* ``done.json`` — written last, when the run finished.

``--resume`` continues from the latest checkpoint with the same timestep count, optimizer state and
normalisation statistics; a finished run refuses to resume.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from mrcomm_agents.vecenv import AgentSlotVecEnv
from mrcomm_env.registry import canonical_id, make, short_name

CONFIG_DIR = Path(__file__).with_name("configs")
#: algorithms ``mrcomm train`` knows: name → (module, class); MaskablePPO needs the env's action masks
ALGORITHMS = {
    "ppo": ("stable_baselines3", "PPO"),
    "maskable_ppo": ("sb3_contrib", "MaskablePPO"),
    "dqn": ("stable_baselines3", "DQN"),
}
#: arguments of ``train`` that are not the algorithm's own hyperparameters
RUN_KEYS = ("n_envs", "normalize", "checkpoint_every", "net_arch", "policy")


class RunError(ValueError):
    """A run folder that cannot be trained, resumed or loaded as asked."""


@dataclass
class TrainConfig:
    env_id: str
    algo: str = "ppo"
    timesteps: int = 200_000  #: agent-steps (each agent slot's step counts once, as SB3 counts them)
    seed: int = 0
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    hyperparams: dict[str, Any] = field(default_factory=dict)
    n_envs: int = 4  #: copies of the parallel env; the VecEnv has n_envs × N agent slots
    normalize: bool = True  #: VecNormalize on observations and returns
    net_arch: list[int] = field(default_factory=lambda: [64, 64])
    #: ``mlp`` (SB3's MlpPolicy) or ``candidates`` (one shared scorer per candidate, ``agents/policies.py``;
    #: needs an env whose ``observation_layout()`` lists candidates)
    policy: str = "mlp"
    checkpoint_every: int = 50_000  #: agent-steps between checkpoints

    def validate(self) -> TrainConfig:
        self.env_id = canonical_id(self.env_id)
        if self.algo not in ALGORITHMS:
            raise ValueError(f"argument 'algo' must be one of {', '.join(ALGORITHMS)}, got {self.algo!r}")
        for name in ("timesteps", "n_envs", "checkpoint_every"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"argument '{name}' must be an integer ≥ 1, got {value!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"argument 'seed' must be an integer ≥ 0, got {self.seed!r}")
        if self.policy not in ("mlp", "candidates"):
            raise ValueError(f"argument 'policy' must be 'mlp' or 'candidates', got {self.policy!r}")
        env = make(self.env_id, **self.env_kwargs)  # the env's own arguments are checked before any work
        if self.policy == "candidates" and env.observation_layout() is None:
            raise ValueError(
                f"policy 'candidates' needs an observation of candidates; {self.env_id} with "
                f"{self.env_kwargs} has a flat one"
            )
        env.close()
        return self


def default_config(env_id: str, algo: str = "ppo") -> dict[str, Any]:
    """The tuned settings shipped in ``agents/configs/<Name>-v0.json`` for ``algo`` (empty when none)."""
    path = CONFIG_DIR / f"{short_name(env_id)}.json"
    if not path.exists():
        return {}
    return json.loads(path.read_text()).get(algo, {})


def policy_class_override(record: dict[str, Any]) -> dict[str, Any] | None:
    """The policy class for SB3's ``load`` when a run used our own (``policy: candidates``): its model.zip names
    the class by the module path it was saved under (models saved before the packages were renamed say
    ``agents.policies``), so the class is handed over rather than looked up by that name."""
    if record.get("policy") != "candidates":
        return None
    from mrcomm_agents.policies import CandidatePolicy  # torch: the train extra

    return {"policy_class": CandidatePolicy}


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
    return data.get(algo, data)


def split_settings(settings: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(run settings, algorithm hyperparameters) of one config block."""
    run = {k: v for k, v in settings.items() if k in RUN_KEYS or k in ("timesteps", "env_kwargs")}
    hyper = {k: v for k, v in settings.items() if k not in run}
    return run, hyper


def make_training_env(config: TrainConfig, seed: int):
    """The agent-slot VecEnv under a VecMonitor (episode returns in the logs, counted once per agent slot)."""
    from stable_baselines3.common.vec_env import VecMonitor

    env_fns = [lambda: make(config.env_id, **config.env_kwargs) for _ in range(config.n_envs)]
    venv = AgentSlotVecEnv(env_fns)
    venv.seed(seed)
    return VecMonitor(venv)


def algorithm_class(algo: str):
    import importlib

    module, name = ALGORITHMS[algo]
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


def write_json(path: Path, data: dict) -> None:
    """Atomic: a temporary file renamed into place, so a reader never sees half a file."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=2, default=_plain))
    os.replace(tmp, path)


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serialisable: {value!r}")


# ------------------------------------------------------------------------------------------------ training
class _Progress:
    """A tqdm bar over agent-steps plus periodic checkpoints (SB3's own bar needs ``rich``).

    Checkpoints are taken when a rollout starts, i.e. after the previous rollout has been trained on: a
    checkpoint taken mid-rollout would count steps whose data the optimizer never saw.
    """

    def __init__(self, total: int, start: int, every: int, save, enabled: bool):
        from stable_baselines3.common.callbacks import BaseCallback
        from tqdm.auto import tqdm

        outer = self
        self.rollout_start = start

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


def train(config: TrainConfig, out: str | Path, resume: bool = False, progress: bool = True) -> Path:
    """Train (or with ``resume``, continue) the run in folder ``out``; returns the folder."""
    import torch
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    torch.set_num_threads(1)
    out = Path(out)
    ckpt = out / "checkpoints"
    if resume:
        config = _resumable(out)
    else:
        config.validate()
        if (out / "config.json").exists():
            raise RunError(f"{out} already holds a run; pass --resume to continue it or choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    ckpt.mkdir(exist_ok=True)
    cls = algorithm_class(config.algo)
    if not resume:
        record = {**asdict(config), "versions": package_versions(), "git_commit": git_commit()}
        write_json(out / "config.json", record)

    venv = make_training_env(config, config.seed)
    if resume:
        if config.normalize:
            venv = VecNormalize.load(str(ckpt / "vecnormalize.pkl"), venv)
        model = cls.load(
            str(ckpt / "model.zip"),
            env=venv,
            device="cpu",
            custom_objects=policy_class_override({"policy": config.policy}),
        )
        done_steps = model.num_timesteps
    else:
        if config.normalize:
            venv = VecNormalize(venv, norm_obs=True, norm_reward=True, gamma=config.hyperparams.get("gamma", 0.99))
        kwargs = dict(config.hyperparams)
        policy_kwargs = dict(kwargs.pop("policy_kwargs", {}))
        if config.policy == "candidates":
            from mrcomm_agents.policies import CandidatePolicy

            probe = make(config.env_id, **config.env_kwargs)
            policy = CandidatePolicy
            policy_kwargs.update(layout=probe.observation_layout(), hidden=int(config.net_arch[0]))
            probe.close()
        else:
            policy = "MlpPolicy"
            policy_kwargs.setdefault("net_arch", list(config.net_arch))
        model = cls(policy, venv, seed=config.seed, device="cpu", verbose=0, policy_kwargs=policy_kwargs, **kwargs)
        done_steps = 0
    model.set_logger(configure(str(out), ["csv", "tensorboard"]))

    def save(m, folder: Path = ckpt) -> None:
        # model first, then statistics, then the step count: a reader trusts state.json only when all exist
        m.save(str(folder / ".model.tmp.zip"))
        os.replace(folder / ".model.tmp.zip", folder / "model.zip")
        if config.normalize:
            m.get_vec_normalize_env().save(str(folder / ".vecnormalize.tmp.pkl"))
            os.replace(folder / ".vecnormalize.tmp.pkl", folder / "vecnormalize.pkl")
        write_json(folder / "state.json", {"num_timesteps": int(m.num_timesteps)})

    bar = _Progress(config.timesteps, done_steps, config.checkpoint_every, save, progress)
    remaining = config.timesteps - done_steps
    try:
        model.learn(total_timesteps=remaining, callback=bar.callback, reset_num_timesteps=not resume)
    except KeyboardInterrupt:
        # an interrupted run resumes from the start of the rollout it was collecting: those steps were not
        # trained on yet, so they are not counted
        model.num_timesteps = bar.rollout_start
        save(model)
        raise
    save(model)
    save(model, out)
    write_json(out / "done.json", {"num_timesteps": int(model.num_timesteps)})
    venv.close()
    return out


def _resumable(out: Path) -> TrainConfig:
    if not (out / "config.json").exists():
        raise RunError(f"cannot resume {out}: it holds no run (config.json is missing)")
    if (out / "done.json").exists():
        raise RunError(f"cannot resume {out}: the run has finished")
    if not (out / "checkpoints" / "state.json").exists():
        raise RunError(f"cannot resume {out}: no checkpoint was written yet; start it again")
    return config_from_record(json.loads((out / "config.json").read_text()))


def config_from_record(record: dict) -> TrainConfig:
    fields = TrainConfig.__dataclass_fields__
    return TrainConfig(**{k: v for k, v in record.items() if k in fields})
