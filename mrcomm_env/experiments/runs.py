"""Training runs as sweep tasks: where a run's folder is, training it (or resuming it), and scoring it on
held-out episodes. ``mrcomm train --seeds/--grid`` (``train.py``) and the learned-against-scripted comparison
(``comparison.py``) both send these tasks through the sweep runner."""

from __future__ import annotations

import csv
import hashlib
import importlib.util
import json
from pathlib import Path

from mrcomm_baselines import make_policy, policy_names
from mrcomm_env.core import backend
from mrcomm_env.core.policy import Policy
from mrcomm_env.experiments.evaluation import evaluate_policy, limit_threads
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
    try:
        from mrcomm_agents.training import CONFIG_DIR  # extra "train"
    except ImportError:  # no SB3 (BenchMARL's venv): the same folder, found without importing the agents package
        CONFIG_DIR = agent_config_dir()
    path = CONFIG_DIR / f"{short_name(env_id)}.json"
    if not path.exists():
        raise ValueError(f"{canonical_id(env_id)} has no learning configuration ({path.name})")
    spec = json.loads(path.read_text())
    if COMPARISON_KEY not in spec:
        raise ValueError(f"{path.name} has no '{COMPARISON_KEY}' section")
    return {"algo": "ppo", **spec[COMPARISON_KEY], "settings": spec}


#: the batched trainer's algorithms (``mrcomm_agents.batched_ppo.BATCHED_ALGORITHMS``, named here so that this
#: module reads agents/configs without importing SB3; a test holds the two equal)
BATCHED_TRAINERS = ("ippo", "mappo")


def sb3_algo(spec: dict) -> str:
    """The algorithm of the env's shipped SB3 configuration (what ``mrcomm bench --train-shipped`` and
    ``mrcomm race`` run on SB3's side): the comparison's, or ``ppo`` where the comparison trains the batched
    trainer (its ``ppo`` section stays the SB3 path's settings)."""
    return "ppo" if spec["algo"] in BATCHED_TRAINERS else spec["algo"]


def run_folder(label: str, config: dict) -> str:
    """``<grid point>-<digest>/s<seed>``: the digest covers every setting of the run but its seed (env arguments,
    algorithm, hyperparameters, agent-steps, …) and the backend of the env's hot loops, so a rerun with any of
    them changed trains new runs instead of reusing the old ones."""
    settings = {k: v for k, v in config.items() if k != "seed"}
    blob = json.dumps([settings, backend.name()], sort_keys=True, default=str)
    return f"{label}-{hashlib.sha1(blob.encode()).hexdigest()[:8]}/s{config['seed']}"


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


def train_run(out: str, config: dict) -> str:
    """Train one run into ``out`` (a process of its own: one torch thread). A finished run is skipped, a
    checkpointed one resumed, one never checkpointed starts over."""
    from mrcomm_agents.training import TrainConfig, has_checkpoint, train  # extra "train"

    limit_threads()
    folder = Path(out)
    if (folder / "done.json").exists():
        return out  # a rerun skips what is done (the folder's name holds every setting: run_folder)
    if has_checkpoint(folder):
        train(None, folder, resume=True, progress=False)
    else:
        teacher = teacher_for(config["env_id"], config.get("init_from"))
        train(TrainConfig(**config), folder, progress=False, teacher=teacher)
    return out


def training_summary(run: Path) -> dict:
    """The last logged mean training return and the run's length, from SB3's ``progress.csv``."""
    with open(run / "progress.csv") as fh:
        rows = list(csv.DictReader(fh))
    returns = [float(r["rollout/ep_rew_mean"]) for r in rows if r.get("rollout/ep_rew_mean")]
    last = rows[-1] if rows else {}
    return {
        "timesteps": int(float(last.get("time/total_timesteps") or 0)),
        "seconds": float(last.get("time/time_elapsed") or 0.0),
        "final_train_return": returns[-1] if returns else float("nan"),
    }


def train_and_evaluate(out: str, config: dict, eval_seeds: list[int]) -> dict:
    """A sweep task: train one run into ``out`` (resumed, or skipped when finished) and score it on ``eval_seeds``
    with the env's comparison metric, bits and return. Returns JSON data only, so any backend can carry it."""
    from mrcomm_agents.learned import LearnedPolicy  # extra "train"

    train_run(out, config)
    summary = training_summary(Path(out))
    try:
        spec = comparison_spec(config["env_id"])
    except ValueError:  # no comparison section: score by the return alone
        spec = {"metric": "episode_return", "deterministic": True}
    policy = LearnedPolicy(out, config["env_id"], config.get("algo"), deterministic=spec.get("deterministic", True))
    evaluation = evaluate_policy(config["env_id"], config.get("env_kwargs", {}), policy, eval_seeds, spec)
    return {"run": out, "training": summary, "evaluation": evaluation}
