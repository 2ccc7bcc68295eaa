"""One field of ``/proc/self/status`` (Linux): peak and locked memory, capabilities."""

from __future__ import annotations

from pathlib import Path


def status_field(name: str) -> str | None:
    """The first value of ``name:`` in ``/proc/self/status`` (``"VmHWM"`` → ``"123456"``, in KiB for the
    Vm fields); None where there is no such file or field."""
    try:
        text = Path("/proc/self/status").read_text()
    except OSError:
        return None
    return next((line.split()[1] for line in text.splitlines() if line.startswith(name + ":")), None)
