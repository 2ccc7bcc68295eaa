"""``adaptiveh router``: a Zenoh router (Python session in router mode); ``zenohd`` is the production one."""

from __future__ import annotations

import argparse
import json
import threading

from deploy.commands import on_stop_signal


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("router", help="run a Zenoh router that parts connect to as clients")
    p.add_argument(
        "--listen", action="append", default=[], help="endpoint, e.g. tcp/0.0.0.0:7447 (repeatable)"
    )
    p.add_argument("--connect", action="append", default=[], help="another router to join (repeatable)")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: until ^C)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import signal

    import zenoh

    listen = args.listen or ["tcp/0.0.0.0:7447"]
    zc = zenoh.Config()
    zc.insert_json5("mode", json.dumps("router"))
    zc.insert_json5("listen/endpoints", json.dumps(listen))
    zc.insert_json5("connect/endpoints", json.dumps(args.connect))
    zc.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(zc)
    stop = threading.Event()
    on_stop_signal(stop.set, signal.SIGTERM)
    print(f"zenoh router {session.zid()} listening on {listen}, connected to {args.connect}", flush=True)
    try:
        stop.wait(args.duration if args.duration > 0 else None)
    except KeyboardInterrupt:
        pass
    finally:
        session.close()
    return 0
