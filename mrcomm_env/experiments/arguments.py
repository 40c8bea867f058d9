"""Argument types of the ``mrcomm`` commands, and the checks of their output paths: a leaf module every command's
module imports (none imports another command's module for them)."""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

from mrcomm_env.experiments.io import TEMP_SUFFIX


def parse_params(pairs: list[str] | None, flag: str = "--param") -> dict:
    """``key=value`` pairs; values are read as JSON where possible (numbers, true, lists), else kept as text."""
    params = {}
    for pair in pairs or []:
        if "=" not in pair:
            raise ValueError(f"{flag} takes key=value, got {pair!r}")
        key, text = pair.split("=", 1)
        try:
            params[key.strip()] = json.loads(text)
        except json.JSONDecodeError:
            params[key.strip()] = text
    return params


def split_values(text: str) -> list[str]:
    """Comma-separated values, where commas inside brackets or a JSON string belong to a value
    (``net_arch=[64,64],[128,128]``, ``label="a, b"``)."""
    values, depth, start, quoted, escaped = [], 0, 0, False, False
    for i, char in enumerate(text):
        if quoted:  # inside "…": only its end counts, and \" does not end it
            quoted = escaped or char != '"'
            escaped = not escaped and char == "\\"
            continue
        quoted = char == '"'
        depth += char in "[{"
        depth -= char in "]}"
        if char == "," and depth == 0:
            values.append(text[start:i])
            start = i + 1
    values.append(text[start:])
    return [v.strip() for v in values]


def rule_argument(name: str, params: dict) -> str:
    """A scripted rule and its parameters as ``mrcomm actions --against`` takes them (``periodic_sketch:period=1``):
    values as JSON, so that lists and text come back as they were (:func:`split_values`, :func:`parse_params`)."""
    pairs = ",".join(f"{key}={json.dumps(value, separators=(',', ':'))}" for key, value in params.items())
    return name + (":" + pairs if pairs else "")


def _integer(text: str, allowed: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or value < minimum:
        raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}")
    return value


def seed_type(text: str) -> int:
    return _integer(text, "an integer ≥ 0", 0)


def positive_int(text: str) -> int:
    return _integer(text, "an integer ≥ 1", 1)


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def positive_seconds(text: str) -> float:
    value = _finite(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a number of seconds > 0, got {text!r}")
    return value


def nonnegative_seconds(text: str) -> float:
    value = _finite(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a number of seconds ≥ 0, got {text!r}")
    return value


def add_episode_arguments(parser: argparse.ArgumentParser) -> None:
    """The episodes a command plays a policy on and their env (``evaluate``, ``actions``): ``--episodes``, ``--seed``
    of the first, ``--param`` env arguments, and ``--trust-pickle`` for a learned model's older run."""
    parser.add_argument("--episodes", type=positive_int, default=10)
    parser.add_argument("--seed", type=seed_type, default=0, help="seed of the first episode (integer ≥ 0)")
    parser.add_argument("--param", action="append", metavar="KEY=VALUE", help="environment argument (JSON value)")
    parser.add_argument(
        "--trust-pickle",
        action="store_true",
        help="load a learned model's run written before the safe formats (it unpickles: only a run you made)",
    )


def check_writable_file(path: str | Path, flag: str) -> Path:
    """Fail early, before any work, when ``path`` cannot be written: ``ValueError`` naming ``flag``.

    Creates the missing parent directories (as the write itself would) and tries a temporary file there,
    so permissions, read-only file systems and a directory in the way are all caught up front.
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{flag} {str(path)!r} is a directory; give a file name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.name}.", suffix=TEMP_SUFFIX):
            pass
    except OSError as exc:
        raise ValueError(f"{flag} {str(path)!r} is not writable: {exc.strerror or exc}") from exc
    return path


def check_writable_dir(path: str | Path, flag: str) -> Path:
    """Like :func:`check_writable_file` for an output directory (created when missing)."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-check.", suffix=TEMP_SUFFIX):
            pass
    except FileExistsError as exc:
        raise ValueError(f"{flag} {str(path)!r} is a file, not a directory") from exc
    except OSError as exc:
        raise ValueError(f"{flag} {str(path)!r} is not writable: {exc.strerror or exc}") from exc
    return path
