"""What ``adaptiveh up`` hands each part it starts through the environment (never argv, which other
users can read): the operator token and the supervisor's pid, so a part dies with its supervisor."""

from __future__ import annotations

import os
import signal
import sys

SUPERVISOR_ENV = "ADAPTIVEH_SUPERVISOR_PID"
TOKEN_ENV = "ADAPTIVEH_TOKEN"


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
