"""``adaptiveh router``: a Zenoh router (Python session in router mode); ``zenohd`` is the production one.

With ``--config`` the router takes that file's ``zenoh`` section: its TLS certificate (identity
``router``), the user:password dictionary and the access control of ``zenoh.router`` (bus.security).
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("router", help="run a Zenoh router that parts connect to as clients")
    p.add_argument(
        "--listen", action="append", default=[], help="endpoint, e.g. tcp/0.0.0.0:7447 (repeatable)"
    )
    p.add_argument("--connect", action="append", default=[], help="another router to join (repeatable)")
    p.add_argument(
        "--config",
        default="",
        help="a stack YAML whose zenoh section secures the router (tls, auth, router: listen,"
        " dictionary_file, access_control)",
    )
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: until ^C)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bus.node import Node, run_until_stopped
    from bus.transport import ZenohConfig

    if args.config:
        from deploy.config import load_stack_config

        zc = load_stack_config(args.config).zenoh
        default = f"{'tls' if zc.tls else 'tcp'}/0.0.0.0:7447"
        listen = args.listen or list(zc.router.listen if zc.router else ()) or [default]
        update = {"mode": "router", "listen": tuple(listen), "connect": tuple(args.connect)}
        cfg = ZenohConfig.model_validate({**zc.model_dump(), **update})  # checked again: tls endpoints
    else:
        listen = args.listen or ["tcp/0.0.0.0:7447"]
        cfg = ZenohConfig(mode="router", listen=tuple(listen), connect=tuple(args.connect))
    router = Node("router", cfg)
    zid = router.bus.session.zid()
    secured = ""
    if args.config:
        acl = cfg.router.access_control if cfg.router else "none"
        tls, auth = ("on" if x is not None else "off" for x in (cfg.tls, cfg.auth))
        secured = f"; tls {tls}, auth {auth}, access control {acl}"
    print(f"zenoh router {zid} listening on {listen}, connected to {args.connect}{secured}", flush=True)
    run_until_stopped(router, args.duration)
    return 0
