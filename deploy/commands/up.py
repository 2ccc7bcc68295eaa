"""``adaptiveh up``: the whole stack (robot-io, vision, learner, monitor) in one command."""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys

from deploy.commands import add_token_argument, operator_token, setup_logging
from deploy.part_env import TOKEN_ENV

TOKEN_NOTE = (
    "A random operator token is printed on this terminal, and nowhere else: the parts' logs "
    "(<run>/logs, mode 0600) and the monitor's URL never hold it; the page asks for it once. For runs "
    f"whose output goes to a file (nohup, systemd) give your own with --token-file or ${TOKEN_ENV}: a "
    "token given is never printed."
)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "up",
        help="start the whole stack on this machine (Ctrl-C stops it cleanly)",
        description=f"Start the whole stack on this machine. {TOKEN_NOTE}",
    )
    p.add_argument("config", nargs="?", default="configs/sim.yaml", help="top-level YAML")
    p.add_argument(
        "--check", action="store_true", help="validate the config and look for drivers; start nothing"
    )
    p.add_argument(
        "--probe-arm", action="store_true", help="with --check: connect to the Franka and read its version"
    )
    p.add_argument("--steps", type=int, default=None, help="override learner.steps")
    p.add_argument(
        "--policy-from",
        default=None,
        metavar="PATH",
        help="start the learner from this checkpoint (a file or run folder): learner.policy_from",
    )
    p.add_argument(
        "--arms",
        default=None,
        metavar="A,B",
        help="fleet configs: run only these arms' parts (robot-io, actor, vision), as another machine that"
        " joins the fleet through the routers does; 'none': the learner and monitor only",
    )
    add_token_argument(p)  # default: a random token, printed (TOKEN_NOTE)
    p.add_argument("--summary", default="", help="also write the summary JSON here")
    p.add_argument("--log-level", default="INFO")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bus.node import on_stop_signal
    from deploy.config import ConfigError
    from deploy.run_report import summary_table
    from deploy.stack import Stack, check

    setup_logging(args.log_level)
    if args.check:
        ok, lines = check(args.config, probe_arm=args.probe_arm, policy_from=args.policy_from)
        for line in lines:
            print(line)
        return 0 if ok else 1
    given = operator_token(args)
    arms = None if args.arms is None else [a for a in args.arms.split(",") if a and a != "none"]
    try:
        stack = Stack(
            args.config, token=given or None, steps=args.steps, policy_from=args.policy_from, arms=arms
        )
    except ConfigError as exc:
        logging.error("%s", exc)
        return 2
    tell_token(stack.token, (args.token_file or f"${TOKEN_ENV}") if given else "")
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
    learner_ok = summary["exit_codes"].get("learner") == 0 or "learner" not in summary["exit_codes"]
    return 0 if learner_ok and not summary["gave_up"] else 1


def tell_token(token: str, source: str) -> None:
    """The operator's token on this terminal, the first line (scripts and tests read it there); one
    the operator gave (``source``) is not repeated, to keep it out of output redirected to a file."""
    if source:
        print(f"using the operator token from {source} (not printed)", flush=True)
        return
    print(f"operator token: {token}", flush=True)
    if not sys.stdout.isatty():
        logging.warning(
            "stdout is not a terminal, yet holds the operator token; for unattended runs "
            "give one with --token-file (never printed)"
        )
