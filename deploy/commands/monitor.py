"""``adaptiveh monitor``: serve the operator's web page for one robot (prints the control token)."""

from __future__ import annotations

import argparse
import logging
import signal
import threading

from deploy.commands import on_stop_signal, setup_logging


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("monitor", help="serve the monitor web page (retreats, chunks, camera, e-stop)")
    p.add_argument("--config", default="configs/sim.yaml", help="top-level YAML (name, zenoh, monitor)")
    p.add_argument("--port", type=int, default=None, help="override monitor.port (0: any free port)")
    p.add_argument("--token", default="", help="control token (default: a random one, printed)")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: until ^C)")
    p.add_argument("--log-level", default="INFO")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from deploy.config import ConfigError, build, load_yaml
    from deploy.monitor.server import MonitorConfig, MonitorServer
    from deploy.transport import Bus, ZenohConfig, open_session

    setup_logging(args.log_level)
    try:
        data = load_yaml(args.config)
        section = dict(data.get("monitor") or {})
        if args.port is not None:
            section["port"] = args.port
        cfg = build(MonitorConfig, section, f"{args.config}: monitor")
        zc = build(ZenohConfig, data.get("zenoh"), "zenoh")
    except ConfigError as exc:
        logging.error("%s", exc)
        return 2
    bus = Bus(open_session(zc), data.get("name", "panda"))
    server = MonitorServer(bus, cfg, args.token or None).start()
    stop = threading.Event()
    on_stop_signal(stop.set, signal.SIGTERM)
    print(f"monitor: {server.url}?token={server.token}", flush=True)
    print(f"monitor token: {server.token}", flush=True)
    try:
        stop.wait(args.duration if args.duration > 0 else None)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
        bus.close()
    return 0
