"""One module per ``adaptiveh`` subcommand; each defines ``register(subparsers)``.

The CLI discovers the modules here, so adding a command never edits a shared file.
"""

import logging
import os
import signal
import sys
import threading
from collections.abc import Callable

LOG_FORMAT = "%(asctime)s %(name)s %(levelname)s %(message)s"


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


def on_stop_signal(action: Callable[[], None], *signums: int) -> None:
    """Run ``action`` (e.g. ``node.request_stop``) when one of ``signums`` arrives, on its own thread.

    A handler runs in the main thread between two bytecodes, possibly while that thread holds a lock
    inside ``Event.wait``; setting an Event from the handler itself can then deadlock (seen: robot-io
    hung for good on SIGTERM after its supervisor was killed). The handler only starts a thread.
    """

    def handler(signum: int, frame: object) -> None:
        threading.Thread(target=action, name=f"on-signal-{signum}", daemon=True).start()

    for signum in signums:
        signal.signal(signum, handler)
