"""``adaptiveh config show FILE``: the stack config as the parts read it, overlays resolved and checked."""

from __future__ import annotations

import argparse

import yaml

from deploy.config import compose_stack_yaml, load_stack_config


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "config",
        help="show a stack config with its overlays resolved",
        description="Print FILE with its base: and learner.agent_from: overlays resolved, after checking it "
        "as every part does (a bad key exits 2 naming it).",
    )
    actions = p.add_subparsers(dest="action", required=True)
    show = actions.add_parser("show", help="print the merged config")
    show.add_argument("file", help="a stack config, e.g. configs/sim.yaml")
    show.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    load_stack_config(args.file)  # the checks every part makes; a ConfigError exits 2 with the key
    text = yaml.safe_dump(compose_stack_yaml(args.file), sort_keys=False, default_flow_style=None, width=200)
    print(text, end="")
    return 0
