"""What a run folder holds, written and read back without running code from it.

Run folders travel (a paper's artifacts, a colleague's sweep, a downloaded model), and a pickle runs whatever it
says when it is loaded. So nothing here is ever unpickled, unless the user opts in for a folder they made:

* ``vecnormalize.json`` — VecNormalize's settings and running statistics as plain JSON numbers (Python writes a
  float as the shortest text that reads back to the same bits, so the statistics come back exactly);
* ``model.zip`` — SB3's own archive, whose ``data`` entry is made JSON only: SB3 pickles the entries it
  cannot write as JSON (the policy class, the spaces, the schedules, the rollout buffer's class, the last
  observations). :func:`save_model` replaces each with a marker (``":rebuilt:"``), and :func:`load_model` gives
  SB3 those objects itself through ``custom_objects``: rebuilt from the run's ``config.json`` (algorithm,
  policy, hyperparameters) and its env (the spaces), or left for SB3 to remake (schedules, buffers). The weights
  (``*.pth``) are loaded by SB3 with ``torch.load(weights_only=True)``, which refuses anything but tensors and
  plain containers.

A folder written before this (``vecnormalize.pkl``, or a ``model.zip`` whose ``data`` still holds pickled
entries) is refused before anything in it is read, naming the file and the opt-in ``--trust-pickle``;
``mrcomm convert-run RUN --trust-pickle`` rewrites it in these formats. With the opt-in only ``vecnormalize.pkl``
is unpickled (:func:`unpickle_statistics`): a ``model.zip``'s pickled entries are rebuilt either way.
"""

from __future__ import annotations

import contextlib
import inspect
import io
import json
import math
import os
import pickle
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.utils import LinearSchedule
from stable_baselines3.common.vec_env import VecNormalize

MODEL_FILE = "model.zip"
STATISTICS_FILE = "vecnormalize.json"
#: VecNormalize's own ``save`` (a pickle): what runs written before ``vecnormalize.json`` hold
PICKLED_STATISTICS_FILE = "vecnormalize.pkl"
TRUST_FLAG = "--trust-pickle"
STATISTICS_FORMAT = "mrcomm-vecnormalize/1"

#: the entries SB3 writes into ``model.zip``; any other one is refused
WEIGHT_MEMBERS = ("policy.pth", "policy.optimizer.pth", "pytorch_variables.pth")
TEXT_MEMBERS = ("_stable_baselines3_version", "system_info.txt")
DATA_MEMBER = "data"
#: SB3's mark of a pickled entry in ``data``, and ours of one rebuilt at load time instead
SERIALIZED = ":serialized:"
REBUILT = ":rebuilt:"
#: the readable fields SB3 writes beside a pickled entry that :func:`save_model` keeps (what it was, and for a
#: space its shape, which :func:`load_model` checks against the run's env)
KEPT_FIELDS = (":type:", "_shape", "n", "dtype")


class RunError(ValueError):
    """A run folder that cannot be trained, resumed or loaded as asked."""


class PickleRefused(RunError):
    """A file of a run folder that would run code when loaded: refused outright (never skipped as damage)."""


def pickle_refusal(path: Path, what: str = "") -> PickleRefused:
    """The one-line refusal of a pickle in a run folder, naming it, the conversion and the opt-in."""
    run = path.parent
    while run.name.startswith("step-") or run.name == "checkpoints":  # a checkpoint's file: convert its run
        run = run.parent
    return PickleRefused(
        f"refused to load {path}{what}: it is a pickle, which runs code when loaded. If you made this run, rewrite it "
        f"once with 'mrcomm convert-run {run} {TRUST_FLAG}' (or load it as it is with {TRUST_FLAG})"
    )


