"""Lock the process's memory (``mlockall``) so the 1 kHz loop never waits on a page fault.

On a kernel without PREEMPT_RT a page fault in franky's FIFO thread (a page swapped out, or a fresh
page touched while the disk is busy) stalls it for milliseconds; 20 lost cycles in a row are a
``communication_constraints_violation``. libfranka's real-time guide locks memory for the same reason.
"""

from __future__ import annotations

import ctypes
import errno
import os

MCL_CURRENT = 1  # <sys/mman.h>: the pages mapped now
MCL_FUTURE = 2  # and every page mapped from now on (new heaps, thread stacks)


class MemoryLockError(RuntimeError):
    """The OS refused to lock this process's memory."""


def lock_memory() -> None:
    """``mlockall(MCL_CURRENT | MCL_FUTURE)``; raises :class:`MemoryLockError` naming the fix."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0:
        return
    code = ctypes.get_errno()
    hint = {
        errno.EPERM: "its memlock limit is 0 and it lacks CAP_IPC_LOCK",
        errno.ENOMEM: "its memlock limit is below what it has mapped",
    }.get(code, "see mlockall(2)")
    raise MemoryLockError(
        f"robot.franka.lock_memory: mlockall failed ({os.strerror(code)}): {hint}; raise it with "
        "`ulimit -l unlimited` (or a memlock line in /etc/security/limits.conf for the realtime group), "
        "or set lock_memory: false"
    )
