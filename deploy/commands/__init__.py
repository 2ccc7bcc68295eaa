"""One module per ``adaptiveh`` subcommand; each defines ``register(subparsers)``.

The CLI discovers the modules here, so adding a command never edits a shared file.
"""

import argparse
import logging
import os
import signal
import sys

LOG_FORMAT = "%(asctime)s %(name)s %(levelname)s %(message)s"


def add_part_arguments(parser: argparse.ArgumentParser, sections: str) -> None:
    """The options every part shares: ``--config``, ``--duration``, ``--log-level``."""
    parser.add_argument("--config", default="configs/sim.yaml", help=f"top-level YAML ({sections})")
    parser.add_argument(
        "--duration", type=float, default=0.0, help="stop after this many seconds (0: run until ^C)"
    )
    parser.add_argument("--log-level", default="INFO")


def setup_logging(level: str) -> None:
    """One log format for every process of the stack (their logs end up side by side)."""
    logging.basicConfig(level=level.upper(), format=LOG_FORMAT)


SUPERVISOR_ENV = "ADAPTIVEH_SUPERVISOR_PID"


def die_with_supervisor() -> None:
    """A part started by ``adaptiveh up`` gets SIGTERM when the supervisor dies, even by SIGKILL.

    Without this, a killed supervisor left robot-io driving the arm and the learner sending chunks.
    Linux only (prctl); elsewhere the part keeps running as before.
    """
    parent = os.environ.pop(SUPERVISOR_ENV, None)  # for this process only, not for its own children
    if not parent or not sys.platform.startswith("linux"):
        return
    import ctypes

    PR_SET_PDEATHSIG = 1
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM))
    if os.getppid() != int(parent):  # the supervisor died before prctl took effect
        sys.exit(f"adaptiveh: the supervisor (pid {parent}) is gone; not starting")
