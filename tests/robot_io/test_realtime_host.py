"""What ``adaptiveh up --check`` says about the host's real-time readiness, on this machine's real
kernel flag, limits and capabilities; the refusals made real in subprocesses with util-linux
(``prlimit`` lowers a limit, ``setpriv`` drops a capability)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from robot_io.backends.franky_config import FrankaConfig
from robot_io.backends.realtime_host import host_report, realtime_kernel

ROOT = Path(__file__).resolve().parents[2]
REPORT = """
import sys
from robot_io.backends.realtime_host import host_report
from robot_io.backends.franky_config import FrankaConfig
ok, lines = host_report(FrankaConfig(realtime=sys.argv[1], lock_memory=True))
print(ok); print("\\n".join(lines))
"""


def _report_without(realtime: str, limit: str, capability: str) -> tuple[bool, str]:
    """host_report in a process with ``limit`` at 0 and (as root) without ``capability``."""
    if not shutil.which("prlimit") or (os.geteuid() == 0 and not shutil.which("setpriv")):
        pytest.skip("util-linux's prlimit (and setpriv, as root) are needed")
    drop = (
        ["setpriv", f"--inh-caps=-{capability}", f"--bounding-set=-{capability}"] if os.geteuid() == 0 else []
    )
    prefix = ["prlimit", f"--{limit}=0", *drop]
    probe = subprocess.run([*prefix, "true"], capture_output=True, text=True, timeout=60)
    if probe.returncode != 0:
        pytest.skip(f"this machine will not run a process with {limit} 0: {probe.stderr}")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [*prefix, sys.executable, "-c", REPORT, realtime]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=env)
    assert out.returncode == 0, out.stderr  # host_report itself must not fail
    first, _, rest = out.stdout.partition("\n")
    return first == "True", rest


def test_the_kernel_flag_is_read_as_libfranka_reads_it(tmp_path):
    flag = tmp_path / "realtime"
    assert not realtime_kernel(flag)  # absent: a kernel without PREEMPT_RT
    flag.write_text("1\n")
    assert realtime_kernel(flag)
    flag.write_text("0\n")
    assert not realtime_kernel(flag)


def test_without_a_realtime_kernel_enforce_is_refused_and_ignore_is_a_note():
    if realtime_kernel():
        pytest.skip("this machine runs a real-time kernel")
    ok, lines = host_report(FrankaConfig(realtime="enforce"))
    assert not ok and any(line.startswith("MISSING host real-time kernel") for line in lines)
    ok, lines = host_report(FrankaConfig(realtime="ignore"))
    assert ok and "host real-time kernel: no" in "\n".join(lines)


def test_without_the_memlock_allowance_locking_is_named():
    ok, text = _report_without("ignore", "memlock", "ipc_lock")
    assert ok and "host memory locking (franka.lock_memory): no" in text
    ok, text = _report_without("enforce", "memlock", "ipc_lock")
    assert not ok and "MISSING host memory locking (franka.lock_memory)" in text


def test_without_rtprio_the_fifo_priority_is_named():
    ok, text = _report_without("enforce", "rtprio", "sys_nice")
    assert not ok and "MISSING host SCHED_FIFO 99 for the 1 kHz loop" in text
