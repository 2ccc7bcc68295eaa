"""``adaptiveh fleet``: place a fleet's arms on a Ray cluster (deploy/ray_fleet.py says how)."""

from __future__ import annotations

import argparse
import logging
import signal
from typing import TYPE_CHECKING

from deploy.commands import add_token_argument, operator_token, setup_logging
from deploy.part_env import TOKEN_ENV

if TYPE_CHECKING:
    from deploy.ray_fleet import RayFleet

DESCRIPTION = (
    "Place each arm of the config's fleet (its robot-io and actor, as adaptiveh up starts them) on the nodes"
    " of a Ray cluster, one Ray actor per arm, spread over the nodes and restarted by Ray; Ctrl-C or SIGTERM"
    " stops them all. The learner and monitor are not placed: run them where the operator is, with"
    " `adaptiveh router --listen tcp/0.0.0.0:7447` and `adaptiveh up CONFIG --arms none` (its zenoh.connect"
    " that router), then `adaptiveh fleet --ray HEAD:6379 --arms N --config CONFIG --connect"
    f" tcp/LEARNER_HOST:7447` with the same operator token (--token-file or ${TOKEN_ENV}). This tree is"
    " shipped to the nodes as the Ray job's working directory; each arm's config and logs are written on its"
    " node under --node-dir."
)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "fleet",
        help="place a fleet's arms on a Ray cluster's nodes (Ctrl-C stops them)",
        description=DESCRIPTION,
    )
    p.add_argument(
        "--ray", required=True, metavar="ADDRESS", help="the Ray cluster: HEAD:PORT, ray://HEAD:PORT or auto"
    )
    p.add_argument(
        "--arms",
        type=int,
        required=True,
        metavar="N",
        help="how many arms to place: the config's fleet arms first, in order; beyond them arm<i> with seed i"
        " (i counting from 0 over the fleet: after two named arms, arm2 with seed 2)",
    )
    p.add_argument("--config", default="configs/fleet.yaml", help="top-level YAML with a fleet section")
    p.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="a Zenoh router the arms join, e.g. tcp/LEARNER_HOST:7447 (repeatable; default: the config's"
        " zenoh.connect); the arms are always its clients (zenoh.mode client)",
    )
    p.add_argument(
        "--cpus-per-arm",
        type=float,
        default=1.0,
        metavar="CPUS",
        help="Ray CPUs each arm holds (robot-io and its actor)",
    )
    p.add_argument(
        "--resource",
        default="",
        metavar="NAME",
        help="a custom Ray resource each arm takes one unit of: arms go only to nodes started with it (e.g."
        " ray start --resources '{\"robot\": 1}' on each robot PC), as many as it has units",
    )
    p.add_argument(
        "--max-restarts",
        type=int,
        default=None,
        metavar="N",
        help="restarts Ray gives each arm (default: supervisor.max_restarts)",
    )
    p.add_argument(
        "--node-dir",
        default="~/.cache/adaptiveh/fleet",
        metavar="DIR",
        help="where on its node an arm's config and logs go: <node-dir>/<name>/<arm>/",
    )
    p.add_argument(
        "--duration",
        type=float,
        default=0.0,
        metavar="S",
        help="stop the arms after this many seconds (0: until ^C)",
    )
    add_token_argument(p)
    p.add_argument("--log-level", default="INFO")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from common.config import ConfigError

    setup_logging(args.log_level)
    try:
        from deploy.ray_fleet import FleetError
    except ImportError as exc:
        if exc.name != "ray":
            raise
        logging.error("adaptiveh fleet needs Ray: pip install -e '.[ray]'")
        return 2
    token = operator_token(args)
    if not token:
        logging.error(
            "the arms sign with the learner's operator token: give it with --token-file or $%s", TOKEN_ENV
        )
        return 2
    try:
        fleet = _fleet(args, token)
    except (FleetError, ConfigError) as exc:
        logging.error("%s", exc)
        return 2
    return _place_and_watch(fleet, args)


def _fleet(args: argparse.Namespace, token: str) -> RayFleet:
    """The fleet the options and the config describe, checked; nothing placed yet."""
    from deploy.ray_fleet import Placement, RayFleet, fleet_config

    config, cfg = fleet_config(args.config, args.arms, tuple(args.connect))
    restarts = cfg.supervisor.max_restarts if args.max_restarts is None else args.max_restarts
    return RayFleet(config, token, Placement(args.cpus_per_arm, args.resource, restarts, args.node_dir))


def _place_and_watch(fleet: RayFleet, args: argparse.Namespace) -> int:
    """Place the arms, tell where each runs, keep them until a stop; 1 if an arm used its restarts."""
    from bus.node import on_stop_signal
    from deploy.ray_fleet import FleetError

    try:
        fleet.connect(args.ray)
        on_stop_signal(fleet.request_stop, signal.SIGTERM, signal.SIGINT)  # after ray.init: it sets its own
        for arm, where in fleet.place().items():
            print(
                f"{arm}: node {where.node_id} ({where.host}, {where.ip}), logs {where.dir}/logs", flush=True
            )
        gave_up = fleet.watch(args.duration)
    except FleetError as exc:
        logging.error("%s", exc)
        return 2
    finally:
        codes = fleet.stop()
    for arm, parts in codes.items():
        print(f"{arm}: " + ("gone before the stop" if parts is None else f"stopped, exit codes {parts}"))
    return 1 if gave_up else 0
