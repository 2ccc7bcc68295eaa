"""A part told to stop exits within its deadline, even when its way out hangs (``bus.node``).

Each case runs a real ``Node`` on a loopback Zenoh session in a process of its own, as ``adaptiveh
<part>`` does, and stops it with SIGTERM: the exit is process-wide, so it cannot run inside pytest.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

import pytest
from loopback import unique_name

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="signals")

PART = """
import sys, threading, time
from bus.node import Node, run_until_stopped
from bus.transport import ZenohConfig

class Part(Node):
    alive_as = "robot-io"

    def __init__(self):
        super().__init__({name!r}, ZenohConfig(listen=({endpoint!r},)))
        self.declare_alive()

    def workers(self):
        return {{"tick": self.tick}}

    def tick(self):
        print("up", flush=True)
        while not self.stopping:
            time.sleep(0.01)

    def close(self):
        super().close()
        if {hang}:
            hang_in_close_forever()

def hang_in_close_forever():
    threading.Event().wait()

run_until_stopped(Part(), deadline_s={deadline})
print("stopped", flush=True)
"""


def _run_part(endpoint: str, hang: bool, deadline: float) -> subprocess.Popen:
    code = PART.format(name=unique_name("node"), endpoint=endpoint, hang=hang, deadline=deadline)
    return subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(code)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _terminate(part: subprocess.Popen, wait_s: float) -> tuple[float, str, str]:
    """SIGTERM once the part ticks; (seconds to its exit, stdout after "up", stderr)."""
    try:
        assert part.stdout.readline().strip() == "up", part.stderr.read()
        t0 = time.monotonic()
        part.send_signal(signal.SIGTERM)
        out, err = part.communicate(timeout=wait_s)
        return time.monotonic() - t0, out, err
    finally:
        part.kill()
        part.wait()


def test_a_part_whose_close_hangs_dumps_its_threads_and_exits_at_the_deadline(endpoint: str) -> None:
    part = _run_part(endpoint, hang=True, deadline=2.0)
    elapsed, out, err = _terminate(part, wait_s=15)
    assert part.returncode == 1, err
    assert 1.5 < elapsed < 8.0, f"exited {elapsed:.1f} s after SIGTERM (deadline 2 s)"
    assert "stopped" not in out
    assert "Timeout" in err and "hang_in_close_forever" in err, f"no thread dump naming the hang:\n{err}"


def test_a_part_that_stops_cleanly_exits_at_once_with_status_0(endpoint: str) -> None:
    part = _run_part(endpoint, hang=False, deadline=2.0)
    elapsed, out, err = _terminate(part, wait_s=15)
    assert part.returncode == 0, err
    assert "stopped" in out and "Timeout" not in err
    assert elapsed < 2.0, f"a clean stop took {elapsed:.1f} s"
