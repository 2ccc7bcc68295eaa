"""Can this machine run franky's 1 kHz loop as ``robot.franka`` asks? What ``adaptiveh up --check`` reports.

The three things libfranka and robot-io ask of the host: a real-time kernel (libfranka reads
``/sys/kernel/realtime``; under ``realtime: enforce`` it refuses to move without one), permission to
raise the loop's thread to SCHED_FIFO 99 (an ``rtprio`` limit of 99, or CAP_SYS_NICE), and, with
``lock_memory``, permission to lock all of the process's memory (an unlimited ``memlock`` limit, or
CAP_IPC_LOCK). Under ``enforce`` a missing one is an error the check names; under ``ignore`` a note.
"""

from __future__ import annotations

import resource
from pathlib import Path

from robot_io.backends.franky_config import FrankaConfig
from robot_io.backends.memory_lock import has_capability, memlock_allowed

CAP_SYS_NICE = 23  # <linux/capability.h>
FIFO_PRIORITY = 99  # sched_get_priority_max(SCHED_FIFO): what libfranka asks for


def realtime_kernel(flag: Path = Path("/sys/kernel/realtime")) -> bool:
    """libfranka's own test (``hasRealtimeKernel``): the kernel's realtime flag reads 1."""
    try:
        return flag.read_text().strip() == "1"
    except OSError:
        return False


def fifo_allowed() -> bool:
    soft = resource.getrlimit(resource.RLIMIT_RTPRIO)[0]
    return soft == resource.RLIM_INFINITY or soft >= FIFO_PRIORITY or has_capability(CAP_SYS_NICE)


def host_report(fc: FrankaConfig) -> tuple[bool, list[str]]:
    """(ready, lines): each requirement met or not; unmet is an error only under ``realtime: enforce``."""
    enforce = fc.realtime == "enforce"
    needs = [
        ("real-time kernel", realtime_kernel(), "/sys/kernel/realtime reads 1 on a PREEMPT_RT kernel"),
        (
            f"SCHED_FIFO {FIFO_PRIORITY} for the 1 kHz loop",
            fifo_allowed(),
            "an rtprio 99 limit or CAP_SYS_NICE",
        ),
    ]
    if fc.lock_memory:
        needs.append(
            ("memory locking (franka.lock_memory)", memlock_allowed(), "memlock unlimited or CAP_IPC_LOCK")
        )
    ok, lines = True, []
    for what, met, how in needs:
        if met:
            lines.append(f"host {what}: yes")
        elif enforce:
            ok = False
            lines.append(f"MISSING host {what}: franka.realtime: enforce will not run without it ({how})")
        else:
            lines.append(
                f"host {what}: no ({how}); franka.realtime: ignore runs without it, cycles may be lost"
            )
    return ok, lines
