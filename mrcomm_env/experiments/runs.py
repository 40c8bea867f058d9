"""What every training run shares, read without the "train" extra: the env's learning configuration
(``agents/configs``), a run's folder name and the scripted teacher of a warm start. Training a run as a sweep task
is :mod:`mrcomm_env.experiments.train`'s (it needs the extra)."""

from __future__ import annotations

import hashlib
import importlib.util
import json
from pathlib import Path

from mrcomm_baselines import make_policy, policy_names
from mrcomm_env.core.policy import Policy
from mrcomm_env.registry import canonical_id, short_name

#: the section of ``agents/configs/<Name>-v0.json`` that sets up the comparison with the baselines
COMPARISON_KEY = "comparison"


def agent_config_dir() -> Path:
    """``agents/configs`` (``mrcomm_agents.training.CONFIG_DIR``), found without importing the agents package, whose
    ``__init__`` imports SB3: the configs are data, read also where the "train" extra is not installed (BenchMARL's
    venv)."""
    spec = importlib.util.find_spec("mrcomm_agents")
    if spec is None or not spec.submodule_search_locations:
        raise ValueError("the learning configurations ship with the mrcomm_agents package, which is not installed")
    return Path(next(iter(spec.submodule_search_locations))) / "configs"


def comparison_spec(env_id: str) -> dict:
    """The env's comparison settings from ``agents/configs/<Name>-v0.json``: the cost argument swept (λ or the
    bit price), its values, the task metric and whether lower is better, the baselines, seeds and episodes."""
    path = agent_config_dir() / f"{short_name(env_id)}.json"
    if not path.exists():
        raise ValueError(f"{canonical_id(env_id)} has no learning configuration ({path.name})")
    spec = json.loads(path.read_text())
    if COMPARISON_KEY not in spec:
        raise ValueError(f"{path.name} has no '{COMPARISON_KEY}' section")
    return {"algo": "ppo", **spec[COMPARISON_KEY], "settings": spec}


def comparison_teacher(spec: dict) -> str | None:
    """The scripted baseline a comparison's runs start from a clone of (``NAME`` of its section's ``init_from:
    baseline:NAME``), or None where they start from random weights."""
    init_from = spec["settings"].get(spec["algo"], {}).get("init_from")
    return str(init_from).partition(":")[2] if init_from else None


def scored_policy_settings(spec: dict) -> dict:
    """How a comparison's runs act when scored, profiled and shipped (``LearnedPolicy``'s keyword arguments):
    deterministically unless the comparison says otherwise, with the final model unless it names
    ``"checkpoint": "best"``."""
    return {"deterministic": spec.get("deterministic", True), "checkpoint": spec.get("checkpoint", "final")}


#: the batched trainer's algorithms (``mrcomm_agents.batched_ppo.BATCHED_ALGORITHMS``, named here so that this
#: module reads agents/configs without importing SB3; a test holds the two equal)
BATCHED_TRAINERS = ("ippo", "mappo")


def sb3_algo(spec: dict) -> str:
    """The algorithm of the env's shipped SB3 configuration (what ``mrcomm bench --train-shipped`` and
    ``mrcomm race`` run on SB3's side): the comparison's, or where the comparison trains the batched trainer, the
    config's SB3 section (``ppo``, or ``maskable_ppo`` where the actions are masked: RendezvousMapping)."""
    if spec["algo"] not in BATCHED_TRAINERS:
        return spec["algo"]
    return next((algo for algo in ("ppo", "maskable_ppo") if algo in spec["settings"]), "ppo")


def run_folder(label: str, config: dict) -> str:
    """``<grid point>-<digest>/s<seed>``: the digest covers every setting of the run but its seed and its stepping
    processes (env arguments, algorithm, hyperparameters, agent-steps, …), so a rerun with any of them changed trains
    new runs instead of reusing the old ones."""
    # env_workers: how many processes step the copies changes no number of the run, only its speed
    settings = {k: v for k, v in config.items() if k not in ("seed", "env_workers")}
    # "numba": the digest once also named the backend of the env's hot loops, numba or numpy (MRCOMM_BACKEND, gone
    # since every hot loop is compiled); kept so that run folders made before keep their names and resume
    blob = json.dumps([settings, "numba"], sort_keys=True, default=str)
    return f"{label}-{hashlib.sha1(blob.encode()).hexdigest()[:8]}/s{config['seed']}"


def train_settings(
    env_id: str,
    algo: str,
    params: dict,
    timesteps: int | None = None,
    config_file: str | None = None,
    **overrides,
) -> tuple[dict, Policy | None]:
    """What ``mrcomm train`` trains, and the teacher of its warm start: ``(settings, teacher)``, the settings being
    :class:`~mrcomm_agents.training.TrainConfig`'s arguments but the seed. They are the env's shipped settings for
    ``algo`` (``agents/configs/<Name>-v0.json``), a ``--config`` file's over them, the env arguments with ``params``
    (``--param``) over the file's, ``timesteps`` where given, and each of ``overrides`` that is not None (``init_from``,
    ``update_threads``, ``env_workers``). The teacher is found once, from the configuration's ``init_from`` or
    ``--init-from``'s, so that a bad name is reported before any work."""
    from mrcomm_agents.training import default_config, load_config_file, split_settings  # extra "train"

    settings = default_config(env_id, algo)
    if config_file:
        settings = {**settings, **load_config_file(config_file, algo)}
    run, hyper = split_settings(settings)
    env_kwargs = {**run.pop("env_kwargs", {}), **params}
    shipped_timesteps = run.pop("timesteps", 200_000)
    run.update({key: value for key, value in overrides.items() if value is not None})
    teacher = teacher_for(env_id, run.get("init_from"))
    timesteps = shipped_timesteps if timesteps is None else timesteps
    return dict(env_id=env_id, algo=algo, timesteps=timesteps, env_kwargs=env_kwargs, hyperparams=hyper, **run), teacher


def teacher_for(env_id: str, init_from: str | None) -> Policy | None:
    """The scripted policy ``--init-from baseline:NAME`` names (``None`` for none); unknown names raise
    ``ValueError`` listing the valid ones."""
    if init_from is None:
        return None
    kind, _, name = str(init_from).partition(":")
    if kind != "baseline" or name not in policy_names(env_id):
        raise ValueError(
            f"argument 'init_from' must be baseline:NAME with NAME one of {', '.join(policy_names(env_id))}, "
            f"got {init_from!r}"
        )
    return make_policy(env_id, name)
