"""Argument types of the ``mrcomm`` commands: a leaf module every command's module imports (none imports another
command's module for them)."""

from __future__ import annotations

import argparse
import json
import math


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