# ------------------------------------------------------------------------------------------------ plain files
def write_json(path: Path, data: dict) -> None:
    """Atomic: a temporary file renamed into place, so a reader never sees half a file. Standard JSON: a float
    that is not finite (a metric the episode left undefined, such as MultiHop's propagation time of a subgraph the
    grid does not hold) is written as ``null``, since ``NaN`` is Python's extension that other readers refuse."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(_finite_or_null(data), indent=2, allow_nan=False))
    os.replace(tmp, path)


def _finite_or_null(value):
    """``value`` with numpy scalars as Python numbers and non-finite floats as None (containers walked)."""
    if isinstance(value, dict):
        return {k: _finite_or_null(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_null(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def looks_pickled(raw: bytes) -> bool:
    """Whether ``raw`` starts as a pickle of protocol 2 to 5 does (its PROTO opcode); nothing is unpickled."""
    return len(raw) >= 2 and raw[0] == 0x80 and 2 <= raw[1] <= 5


def read_json(path: Path) -> dict:
    """A JSON object from ``path``; anything else (missing, not text, not JSON, not an object) is a one-line
    :class:`RunError` naming the file, and a pickle in its place is refused as one (:class:`PickleRefused`)."""
    try:
        raw = Path(path).read_bytes()
        if looks_pickled(raw):
            raise PickleRefused(f"refused to load {path}: it holds a pickle, not JSON (a pickle runs code when loaded)")
        data = json.loads(raw.decode("utf-8"))
    except FileNotFoundError:
        raise RunError(f"{path} is missing") from None
    except OSError as exc:
        raise RunError(f"cannot read {path}: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise RunError(f"{path} is corrupt (not JSON)") from None
    if not isinstance(data, dict):
        raise RunError(f"{path} is corrupt (not a JSON object)")
    return data


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return (text[0] if text else "")[:200]


# ------------------------------------------------------------------------------------------------ statistics
def save_statistics(normalizer: VecNormalize, path: Path) -> None:
    """VecNormalize's settings and running statistics as JSON (what its pickle holds that a reader needs; the
    per-copy discounted returns are not kept, as VecNormalize's own ``save`` does not keep them)."""
    if not isinstance(normalizer.obs_rms, RunningMeanStd):
        raise RunError("only VecNormalize over a Box observation space can be saved (no Dict observations)")
    record = {
        "format": STATISTICS_FORMAT,
        "norm_obs": bool(normalizer.norm_obs),
        "norm_reward": bool(normalizer.norm_reward),
        "training": bool(normalizer.training),
        "clip_obs": float(normalizer.clip_obs),
        "clip_reward": float(normalizer.clip_reward),
        "gamma": float(normalizer.gamma),
        "epsilon": float(normalizer.epsilon),
        "obs_rms": _rms_record(normalizer.obs_rms),
        "ret_rms": _rms_record(normalizer.ret_rms),
    }
    write_json(path, record)


def _rms_record(rms: RunningMeanStd) -> dict:
    mean = np.asarray(rms.mean, dtype=np.float64)
    return {
        "shape": list(mean.shape),
        "mean": mean.ravel().tolist(),
        "var": np.asarray(rms.var, dtype=np.float64).ravel().tolist(),
        "count": float(rms.count),
    }


def _rms_from_record(record: Any, path: Path, name: str) -> RunningMeanStd:
    if not isinstance(record, dict):
        raise RunError(f"{path} is corrupt: '{name}' is not an object")
    shape = record.get("shape")
    if not isinstance(shape, list) or not all(isinstance(n, int) and n >= 0 for n in shape):
        raise RunError(f"{path} is corrupt: '{name}.shape' is not a list of sizes")
    size = math.prod(shape)
    arrays = []
    for key in ("mean", "var"):
        values = record.get(key)
        if not isinstance(values, list) or len(values) != size:
            raise RunError(f"{path} is corrupt: '{name}.{key}' is not a list of {size} numbers")
        try:
            array = np.array(values, dtype=np.float64).reshape(shape)
        except (TypeError, ValueError):
            raise RunError(f"{path} is corrupt: '{name}.{key}' is not a list of {size} numbers") from None
        arrays.append(array)
    count = record.get("count")
    if isinstance(count, bool) or not isinstance(count, int | float) or not count > 0:
        raise RunError(f"{path} is corrupt: '{name}.count' is not a positive number")
    if np.any(arrays[1] < 0):
        raise RunError(f"{path} is corrupt: '{name}.var' has a negative variance")
    rms = RunningMeanStd(shape=tuple(shape))
    rms.mean, rms.var, rms.count = arrays[0], arrays[1], float(count)
    return rms


