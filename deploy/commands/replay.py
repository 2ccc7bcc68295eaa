"""``adaptiveh replay FILE``: play a recorded run back onto Zenoh, into a monitor started here."""

from __future__ import annotations

import argparse
import logging


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("replay", help="replay an MCAP recording into the monitor")
    p.add_argument("file", help="a .mcap written by adaptiveh up")
    p.add_argument("--config", default="configs/sim.yaml", help="top-level YAML (zenoh, monitor)")
    p.add_argument("--speed", type=float, default=1.0, help="playback speed factor")
    p.add_argument("--no-monitor", action="store_true", help="only publish; a monitor runs elsewhere")
    p.add_argument("--port", type=int, default=None, help="override monitor.port")
    p.add_argument("--log-level", default="INFO")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from deploy.config import ConfigError, build, load_yaml
    from deploy.monitor.server import MonitorConfig, MonitorServer
    from deploy.recording import replay
    from deploy.transport import Bus, ZenohConfig, open_session

    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        data = load_yaml(args.config)
        zc = build(ZenohConfig, data.get("zenoh"), "zenoh")
        section = dict(data.get("monitor") or {})
        if args.port is not None:
            section["port"] = args.port
        mcfg = build(MonitorConfig, section, "monitor")
    except ConfigError as exc:
        logging.error("%s", exc)
        return 2
    session = open_session(zc)
    server = None
    if not args.no_monitor:
        # The recorded robot name comes from the keys; the monitor listens for the config's name.
        server = MonitorServer(Bus(session, data.get("name", "panda")), mcfg).start()
        print(f"monitor: {server.url}?token={server.token}", flush=True)
    try:
        n = replay(session, args.file, args.speed)
        print(f"replayed {n} messages from {args.file}")
        if server is not None:
            input("replay done; press Enter to stop the monitor ")
    except (KeyboardInterrupt, EOFError):
        pass
    finally:
        if server is not None:
            server.stop()
        session.close()
    return 0
