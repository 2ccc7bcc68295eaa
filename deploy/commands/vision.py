"""``adaptiveh vision``: run the vision process alone (sim frames over Zenoh, or a RealSense)."""

from __future__ import annotations

import argparse
import logging
import signal

from deploy.commands import on_stop_signal, setup_logging


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("vision", help="run the vision process: camera frames in, 3D target out")
    p.add_argument("--config", default="configs/sim.yaml", help="top-level YAML (name, zenoh, vision)")
    p.add_argument(
        "--duration", type=float, default=0.0, help="stop after this many seconds (0: run until ^C)"
    )
    p.add_argument("--log-level", default="INFO")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from deploy.config import ConfigError
    from deploy.vision_node import VisionNode, load_settings
    from vision.cameras.protocol import CameraError

    setup_logging(args.log_level)
    try:
        settings = load_settings(args.config)
    except ConfigError as exc:
        logging.error("%s", exc)
        return 2
    try:
        node = VisionNode(settings)
    except CameraError as exc:
        logging.error("%s", exc)
        return 3
    on_stop_signal(node.request_stop, signal.SIGTERM)
    logging.info("vision '%s' up: camera %s", settings.name, settings.vision.camera)
    node.start()
    try:
        if args.duration > 0:
            node.wait(args.duration)
        else:
            while not node.wait(0.5):
                pass
    finally:
        node.stop()
        logging.info("vision stopped: %d frames processed, %d dropped", node.frames, node.dropped)
    return 0
