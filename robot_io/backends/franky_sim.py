"""A franky-sim server (MuJoCo FR3 speaking libfranka's network protocol) as a child process.

Tests and bench/franka_bench.py run the simulator in its own process, as the real arm is its own
machine: it can be killed and restarted (a lost connection), and its Python 1 kHz loop does not share
a GIL with robot-io. ``franky-sim -s mujoco --hostname <loopback address>`` is the package's own CLI
(``-s mujoco`` because its ``auto`` choice fails when the optional genesis simulator is absent); each
server binds its own 127.x.y.z address, so several can run at once.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import threading
from pathlib import Path


def franky_sim_command(hostname: str) -> list[str]:
    exe = shutil.which("franky-sim") or str(Path(sys.executable).parent / "franky-sim")
    return [exe, "-s", "mujoco", "--hostname", hostname]


class FrankySimServer:
    """``start()`` waits until the server accepts connections; ``kill()`` ends it without a goodbye."""

    def __init__(self, hostname: str = "127.0.0.1", startup_timeout_s: float = 60.0) -> None:
        self.hostname = hostname
        self.startup_timeout_s = startup_timeout_s
        self.proc: subprocess.Popen[str] | None = None
        self.output: list[str] = []

    def start(self) -> FrankySimServer:
        self.proc = subprocess.Popen(
            franky_sim_command(self.hostname), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        ready = threading.Event()

        def read(proc: subprocess.Popen[str]) -> None:
            for line in proc.stdout:  # keep draining, so the server never blocks on a full pipe
                self.output.append(line.rstrip())
                if "Connect to the server" in line:
                    ready.set()

        threading.Thread(target=read, args=(self.proc,), daemon=True).start()
        if not ready.wait(self.startup_timeout_s):
            self.kill()
            raise RuntimeError("franky-sim did not start:\n" + "\n".join(self.output[-30:]))
        return self

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self.proc = None

    def __enter__(self) -> FrankySimServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.kill()
