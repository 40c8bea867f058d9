"""A trained SB3 model as a team policy: the same interface, metrics and JSON as a scripted baseline.

``mrcomm evaluate ID --policy ppo:runs/NAME`` loads a run folder written by ``mrcomm train``;
``--policy pretrained`` loads the small model shipped in ``agents/pretrained/<Name>-v0/``; ``ippo:RUN`` and
``mappo:RUN`` load the batched trainer's runs (an SB3 model too). A run that stopped before it finished (Ctrl-C)
is evaluated with its newest checkpoint, and says so on stderr. The policy sees
exactly what it was trained on: each agent's observation (normalised with the run's statistics), and, for
masked envs, the robot's own ``action_mask`` field of its local view.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mrcomm_agents.artifacts import MODEL_FILE, RunError, load_model, read_json, read_statistics, refuse_pickles
from mrcomm_agents.heldout import sb3_masks, uses_masks
from mrcomm_agents.training import ALGORITHMS, best_checkpoint, checkpoints, config_from_record, model_spec
from mrcomm_env.core.policy import LocalViews, Policy
from mrcomm_env.registry import canonical_id, short_name

PRETRAINED_DIR = Path(__file__).with_name("pretrained")
MASK_FIELD = "action_mask"


def pretrained_dir(env_id: str) -> Path:
    return PRETRAINED_DIR / short_name(env_id)


def has_pretrained(env_id: str) -> bool:
    return (pretrained_dir(env_id) / MODEL_FILE).exists()


#: the card beside each shipped model: how it was trained and the evaluation mode it was chosen with
CARD_NAME = "card.json"


def model_card(env_id: str) -> dict[str, Any]:
    """The shipped model's card (``agents/pretrained/<Name>-v0/card.json``): env id and arguments, algorithm, seed,
    agent-steps, the evaluation mode (``deterministic``) it was chosen with and the command that remakes it."""
    path = pretrained_dir(env_id) / CARD_NAME
    if not path.exists():
        raise RunError(f"the pretrained model of {canonical_id(env_id)} has no {path.name}")
    try:
        card = read_json(path)
    except RunError:
        raise RunError(f"{path} is corrupt (not JSON); reinstall the package or re-export the model") from None
    if not isinstance(card.get("deterministic"), bool):
        raise RunError(f"{path} must say whether the model acts deterministically ('deterministic': true/false)")
    return card


#: which of a run's models a learned policy acts with (``checkpoint``): its last, or its best by held-out return
CHECKPOINTS = ("final", "best")


class LearnedPolicy(Policy):
    """A parameter-shared SB3 policy: one network acts for every agent.

    ``deterministic`` (default) takes each agent's most likely action; otherwise actions are sampled, seeded by
    ``reset``. Sampling matters where identical robots must break symmetry (two robots with the same observation
    and a deterministic shared policy always act alike). ``checkpoint``: ``final``, the run's last model (or, for a
    run stopped early, its newest checkpoint), or ``best``, the checkpoint its held-out evaluation scored highest
    (``best.json``, rl-zoo3's ``best_model``)."""

    name = "learned"

    def __init__(
        self,
        run: str | Path,
        env_id: str,
        algo: str | None = None,
        deterministic: bool = True,
        trust_pickle: bool = False,
        checkpoint: str = "final",
    ):
        super().__init__()
        if not isinstance(deterministic, bool):
            raise RunError(f"parameter 'deterministic' must be true or false, got {deterministic!r}")
        if checkpoint not in CHECKPOINTS:
            raise RunError(f"parameter 'checkpoint' must be one of {', '.join(CHECKPOINTS)}, got {checkpoint!r}")
        self.deterministic = deterministic
        run = Path(run)
        self.run = run
        config_path = run / "config.json"
        if not config_path.exists():
            raise RunError(f"{run} is not a training run (no config.json); train one with 'mrcomm train'")
        refuse_pickles(run, trust_pickle)  # before anything of the run is read (agents/artifacts.py)
        record = read_json(config_path)
        trained_on = record.get("env_id")  # stored canonical by TrainConfig.validate
        if trained_on != canonical_id(env_id):
            raise RunError(f"the model in {run} was trained on {trained_on}, not {canonical_id(env_id)}")
        self.env_id = trained_on
        self.algo = algo or record.get("algo", "ppo")
        if self.algo not in ALGORITHMS:
            raise RunError(f"unknown algorithm {self.algo!r} in {run}; known: {', '.join(ALGORITHMS)}")
        if record.get("algo") and self.algo != record["algo"]:
            raise RunError(f"the model in {run} was trained with {record['algo']}, not {self.algo}")
        self.env_kwargs = record.get("env_kwargs", {})
        if not isinstance(self.env_kwargs, dict):
            raise RunError(f"{config_path} is corrupt: 'env_kwargs' is not an object")
        model_path, source = run / MODEL_FILE, run
        if checkpoint == "best":  # the run's best policy by held-out return (training.BestCheckpoint)
            source = best_checkpoint(run)
            refuse_pickles(source, trust_pickle)
            model_path = source / MODEL_FILE
        elif not model_path.exists():
            # a run stopped early (Ctrl-C, a crash) holds checkpoints: its newest one is the policy it has
            found = checkpoints(run)
            if not found:
                raise RunError(
                    f"{run} has no {MODEL_FILE} and no checkpoint (it stopped before its first one; train it again)"
                )
            source = found[0]
            refuse_pickles(source, trust_pickle)
            model_path = source / MODEL_FILE
            print(f"{run} has not finished: using its newest checkpoint, {source.name}", file=sys.stderr)
        try:
            config = config_from_record({**record, "algo": self.algo})
        except TypeError as exc:
            raise RunError(f"{config_path} is corrupt: {exc}") from None
        self.model = load_model(model_path, model_spec(config), trust_pickle=trust_pickle)
        self.normalizer = read_statistics(source, trust_pickle=trust_pickle) if record.get("normalize", True) else None
        #: the folder the model and its statistics were read from: the run, or one of its checkpoints
        self.source = source
        self.params = {"run": str(run), "algo": self.algo, "deterministic": deterministic, "checkpoint": checkpoint}

    def reset(self, views: LocalViews, seed: int | None = None) -> None:
        super().reset(views, seed)
        if not self.deterministic:
            torch.manual_seed(int(self.rng.integers(2**63)))  # SB3 samples from torch's global generator
        model_obs, model_act = self.model.observation_space, self.model.action_space
        if model_obs.shape != views.observation_space.shape or model_act != views.action_space:
            raise RunError(
                f"the model in {self.run} expects observations {model_obs.shape} and actions {model_act}, but "
                f"this env has {views.observation_space.shape} and {views.action_space}; it was trained with the "
                f"env arguments {self.env_kwargs}"
            )
        self._masked = MASK_FIELD in views.fields and uses_masks(self.model)

    def act(self, observations: dict[str, np.ndarray], views: LocalViews) -> dict[str, Any]:
        agents = list(observations)
        obs = np.stack([observations[a] for a in agents])
        if self.normalizer is not None:
            obs = self.normalizer.normalize_obs(obs)
        kwargs = {}
        if self._masked:
            masks = views.team(MASK_FIELD)
            kwargs["action_masks"] = sb3_masks(np.stack([masks[views.index(a)] for a in agents]), views.action_space)
        actions, _ = self.model.predict(obs, deterministic=self.deterministic, **kwargs)
        if np.ndim(actions) == 1:
            return {a: int(x) for a, x in zip(agents, actions)}
        return dict(zip(agents, np.asarray(actions, dtype=np.float32)))


def load_policy(spec: str, env_id: str, trust_pickle: bool = False, **params) -> LearnedPolicy:
    """``ppo:PATH``, ``maskable_ppo:PATH``, ``dqn:PATH``, ``ippo:PATH``, ``mappo:PATH`` or ``pretrained``;
    ``params``: ``deterministic``, and for a run ``checkpoint``: ``final`` (its last model) or ``best`` (its best by
    held-out return, ``best.json``).
    ``trust_pickle``: load a run written before ``agents/artifacts.py``'s formats (only one the user made)."""
    unknown = set(params) - {"deterministic", "checkpoint"}
    if unknown:
        raise RunError(
            f"a learned policy takes only the parameters 'deterministic' and 'checkpoint', got {sorted(unknown)}"
        )
    if spec == "pretrained":
        if "checkpoint" in params:
            raise RunError("parameter 'checkpoint' is for a run (ALGO:PATH); a pretrained model is one model")
        if not has_pretrained(env_id):
            raise RunError(f"no pretrained model ships for {canonical_id(env_id)}")
        # the mode the model was chosen with (its card), unless the caller asks for the other one
        params.setdefault("deterministic", model_card(env_id)["deterministic"])
        return LearnedPolicy(pretrained_dir(env_id), env_id, trust_pickle=trust_pickle, **params)
    algo, _, path = spec.partition(":")
    if algo not in ALGORITHMS or not path:
        raise RunError(f"a learned policy is ALGO:PATH with ALGO one of {', '.join(ALGORITHMS)}, got {spec!r}")
    return LearnedPolicy(path, env_id, algo, trust_pickle=trust_pickle, **params)


def is_learned(spec: str) -> bool:
    return spec == "pretrained" or spec.partition(":")[0] in ALGORITHMS and ":" in spec