def load_statistics(path: Path, venv=None) -> VecNormalize:
    """The VecNormalize ``save_statistics`` wrote: wrapping ``venv`` (to resume training), or without one for a
    policy that only normalises its observations (``normalize_obs``), as SB3's own unpickling leaves it."""
    record = read_json(path)
    if record.get("format") != STATISTICS_FORMAT:
        raise RunError(
            f"{path} is not VecNormalize statistics of this library (its 'format' is not {STATISTICS_FORMAT})"
        )
    settings: dict[str, Any] = {}
    for key in ("norm_obs", "norm_reward", "training"):
        if not isinstance(record.get(key), bool):
            raise RunError(f"{path} is corrupt: '{key}' must be true or false")
        settings[key] = record[key]
    for key in ("clip_obs", "clip_reward", "gamma", "epsilon"):
        value = record.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
            raise RunError(f"{path} is corrupt: '{key}' must be a number ≥ 0")
        settings[key] = float(value)
    obs_rms = _rms_from_record(record.get("obs_rms"), path, "obs_rms")
    ret_rms = _rms_from_record(record.get("ret_rms"), path, "ret_rms")
    if ret_rms.mean.shape != ():
        raise RunError(f"{path} is corrupt: 'ret_rms' must be of one number")
    if venv is not None:
        if tuple(venv.observation_space.shape) != obs_rms.mean.shape:
            raise RunError(
                f"{path} holds statistics of observations of shape {obs_rms.mean.shape}, but the run's env has "
                f"{tuple(venv.observation_space.shape)}"
            )
        normalizer = VecNormalize(venv, **settings)
    else:
        # what unpickling VecNormalize.save's file gives (its __setstate__), before set_venv: enough to normalise
        normalizer = VecNormalize.__new__(VecNormalize)
        normalizer.__setstate__(
            {
                **settings,
                "observation_space": spaces.Box(-np.inf, np.inf, obs_rms.mean.shape, np.float32),
                "action_space": None,
                "norm_obs_keys": None,
                "old_obs": np.array([]),
                "old_reward": np.array([]),
            }
        )
        # what VecNormalize.save drops and set_venv restores: present, so that the user can still save it
        normalizer.class_attributes = dict(inspect.getmembers(VecNormalize))
        normalizer.returns = np.zeros(0)
    # as SB3's own __setstate__ puts them in place (its attribute is typed for Dict observations too)
    normalizer.__dict__.update(obs_rms=obs_rms, ret_rms=ret_rms)
    return normalizer


def unpickle_statistics(path: Path, venv=None) -> VecNormalize:
    """``vecnormalize.pkl`` as VecNormalize's own ``load`` reads it — it unpickles, so only with ``--trust-pickle``
    (the caller checks) for a folder the user made."""
    try:
        with open(path, "rb") as handle:
            normalizer = pickle.load(handle)  # noqa: S301 - the user opted in with --trust-pickle
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError) as exc:
        raise RunError(f"cannot load {path}: {type(exc).__name__}: {_first_line(exc)}") from None
    if not isinstance(normalizer, VecNormalize):
        raise RunError(f"{path} does not hold VecNormalize statistics (it holds a {type(normalizer).__name__})")
    if venv is not None:
        normalizer.set_venv(venv)
    return normalizer


def statistics_path(folder: Path, trust_pickle: bool) -> tuple[Path, bool]:
    """(file, pickled) of the statistics in ``folder``: ``vecnormalize.json``, else — with the opt-in only —
    ``vecnormalize.pkl``. Raises :class:`RunError` when there is neither, or only the pickle without the opt-in."""
    plain = folder / STATISTICS_FILE
    if plain.exists():
        return plain, False
    pickled = folder / PICKLED_STATISTICS_FILE
    if pickled.exists():
        if not trust_pickle:
            raise pickle_refusal(pickled)
        return pickled, True
    raise RunError(f"{folder} has no {STATISTICS_FILE}, which its config says it was trained with")


