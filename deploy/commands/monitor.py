"""``adaptiveh monitor``: serve the operator's web page for one robot, and the Foxglove live view beside it
(``monitor.foxglove_port``; prints its ``ws://`` URL).

It prints the page's URL without the token: under ``adaptiveh up`` its output is monitor.log, and a log
file must never hold the secret that moves the arm. How the operator learns the token: ``TOKEN_HELP``.
"""

from __future__ import annotations

import argparse

from deploy.commands import (
    TOKEN_HELP,
    add_part_arguments,
    add_token_argument,
    operator_token,
    setup_logging,
    show_token,
)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "monitor",
        help="serve the monitor web page (retreats, chunks, camera, e-stop)",
        description=f"Serve the monitor web page for one robot. {TOKEN_HELP}",
    )
    add_part_arguments(p, "name, zenoh, monitor")
    p.add_argument("--port", type=int, default=None, help="override monitor.port (0: any free port)")
    add_token_argument(p)
    p.add_argument(
        "--foxglove-port", type=int, default=None, help="override monitor.foxglove_port (0: any free port)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bus.node import run_until_stopped
    from bus.signing import mac_key
    from bus.transport import Bus, open_session
    from deploy.config import load_stack_config
    from monitor.foxglove.derive import SceneSetup
    from monitor.foxglove.live import start_live
    from monitor.server import MonitorConfig, MonitorServer

    setup_logging(args.log_level)
    cfg = load_stack_config(args.config, monitor={"port": args.port, "foxglove_port": args.foxglove_port})
    mcfg = cfg.monitor or MonitorConfig()
    token = operator_token(args)
    bus = Bus(open_session(cfg.zenoh), cfg.name, mac_key(token))  # signs controls with the stack's key
    # With the stack's key the page and the live view believe only what the stack signed; the view
    # limits keep out-of-range values off the plots.
    limits = cfg.view_limits()
    # A token given, else a random one (its controls are not the stack's); a fleet's arms listed.
    server = MonitorServer(bus, mcfg, token or None, limits, arms=cfg.arm_names)
    setup = SceneSetup.from_vision(cfg.vision)
    live = start_live(
        bus.session,
        cfg.name,
        setup,
        mcfg.host,
        mcfg.foxglove_port,
        cfg.recording.exclude,
        bus.signing_key,
        limits,
    )
    print(f"monitor: {server.url}", flush=True)  # the supervisor reads this line from monitor.log
    token_file = None if token else show_token(server.token, cfg.name)
    if live is not None:
        print(f"foxglove: {live.url}", flush=True)
    try:
        run_until_stopped(server, args.duration)
    finally:
        if live is not None:
            live.close()
        if token_file is not None:
            token_file.unlink(missing_ok=True)  # the token dies with this monitor
    return 0
