"""robot.franka.lock_memory: mlockall for real, in subprocesses (a locked pytest process would pin all
its memory), and the backend's policy when the OS refuses: fatal under realtime: enforce, a warning
under ignore. The refusal is made real with util-linux: ``prlimit --memlock=0`` and ``setpriv`` dropping
CAP_IPC_LOCK."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LOCK = "from robot_io.backends.memory_lock import lock_memory; lock_memory()\n"
STATUS = "print([l.split()[1] for l in open('/proc/self/status') if l.startswith('VmLck')][0])\n"
BACKEND = """
import logging, sys
logging.basicConfig(level=logging.WARNING, stream=sys.stdout)
from robot_io.backends.franky_backend import FrankyBackend
from robot_io.backends.franky_config import FrankaConfig
from robot_io.config import RobotConfig
fc = FrankaConfig(ip="127.0.0.1", realtime=sys.argv[1], lock_memory=True)
FrankyBackend(RobotConfig(backend="franka", model="fr3", franka=fc))
"""


def _refusing() -> list[str]:
    """A command prefix under which mlockall is refused: no memlock allowance, and (root) no CAP_IPC_LOCK."""
    drop = ["setpriv", "--inh-caps=-ipc_lock", "--bounding-set=-ipc_lock"] if os.geteuid() == 0 else []
    return ["prlimit", "--memlock=0", *drop]


def _python(code: str, *args: str, refused: bool = False) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-c", code, *args]
    if refused:
        cmd = [*_refusing(), *cmd]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=env, cwd=ROOT)


@pytest.fixture
def can_refuse():
    if not shutil.which("prlimit") or (os.geteuid() == 0 and not shutil.which("setpriv")):
        pytest.skip("util-linux's prlimit (and setpriv, as root) are needed to make the OS refuse")
    probe = subprocess.run([*_refusing(), "true"], capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip(f"this machine will not run a process without the memlock allowance: {probe.stderr}")


def test_locking_pins_the_process_memory():
    out = _python(LOCK + STATUS)
    if out.returncode != 0 and "MemoryLockError" in out.stderr and os.geteuid() != 0:
        pytest.skip(f"this user may not lock memory: {out.stderr.strip().splitlines()[-1]}")
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.strip()) > 1000  # kB locked: the interpreter's pages at least


def test_a_refusal_names_the_key_and_the_fix(can_refuse):
    out = _python(LOCK, refused=True)
    assert out.returncode != 0
    assert (
        "MemoryLockError: robot.franka.lock_memory: the memlock limit is 0 KiB, not unlimited" in out.stderr
    )
    assert "lacks CAP_IPC_LOCK" in out.stderr and "ulimit -l unlimited" in out.stderr


def test_the_backend_refuses_to_run_unlocked_under_realtime_enforce(can_refuse):
    pytest.importorskip("franky")
    out = _python(BACKEND, "enforce", refused=True)
    assert out.returncode != 0
    assert "MemoryLockError" in out.stderr and "franky connected" not in out.stdout + out.stderr


def test_the_backend_warns_and_goes_on_under_realtime_ignore(can_refuse):
    pytest.importorskip("franky")
    out = _python(BACKEND, "ignore", refused=True)
    assert "memory not locked (realtime: ignore, going on): robot.franka.lock_memory:" in out.stdout
    # It went on to connect: nothing serves 127.0.0.1's FCI, so it is the connection that fails.
    assert out.returncode != 0 and "MemoryLockError" not in out.stderr and "NetworkException" in out.stderr