def read_statistics(folder: Path, venv=None, trust_pickle: bool = False) -> VecNormalize:
    path, pickled = statistics_path(folder, trust_pickle)
    return unpickle_statistics(path, venv) if pickled else load_statistics(path, venv)


def refuse_pickles(folder: Path, trust_pickle: bool) -> None:
    """Before anything in ``folder`` is read: a pickled statistics file without the JSON one is refused (unless the
    user opted in), naming it and the opt-in."""
    if trust_pickle or (folder / STATISTICS_FILE).exists():
        return
    if (folder / PICKLED_STATISTICS_FILE).exists():
        raise pickle_refusal(folder / PICKLED_STATISTICS_FILE)


# ------------------------------------------------------------------------------------------------ schedules
#: the hyperparameters that may be annealed over a run, in rl-zoo3's notation ``"lin_<start>"``: linear from
#: ``start`` at the first update to 0 at the last (as rl-zoo3's configs write it, e.g. ``learning_rate: lin_2.5e-4``;
#: rl-zoo3 converts the same three PPO settings)
SCHEDULED = ("learning_rate", "clip_range", "clip_range_vf")
LINEAR_PREFIX = "lin_"


def schedule_start(name: str, value: Any) -> Any:
    """The start of a ``"lin_<start>"`` setting of ``name`` as a float (any other value as it was), for range
    checks; a string that is not that notation is a ValueError naming ``name`` and what is allowed."""
    if not isinstance(value, str):
        return value
    start: float | None = None
    if name in SCHEDULED and value.startswith(LINEAR_PREFIX):
        with contextlib.suppress(ValueError):
            start = float(value[len(LINEAR_PREFIX) :])
    if start is None or not math.isfinite(start):
        allowed = (
            f"a number or '{LINEAR_PREFIX}<number>' (linear to 0 over the run)" if name in SCHEDULED else "a number"
        )
        raise ValueError(f"argument {name!r} must be {allowed}, got {value!r}")
    return start


def sb3_setting(name: str, value: Any) -> Any:
    """A hyperparameter as SB3's constructor takes it: ``"lin_<start>"`` becomes SB3's own
    ``LinearSchedule(start, 0, 1)`` (``progress_remaining`` 1 → 0 over the run's timesteps), anything else as it
    was (the range checks are :class:`~mrcomm_agents.training.TrainConfig`'s). A run's ``config.json`` keeps the
    string, so a loaded model gets the same schedule back."""
    if name not in SCHEDULED or not isinstance(value, str):
        return value
    return LinearSchedule(schedule_start(name, value), 0.0, 1.0)


def sb3_settings(hyperparams: dict[str, Any]) -> dict[str, Any]:
    """:func:`sb3_setting` on every entry of ``hyperparams``."""
    return {name: sb3_setting(name, value) for name, value in hyperparams.items()}


# ------------------------------------------------------------------------------------------------ models
@dataclass
class ModelSpec:
    """What rebuilds the entries of ``model.zip``'s ``data`` that SB3 would unpickle: the algorithm class, the
    policy (SB3's alias such as ``"MlpPolicy"``, or a class), its keyword arguments, the run's hyperparameters and
    its env's spaces."""

    algorithm: type[BaseAlgorithm]
    policy: Any
    policy_kwargs: dict[str, Any]
    observation_space: spaces.Space
    action_space: spaces.Space
    hyperparams: dict[str, Any] = field(default_factory=dict)

    def policy_class(self) -> type:
        """The policy's class (SB3's ``load`` puts it in place after the constructor resolved aliases)."""
        if isinstance(self.policy, str):
            return self.algorithm.policy_aliases[self.policy]
        return self.policy

    def setting(self, name: str) -> Any:
        """A hyperparameter as the run set it, else the algorithm's default (its constructor's)."""
        if name in self.hyperparams:
            return sb3_setting(name, self.hyperparams[name])
        parameter = inspect.signature(self.algorithm).parameters.get(name)
        return None if parameter is None or parameter.default is inspect.Parameter.empty else parameter.default


