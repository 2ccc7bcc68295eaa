"""``adaptiveh up``: the whole stack (robot-io, vision, learner, monitor) in one command."""

from __future__ import annotations

import argparse
import json
import logging
import signal

from deploy.commands import add_token_argument, operator_token, setup_logging


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("up", help="start the whole stack on this machine (Ctrl-C stops it cleanly)")
    p.add_argument("config", nargs="?", default="configs/sim.yaml", help="top-level YAML")
    p.add_argument(
        "--check", action="store_true", help="validate the config and look for drivers; start nothing"
    )
    p.add_argument(
        "--probe-arm", action="store_true", help="with --check: connect to the Franka and read its version"
    )
    p.add_argument("--steps", type=int, default=None, help="override learner.steps")
    add_token_argument(p)  # default: a random token, printed
    p.add_argument("--summary", default="", help="also write the summary JSON here")
    p.add_argument("--log-level", default="INFO")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bus.node import on_stop_signal
    from deploy.run_report import summary_table
    from deploy.stack import Stack, check

    setup_logging(args.log_level)
    if args.check:
        ok, lines = check(args.config, probe_arm=args.probe_arm)
        for line in lines:
            print(line)
        return 0 if ok else 1
    stack = Stack(args.config, token=operator_token(args) or None, steps=args.steps)
    print(f"operator token: {stack.token}", flush=True)
    on_stop_signal(stack.request_stop, signal.SIGTERM, signal.SIGINT)
    try:
        summary = stack.run()
    except RuntimeError as exc:
        logging.error("%s", exc)
        return 2
    text = json.dumps(summary, indent=1)
    print("summary:\n" + summary_table(summary))
    print(f"summary file: {summary['summary_file']}")
    if summary["learning_curve"]:
        print(f"learning curve: {summary['learning_curve']}")
    if args.summary:
        with open(args.summary, "w") as fh:
            fh.write(text)
    return 0 if summary["exit_codes"].get("learner") == 0 and not summary["gave_up"] else 1
