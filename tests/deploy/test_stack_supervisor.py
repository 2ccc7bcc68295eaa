"""A killed ``adaptiveh up`` takes its parts with it: no orphaned robot-io driving the arm."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from stack_helpers import write_stack_config

PARTS = ("robot-io", "vision", "learn", "monitor")


def _parts_of(config: Path) -> dict[str, int]:
    """pid of every running ``deploy.cli <part> --config <config>`` process."""
    found = {}
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            args = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        words = [a.decode(errors="replace") for a in args]
        if str(config) in words and "deploy.cli" in words:
            part = words[words.index("deploy.cli") + 1]
            if part in PARTS:
                found[part] = int(pid)
    return found


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="parent-death signal is Linux only")
def test_parts_stop_when_the_supervisor_is_killed(tmp_path):
    path, _ = write_stack_config(tmp_path, "sup", steps=100000)
    up = subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "up", str(path)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        while set(_parts_of(path)) != set(PARTS):
            assert time.monotonic() < deadline, f"parts up: {sorted(_parts_of(path))}"
            assert up.poll() is None, "adaptiveh up exited early"
            time.sleep(0.5)
        time.sleep(8.0)  # every part has started up and the learner is driving the arm
        up.send_signal(signal.SIGKILL)  # no cleanup of its own
        up.wait(timeout=10)
        deadline = time.monotonic() + 20
        while _parts_of(path):
            if time.monotonic() > deadline:
                for pid in _parts_of(path).values():
                    os.kill(pid, signal.SIGUSR1)  # their stacks go to logs/<part>.log
                time.sleep(1.0)
                logs = {p.name: p.read_text()[-3000:] for p in (tmp_path / "logs").glob("*.log")}
                pytest.fail(f"orphaned parts: {_parts_of(path)}\n{logs}")
            time.sleep(0.2)
    finally:
        for pid in _parts_of(path).values():
            os.kill(pid, signal.SIGKILL)
        if up.poll() is None:
            up.kill()