#: every entry SB3 2.9 pickles for PPO, MaskablePPO and DQN, and what stands in for it at load time. ``None``
#: is remade by the algorithm's ``_setup_model`` (the schedules from ``learning_rate`` and ``exploration_*``, the
#: buffer classes as the algorithm's defaults) or by ``learn`` (the last observations: SB3 resets the env when a
#: model is loaded with one, its ``force_reset``; the episode-info buffers)
REBUILDERS: dict[str, Any] = {
    "policy_class": lambda spec: spec.policy_class(),
    "policy_kwargs": lambda spec: spec.policy_kwargs,
    "observation_space": lambda spec: spec.observation_space,
    "action_space": lambda spec: spec.action_space,
    "learning_rate": lambda spec: spec.setting("learning_rate"),
    "clip_range": lambda spec: spec.setting("clip_range"),
    "clip_range_vf": lambda spec: spec.setting("clip_range_vf"),
    "train_freq": lambda spec: spec.setting("train_freq"),
    **dict.fromkeys(
        (
            "lr_schedule",
            "exploration_schedule",
            "rollout_buffer_class",
            "replay_buffer_class",
            "_last_obs",
            "_last_episode_starts",
            "_last_original_obs",
            "ep_info_buffer",
            "ep_success_buffer",
        ),
        lambda spec: None,
    ),
}


def save_model(model, path: Path) -> None:
    """SB3's ``model.save`` with every pickled entry of ``data`` replaced by a marker that :func:`load_model`
    rebuilds; written atomically. An entry this module cannot rebuild is an error here, not at load time."""
    buffer = io.BytesIO()
    model.save(buffer)
    write_bytes_atomically(path, strip_pickles(buffer.getvalue(), path))


def strip_pickles(archive: bytes, path: Path) -> bytes:
    """``archive`` (an SB3 ``model.zip``) with its ``data`` entry made JSON only; the other entries as they were.
    Nothing is unpickled: a pickled entry is dropped, not read."""
    source = zipfile.ZipFile(io.BytesIO(archive))
    data = json.loads(source.read(DATA_MEMBER).decode("utf-8"))
    for key, item in data.items():
        if isinstance(item, dict) and SERIALIZED in item:
            if key not in REBUILDERS:
                raise RunError(f"{path}: SB3 pickled the entry '{key}', which this library cannot rebuild on load")
            data[key] = {REBUILT: True, **{k: item[k] for k in KEPT_FIELDS if k in item}}
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as target:
        for info in source.infolist():
            payload = json.dumps(data, indent=4).encode() if info.filename == DATA_MEMBER else source.read(info)
            target.writestr(info, payload, compress_type=info.compress_type)
    return out.getvalue()


