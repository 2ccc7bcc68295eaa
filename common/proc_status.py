"""What /proc says of a process (Linux): a field of this one's status (peak and locked memory,
capabilities), and any one's CPU time."""

from __future__ import annotations

import os
from pathlib import Path


def status_field(name: str) -> str | None:
    """The first value of ``name:`` in ``/proc/self/status`` (``"VmHWM"`` → ``"123456"``, in KiB for the
    Vm fields); None where there is no such file or field."""
    try:
        text = Path("/proc/self/status").read_text()
    except OSError:
        return None
    return next((line.split()[1] for line in text.splitlines() if line.startswith(name + ":")), None)


def cpu_seconds(pid: int) -> float | None:
    """CPU time (user + system, s) process ``pid`` used so far; None once it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()  # after ``(comm)``
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime
