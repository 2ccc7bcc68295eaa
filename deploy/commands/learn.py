"""``adaptiveh learn``: run the learner process alone (it finds the robot over Zenoh)."""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys

from deploy.commands import add_token_argument, operator_token, setup_logging


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "learn", help="run the learner (AdaptiveH/RKHS/TD3/DDPG) against the robot over Zenoh"
    )
    p.add_argument(
        "--config", default="configs/sim.yaml", help="top-level YAML (name, zenoh, robot, learner)"
    )
    p.add_argument("--algo", default=None, help="override learner.algo")
    p.add_argument(
        "--steps", type=int, default=None, help="override learner.steps (total, including resumed)"
    )
    p.add_argument("--checkpoint-dir", default=None, help="override learner.checkpoint_dir")
    p.add_argument("--policy-from", default=None, metavar="PATH", help="override learner.policy_from")
    add_token_argument(p)
    p.add_argument("--log-level", default="INFO")
    p.set_defaults(func=run)


LEARNER_STOP_DEADLINE_S = 30.0


def run(args: argparse.Namespace) -> int:
    from bus.node import on_stop_signal
    from deploy.config import load_stack_config
    from deploy.learner_node import LearnerNode

    setup_logging(args.log_level)
    overrides = {
        "algo": args.algo,
        "steps": args.steps,
        "checkpoint_dir": args.checkpoint_dir,
        "policy_from": args.policy_from,
    }
    cfg = load_stack_config(args.config, learner=overrides)
    node = LearnerNode(cfg, control_token=operator_token(args))
    # Its last checkpoint and result are written on the way out: more time than a part's 10 s.
    on_stop_signal(node.request_stop, signal.SIGTERM, signal.SIGINT, deadline_s=LEARNER_STOP_DEADLINE_S)
    lc = cfg.learner
    logging.info(
        "learner %s on '%s': %d steps (resuming at %d), checkpoints in %s",
        lc.algo,
        cfg.name,
        lc.steps,
        node.resumed_from,
        node.ckpt.parent,
    )
    try:
        result = node.run()
    finally:
        node.close()
    keys = ("summary", "dropped_actions", "retreat_preemptions")
    json.dump({k: result[k] for k in keys if k in result}, sys.stdout, default=float)
    print()
    return 0
