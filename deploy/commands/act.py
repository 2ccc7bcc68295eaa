"""``adaptiveh act``: run the actor beside the arm (plans from the learner's newest policy snapshot)."""

from __future__ import annotations

import argparse
import logging

from deploy.commands import add_part_arguments, add_token_argument, operator_token, setup_logging


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "act", help="run the actor beside the robot: plans and retreats from the learner's policy snapshots"
    )
    add_part_arguments(p, "name, zenoh, robot, learner", per_arm=True)
    add_token_argument(p)
    p.add_argument(
        "--policy-from",
        default=None,
        metavar="PATH",
        help="override learner.policy_from (the actor then "
        "plans nothing before the learner's first snapshot)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bus.node import run_until_stopped
    from deploy.actor_node import ActorNode
    from deploy.config import load_stack_config
    from learner.segments import Execution

    setup_logging(args.log_level)
    cfg = load_stack_config(args.config, learner={"policy_from": args.policy_from}).for_arm(args.arm)
    if cfg.learner.execution != Execution.ACTOR:
        logging.error(
            "learner.execution is %r: the learner drives the arm itself, no actor runs", cfg.learner.execution
        )
        return 2
    node = ActorNode(cfg, control_token=operator_token(args))
    logging.info(
        "actor '%s' up: %s policy at %.0f Hz", cfg.bus_key, cfg.learner.algo, cfg.robot.control_rate_hz
    )
    run_until_stopped(node, args.duration)
    logging.info("actor stopped: %s", node.counts)
    if node.error:
        logging.error("acting ended: %s", node.error)
        return 1
    return 0
