"""``adaptiveh robot-io``: run the robot-interface process alone (one per arm)."""

from __future__ import annotations

import argparse
import logging

from deploy.commands import add_part_arguments, add_token_argument, operator_token, setup_logging


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("robot-io", help="run the robot interface (mock or Franka) over Zenoh")
    add_part_arguments(p, "name, zenoh, robot", per_arm=True)
    p.add_argument("--watch", default="learner", help="comma-separated peers whose absence holds the arm")
    add_token_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bus.node import run_until_stopped
    from deploy.config import load_stack_config
    from deploy.robot_io_node import RobotIONode

    setup_logging(args.log_level)
    cfg = load_stack_config(args.config).for_arm(args.arm)
    watch = tuple(p for p in args.watch.split(",") if p)
    node = RobotIONode(cfg, watch_peers=watch, control_token=operator_token(args))
    robot = cfg.robot
    logging.info("robot-io '%s' up: backend %s at %.0f Hz", cfg.bus_key, robot.backend, robot.control_rate_hz)
    run_until_stopped(node, args.duration)
    return 0
