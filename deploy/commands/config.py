"""``adaptiveh config show FILE``: the stack config as the parts read it, overlays resolved and checked.
``adaptiveh config reference``: regenerate the configuration reference (docs/reference/) from the models."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from deploy.config import compose_stack_yaml, load_stack_config


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "config",
        help="show a stack config with its overlays resolved; regenerate the configuration reference",
        description="show: print FILE with its base: and learner.agent_from: overlays resolved, after "
        "checking it as every part does (a bad key exits 2 naming it). reference: rewrite the "
        "configuration reference (docs/reference/) from the config models.",
    )
    actions = p.add_subparsers(dest="action", required=True)
    show = actions.add_parser("show", help="print the merged config")
    show.add_argument("file", help="a stack config, e.g. configs/sim.yaml")
    show.set_defaults(func=run)
    ref = actions.add_parser(
        "reference",
        help="regenerate docs/reference/ (every key: type, default, bounds, description)",
        description="Write the configuration reference pages from the config models (descriptions are "
        "the models' # comments); only the pages that changed are written.",
    )
    ref.add_argument(
        "--dir", default=None, help="where the pages go (default: the repository's docs/reference)"
    )
    ref.add_argument("--check", action="store_true", help="write nothing; exit 1 if a page is stale")
    ref.set_defaults(func=reference)


def run(args: argparse.Namespace) -> int:
    load_stack_config(args.file)  # the checks every part makes; a ConfigError exits 2 with the key
    text = yaml.safe_dump(compose_stack_yaml(args.file), sort_keys=False, default_flow_style=None, width=200)
    print(text, end="")
    return 0


def reference(args: argparse.Namespace) -> int:
    from deploy.config_reference import COMMAND, REFERENCE_DIR, render_pages, stale_pages, write_pages

    directory = Path(args.dir) if args.dir else REFERENCE_DIR
    pages = render_pages()
    if args.check:
        stale = stale_pages(pages, directory)
        for name in stale:
            print(f"{directory / name}: stale; run `{COMMAND}`", file=sys.stderr)
        return 1 if stale else 0
    written = write_pages(pages, directory)
    for path in written:
        print(f"wrote {path}")
    if not written:
        print(f"{directory}: up to date")
    return 0
