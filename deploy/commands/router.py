"""``adaptiveh router``: a Zenoh router (Python session in router mode); ``zenohd`` is the production one."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("router", help="run a Zenoh router that parts connect to as clients")
    p.add_argument(
        "--listen", action="append", default=[], help="endpoint, e.g. tcp/0.0.0.0:7447 (repeatable)"
    )
    p.add_argument("--connect", action="append", default=[], help="another router to join (repeatable)")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: until ^C)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from deploy.node import Node, run_until_stopped
    from deploy.transport import ZenohConfig

    listen = args.listen or ["tcp/0.0.0.0:7447"]
    router = Node("router", ZenohConfig(mode="router", listen=tuple(listen), connect=tuple(args.connect)))
    zid = router.bus.session.zid()
    print(f"zenoh router {zid} listening on {listen}, connected to {args.connect}", flush=True)
    run_until_stopped(router, args.duration)
    return 0
