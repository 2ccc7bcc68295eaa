"""``adaptiveh monitor``: serve the operator's web page for one robot (prints the control token)."""

from __future__ import annotations

import argparse

from deploy.commands import add_part_arguments, setup_logging


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("monitor", help="serve the monitor web page (retreats, chunks, camera, e-stop)")
    add_part_arguments(p, "name, zenoh, monitor")
    p.add_argument("--port", type=int, default=None, help="override monitor.port (0: any free port)")
    p.add_argument("--token", default="", help="control token (default: a random one, printed)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from deploy.config import load_stack_config
    from deploy.monitor.server import MonitorConfig, MonitorServer
    from deploy.node import run_until_stopped
    from deploy.transport import Bus, open_session

    setup_logging(args.log_level)
    cfg = load_stack_config(args.config, monitor={"port": args.port})
    bus = Bus(open_session(cfg.zenoh), cfg.name)
    server = MonitorServer(bus, cfg.monitor or MonitorConfig(), args.token or None)  # no section: defaults
    print(f"monitor: {server.url}?token={server.token}", flush=True)
    print(f"monitor token: {server.token}", flush=True)
    run_until_stopped(server, args.duration)
    return 0
