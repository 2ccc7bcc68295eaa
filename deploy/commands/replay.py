"""``adaptiveh replay FILE``: play a recorded run back onto Zenoh, into a monitor started here.

The replay publishes under ``adaptiveh/<as>/…`` (default ``<recorded robot>-replay``) so recorded
chunks and controls never reach a live robot of the recorded name; the monitor here follows that name.
Its page's token is made up here and never printed into a log (``TOKEN_HELP``).
"""

from __future__ import annotations

import argparse
import logging
import signal
import threading

from deploy.commands import TOKEN_HELP, setup_logging, show_token


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "replay",
        help="replay an MCAP recording into the monitor",
        description=f"Replay an MCAP recording into a monitor started here. {TOKEN_HELP}",
    )
    p.add_argument("file", help="a .mcap written by adaptiveh up")
    p.add_argument("--config", default="configs/sim.yaml", help="top-level YAML (zenoh, monitor)")
    p.add_argument("--speed", type=float, default=1.0, help="playback speed factor")
    p.add_argument(
        "--as",
        dest="robot",
        default=None,
        help="robot name to publish under (default: <recorded name>-replay; the recorded name itself "
        "would drive a live robot of that name)",
    )
    p.add_argument("--no-monitor", action="store_true", help="only publish; a monitor runs elsewhere")
    p.add_argument("--port", type=int, default=None, help="override monitor.port")
    p.add_argument(
        "--wait-subscribers", type=float, default=5.0, help="with --no-monitor: wait this long for a listener"
    )
    p.add_argument(
        "--keep", type=float, default=-1.0, help="seconds the monitor stays up after playback (-1: until ^C)"
    )
    p.add_argument("--log-level", default="INFO")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bus.node import on_stop_signal
    from bus.transport import Bus, open_session
    from deploy.config import load_stack_config
    from monitor.foxglove.derive import SceneSetup
    from monitor.foxglove.live import start_live
    from monitor.recording import read, recorded_robot, replay, replayable
    from monitor.server import MonitorConfig, MonitorServer

    setup_logging(args.log_level)
    stack = load_stack_config(args.config, monitor={"port": args.port})
    zc, mcfg = stack.zenoh, stack.monitor or MonitorConfig()
    try:
        records = replayable(read(args.file))  # the robot's topics: not the derived Foxglove channels
        robot = args.robot or (recorded_robot(records[0][0]) + "-replay" if records else "replay")
    except Exception as exc:  # mcap raises its own types on a damaged file
        logging.error("%s: not a readable recording: %s", args.file, exc)
        return 2
    stop = threading.Event()
    on_stop_signal(stop.set, signal.SIGTERM, signal.SIGINT)
    session = open_session(zc)
    server = live = token_file = None
    if not args.no_monitor:
        server = MonitorServer(Bus(session, robot), mcfg).start()
        print(f"monitor: {server.url}", flush=True)
        token_file = show_token(server.token, robot)
        live = start_live(session, robot, SceneSetup.from_vision(stack.vision), mcfg.host, mcfg.foxglove_port)
        if live is not None:
            print(f"foxglove: {live.url}", flush=True)
    print(f"replaying {len(records)} messages as adaptiveh/{robot}/...", flush=True)
    try:
        n = replay(
            session,
            args.file,
            args.speed,
            stop=stop,
            robot=robot,
            wait_subscribers_s=0.0 if server is not None else args.wait_subscribers,
        )
        print(f"replayed {n} messages from {args.file}", flush=True)
        if server is not None and not stop.is_set():
            print("replay done; the monitor stays up (Ctrl-C stops it)", flush=True)
            stop.wait(args.keep if args.keep >= 0 else None)
    finally:
        if live is not None:
            live.close()
        if server is not None:
            server.stop()  # closes its bus, and with it the session
        else:
            session.close()
        if token_file is not None:
            token_file.unlink(missing_ok=True)  # the token dies with this monitor
    return 0
