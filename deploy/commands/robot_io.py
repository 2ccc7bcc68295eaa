"""``adaptiveh robot-io``: run the robot-interface process alone (one per arm)."""

from __future__ import annotations

import argparse
import logging
import signal

from deploy.commands import on_stop_signal, setup_logging
from deploy.config import ConfigError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("robot-io", help="run the robot interface (mock or Franka) over Zenoh")
    p.add_argument("--config", default="configs/sim.yaml", help="top-level YAML (name, zenoh, robot)")
    p.add_argument("--watch", default="learner", help="comma-separated peers whose absence holds the arm")
    p.add_argument("--token", default="", help="operator token required on control messages (e-stop exempt)")
    p.add_argument(
        "--duration", type=float, default=0.0, help="stop after this many seconds (0: run until ^C)"
    )
    p.add_argument("--log-level", default="INFO")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from deploy.robot_io_node import RobotIONode, load_settings

    setup_logging(args.log_level)
    try:
        settings = load_settings(args.config)
    except ConfigError as exc:
        logging.error("%s", exc)
        return 2
    watch = tuple(p for p in args.watch.split(",") if p)
    node = RobotIONode(settings, watch_peers=watch, control_token=args.token)
    on_stop_signal(node.request_stop, signal.SIGTERM)
    logging.info(
        "robot-io '%s' up: backend %s at %.0f Hz",
        settings.name,
        settings.robot.backend,
        settings.robot.control_rate_hz,
    )
    node.start()
    try:
        if args.duration > 0:
            node.wait(args.duration)
        else:
            while not node.wait(0.5):
                pass
    finally:
        node.stop()
    return 0
