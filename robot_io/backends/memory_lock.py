"""Lock the process's memory (``mlockall``) so the 1 kHz loop never waits on a page fault.

On a kernel without PREEMPT_RT a page fault in franky's FIFO thread (a page swapped out, or a fresh
page touched while the disk is busy) stalls it for milliseconds; 20 lost cycles in a row are a
``communication_constraints_violation``. libfranka's real-time guide locks memory for the same reason.
"""

from __future__ import annotations

import ctypes
import errno
import os
import resource

from common.errors import AdaptiveHError
from common.proc_status import status_field

MCL_CURRENT = 1  # <sys/mman.h>: the pages mapped now
MCL_FUTURE = 2  # and every page mapped from now on (new heaps, thread stacks)
CAP_IPC_LOCK = 14  # <linux/capability.h>
FIX = (
    "raise it with `ulimit -l unlimited` (or a memlock line in /etc/security/limits.conf), "
    "or set lock_memory: false"
)


class MemoryLockError(AdaptiveHError, RuntimeError):
    """The OS refused, or would later refuse, to lock this process's memory."""


def has_capability(bit: int) -> bool:
    """Whether this process's effective capability set holds ``bit`` (<linux/capability.h>)."""
    return bool(int(status_field("CapEff") or "0", 16) >> bit & 1)


def memlock_allowed() -> bool:
    """Locking stays allowed as the process grows: an unlimited memlock limit, or CAP_IPC_LOCK."""
    return resource.getrlimit(resource.RLIMIT_MEMLOCK)[0] == resource.RLIM_INFINITY or has_capability(
        CAP_IPC_LOCK
    )


def lock_memory() -> None:
    """``mlockall(MCL_CURRENT | MCL_FUTURE)``; raises :class:`MemoryLockError` naming the fix.

    Refused up front under a finite memlock limit even if it would fit now: with MCL_FUTURE every later
    mapping counts against it, and a robot-io that outgrows it mid-run fails an allocation."""
    if not memlock_allowed():
        limit = resource.getrlimit(resource.RLIMIT_MEMLOCK)[0]
        raise MemoryLockError(
            f"robot.franka.lock_memory: the memlock limit is {limit // 1024} KiB, not unlimited, and the "
            f"process lacks CAP_IPC_LOCK; {FIX}"
        )
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE) == 0:
        return
    code = ctypes.get_errno()
    hint = {errno.ENOMEM: "out of memory to lock"}.get(code, "see mlockall(2)")
    raise MemoryLockError(f"robot.franka.lock_memory: mlockall failed ({os.strerror(code)}): {hint}; {FIX}")
