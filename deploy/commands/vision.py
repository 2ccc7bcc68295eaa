"""``adaptiveh vision``: run the vision process alone (sim frames over Zenoh, or a RealSense)."""

from __future__ import annotations

import argparse
import logging

from deploy.commands import add_part_arguments, add_token_argument, operator_token, setup_logging


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("vision", help="run the vision process: camera frames in, 3D target out")
    add_part_arguments(p, "name, zenoh, vision", per_arm=True)
    add_token_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bus.node import run_until_stopped
    from deploy.config import load_stack_config
    from deploy.vision_node import VisionNode
    from vision.cameras.protocol import CameraError

    setup_logging(args.log_level)
    cfg = load_stack_config(args.config).for_arm(args.arm)
    try:
        node = VisionNode(cfg, token=operator_token(args))
    except CameraError as exc:
        logging.error("%s", exc)
        return 3
    logging.info("vision '%s' up: camera %s", cfg.bus_key, cfg.vision.camera)
    run_until_stopped(node, args.duration)
    logging.info("vision stopped: %d frames processed, %d dropped", node.frames, node.dropped)
    return 0
