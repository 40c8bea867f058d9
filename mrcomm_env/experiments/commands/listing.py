"""``mrcomm list``: environment ids, their policies and reproductions."""

from __future__ import annotations

import argparse

from mrcomm_baselines import default_policy, policy_names
from mrcomm_env.experiments.reproductions import module as reproduction_module
from mrcomm_env.registry import env_class, env_ids


def add_parser(command) -> None:
    command("list", help="environment ids, policies and reproductions").set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    for env_id in env_ids():
        cls = env_class(env_id)
        print(f"{env_id}  —  {cls.DESCRIPTION}")
        policies = [f"{p}*" if p == default_policy(env_id) else p for p in policy_names(env_id)]
        print(f"    policies (* default): {', '.join(policies)}")
        print(f"    reproduction: {', '.join(reproduction_module(env_id).EXPERIMENTS)}")
    return 0
