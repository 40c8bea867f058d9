"""``mrcomm actions``: what a policy chooses, beside the rules it is compared with, at the states it reaches
(:mod:`mrcomm_env.experiments.actions`)."""

from __future__ import annotations

import argparse

from mrcomm_baselines import policy_names
from mrcomm_env.experiments.actions import context_table, profile_actions, profile_table
from mrcomm_env.experiments.arguments import add_episode_arguments, check_writable_file, parse_params, split_values
from mrcomm_env.experiments.evaluation import acting_setting, baseline_label, limit_threads, make_any_policy
from mrcomm_env.experiments.io import atomic_write_json
from mrcomm_env.registry import canonical_id


def add_parser(command) -> None:
    p = command(
        "actions",
        help="what a policy chooses, and how often it chooses as each rule would at the same states",
    )
    p.add_argument("env_id")
    p.add_argument("--policy", required=True, help="the policy that acts (a baseline, pretrained or ALGO:RUN)")
    p.add_argument(
        "--against",
        required=True,
        action="append",
        metavar="RULE[:KEY=VALUE,…]",
        help="a policy asked at every state the policy reaches (its actions are not stepped): a scripted one, with "
        "its parameters after a colon (periodic_sketch:period=1), or a learned one (pretrained, ALGO:RUN); repeat "
        "for several",
    )
    add_episode_arguments(p)
    p.add_argument("--json", metavar="PATH", help="also write the counts as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    limit_threads()
    env_id = canonical_id(args.env_id)
    params = parse_params(args.param)
    json_path = check_writable_file(args.json, "--json") if args.json else None
    policy = make_any_policy(env_id, args.policy, trust_pickle=args.trust_pickle)
    rules = {}
    for text in args.against:
        name, _, rest = text.partition(":")
        if name.strip() in policy_names(env_id):  # a scripted rule, its parameters after the colon
            name, rule_params = name.strip(), parse_params([pair for pair in split_values(rest) if pair], "--against")
        else:  # a learned policy (ALGO:RUN, pretrained), or an unknown name make_any_policy reports
            name, rule_params = text, {}
        rules[baseline_label(name, rule_params)] = make_any_policy(
            env_id, name, trust_pickle=args.trust_pickle, **rule_params
        )
    params = acting_setting(policy, params)
    seeds = list(range(args.seed, args.seed + args.episodes))
    # the acting policy asked beside itself (e.g. to see how deterministic it is) gets a name of its own
    acting = args.policy if args.policy not in rules else f"{args.policy} (acting)"
    profile = profile_actions(env_id, params, policy, rules, seeds, policy_name=acting)
    print(f"{env_id}  policy={args.policy}  episodes={args.episodes}  seed={args.seed}  params={params}")
    print(f"{profile.decisions} decisions; each rule asked at every state the policy reached")
    print("\n".join(profile_table(profile)))
    if profile.by_context:
        print("by each robot's situation when it chose (the env's decision_context):")
        print("\n".join(context_table(profile)))
    if json_path is not None:
        atomic_write_json(json_path, {"env": env_id, "params": params, **profile.to_json()}, indent=2)
        print(f"wrote {json_path}")
    return 0