def write_bytes_atomically(path: Path, payload: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(payload)
    os.replace(tmp, path)


def pickled_entries(path: Path) -> list[str]:
    """The entries of ``model.zip``'s ``data`` that are still pickled (a model written before
    :func:`save_model`); read as JSON, nothing unpickled."""
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read(DATA_MEMBER).decode("utf-8"))
    except (OSError, KeyError, zipfile.BadZipFile, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RunError(f"cannot read {path}: {type(exc).__name__}: {_first_line(exc)}") from None
    if not isinstance(data, dict):
        raise RunError(f"cannot read {path}: its '{DATA_MEMBER}' entry is not a JSON object")
    return [key for key, item in data.items() if isinstance(item, dict) and SERIALIZED in item]


_VERSION = re.compile(r"[0-9A-Za-z.+\-]{1,64}")


def load_model(path: Path, spec: ModelSpec, env=None, trust_pickle: bool = False):
    """The SB3 model in ``path`` (``model.zip``), its ``data`` read as JSON and every pickled or rebuilt entry
    supplied by ``spec`` through ``custom_objects``, so that SB3 unpickles nothing; the weights go through
    ``torch.load(weights_only=True)``. ``env``: the VecEnv to train on (resuming), else ``None``.

    A pickled entry (a model written before this module) is refused unless ``trust_pickle``; even then it is
    rebuilt, not unpickled. Any damage is a one-line :class:`RunError` naming the file; anything that would run
    code is a :class:`PickleRefused`."""
    raw, data = _read_archive(Path(path))
    custom: dict[str, Any] = {}
    for key, item in data.items():
        if not (isinstance(item, dict) and (SERIALIZED in item or REBUILT in item)):
            continue
        if SERIALIZED in item and not trust_pickle:
            raise pickle_refusal(Path(path), f" (its entry '{key}')")
        if key not in REBUILDERS:
            raise RunError(f"cannot load {path}: its entry '{key}' is neither plain data nor one this library rebuilds")
        custom[key] = REBUILDERS[key](spec)
        _check_space(path, key, item, custom[key])
    try:
        return spec.algorithm.load(io.BytesIO(raw), env=env, device="cpu", custom_objects=custom)
    except pickle.UnpicklingError:  # torch's weights_only refused an entry: it asks for more than tensors
        raise PickleRefused(
            f"refused to load {path}: one of its weights entries ({', '.join(WEIGHT_MEMBERS)}) holds more than "
            "tensors, which would run code when loaded"
        ) from None
    except Exception as exc:  # noqa: BLE001 - anything in the file that SB3 or torch refuses is the file's fault
        raise RunError(f"cannot load {path}: {type(exc).__name__}: {_first_line(exc)}") from None


def _read_archive(path: Path) -> tuple[bytes, dict]:
    """(the archive's bytes, its ``data`` as JSON), read once: SB3 then loads the same bytes that were checked.
    Only SB3's entries are allowed; the text ones must be text, and none may be a pickle."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise RunError(f"{path} is missing") from None
    except OSError as exc:
        raise RunError(f"cannot read {path}: {exc.strerror or exc}") from None
    if looks_pickled(raw):
        raise PickleRefused(f"refused to load {path}: it is a pickle, not an SB3 model archive (a pickle runs code)")
    try:
        archive = zipfile.ZipFile(io.BytesIO(raw))
        names = archive.namelist()
        unknown = sorted(set(names) - {DATA_MEMBER, *WEIGHT_MEMBERS, *TEXT_MEMBERS})
        if unknown or DATA_MEMBER not in names or "policy.pth" not in names or len(set(names)) != len(names):
            raise ValueError(f"unexpected entries {unknown}" if unknown else "not the entries of an SB3 model")
        texts = {name: archive.read(name) for name in (DATA_MEMBER, *TEXT_MEMBERS) if name in names}
    except (zipfile.BadZipFile, ValueError, EOFError) as exc:
        raise RunError(f"cannot load {path}: {_first_line(exc)}") from None
    for name, text in texts.items():
        if looks_pickled(text):
            raise PickleRefused(f"refused to load {path}: its entry '{name}' is a pickle (a pickle runs code)")
    try:
        decoded = {name: text.decode("utf-8") for name, text in texts.items()}
        version = decoded.get("_stable_baselines3_version")
        if version is not None and not _VERSION.fullmatch(version.strip()):
            raise ValueError("its entry _stable_baselines3_version is not a version")
        data = json.loads(decoded[DATA_MEMBER])
    except (UnicodeDecodeError, ValueError) as exc:  # JSONDecodeError is a ValueError
        raise RunError(f"cannot load {path}: {type(exc).__name__}: {_first_line(exc)}") from None
    if not isinstance(data, dict):
        raise RunError(f"cannot load {path}: its '{DATA_MEMBER}' entry is not a JSON object")
    return raw, data


def _check_space(path: Path, key: str, item: dict, space) -> None:
    """The readable shape SB3 kept beside a space against the space the run's env has now."""
    if key not in ("observation_space", "action_space") or "_shape" not in item:
        return
    saved = item["_shape"]
    if not isinstance(saved, list) or tuple(saved) != tuple(space.shape):
        kind = "observations" if key == "observation_space" else "actions"
        raise RunError(
            f"the model in {path} was trained on {kind} of shape {tuple(saved) if isinstance(saved, list) else saved}"
            f", but its env now has {tuple(space.shape)}"
        )
