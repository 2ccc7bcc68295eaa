"""``adaptiveh up`` restarts a crashed part and keeps the token off command lines. (A killed ``adaptiveh up``
takes its parts with it, no orphaned robot-io driving the arm: test_fault_matrix.py, test_09.)"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from polling import wait_until
from stack_helpers import PARTS, parts_of, write_stack_config

from common.heap import ALLOCATOR_ENV


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_crashed_part_is_restarted_and_the_token_is_never_on_a_command_line(tmp_path):
    """SIGKILL of the vision process (cameras fail most on real rigs) no longer ends the run: the
    supervisor restarts it after its back-off and the learner goes on. The operator token reaches the
    parts through their environment: no part's argv (world-readable through ``ps``) holds it."""
    path, _ = write_stack_config(tmp_path, "rs", steps=100000)
    out = tmp_path / "summary.json"
    up = subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "up", str(path), "--summary", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        token = up.stdout.readline().strip().removeprefix("operator token: ")
        assert len(token) >= 12
        deadline = time.monotonic() + 60
        while set(parts_of(path)) != set(PARTS):
            assert time.monotonic() < deadline and up.poll() is None, f"parts up: {sorted(parts_of(path))}"
            time.sleep(0.5)
        parts = parts_of(path)
        for pid in parts.values():
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
            assert token not in argv
            environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
            assert f"ADAPTIVEH_TOKEN={token}".encode() in environ
            for name, value in ALLOCATOR_ENV.items():  # bounded allocator caches, unless the user set them
                assert f"{name}={os.environ.get(name, value)}".encode() in environ
        os.kill(parts["vision"], signal.SIGKILL)
        deadline = time.monotonic() + 30
        while parts_of(path).get("vision") in (None, parts["vision"]):
            assert time.monotonic() < deadline, "vision was not restarted"
            assert up.poll() is None, "adaptiveh up ended when vision died"
            time.sleep(0.2)
        assert parts_of(path).get("learn") == parts["learn"]  # the learner went on, untouched
        up.send_signal(signal.SIGTERM)
        assert up.wait(timeout=60) in (0, 1)
    finally:
        for pid in parts_of(path).values():
            os.kill(pid, signal.SIGKILL)
        if up.poll() is None:
            up.kill()
    summary = json.loads(out.read_text())
    assert summary["restarts"] == {"vision": 1}


def test_a_token_file_others_can_read_is_refused(tmp_path):
    from deploy.cli import main

    token = tmp_path / "token"
    token.write_text("secret\n")
    token.chmod(0o644)
    with pytest.raises(SystemExit, match="readable by others"):
        main(["monitor", "--config", "configs/sim.yaml", "--token-file", str(token), "--duration", "0.1"])


def test_the_run_ends_when_a_part_has_used_its_restarts(tmp_path):
    """A part that cannot run (the monitor's port is taken) is restarted ``max_restarts`` times, then the
    run ends: every part stopped, the summary says who used its restarts."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        path, cfg = write_stack_config(tmp_path, "ex", steps=100000)
        cfg["monitor"]["port"] = taken.getsockname()[1]
        cfg["supervisor"] = {"max_restarts": 2, "backoff_s": 0.2}
        path.write_text(yaml.safe_dump(cfg))
        out = tmp_path / "summary.json"
        up = subprocess.run(
            [sys.executable, "-m", "deploy.cli", "up", str(path), "--summary", str(out)],
            capture_output=True,
            text=True,
            timeout=180,
        )
    assert up.returncode != 0
    summary = json.loads(out.read_text())
    assert summary["restarts"] == {"monitor": 2} and summary["gave_up"] == "monitor"
    assert "used its 2 restarts" in (tmp_path / "logs" / "monitor.log").read_text() + up.stderr + up.stdout
    assert not parts_of(path)


def test_a_parts_fork_is_not_the_part(tmp_path):
    """A child between fork and exec carries its parent's command line (a part that runs ldconfig, say):
    ``running_parts`` names the part, not its fork (the e-stop test once read a fork as a restart)."""
    config = tmp_path / "sim.yaml"
    code = "import os, time\nif os.fork() == 0:\n    time.sleep(30)\n    os._exit(0)\ntime.sleep(30)"
    part = subprocess.Popen([sys.executable, "-c", code, "deploy.cli", "vision", "--config", str(config)])
    children_file, children = Path(f"/proc/{part.pid}/task/{part.pid}/children"), []
    try:
        children = wait_until(lambda: children_file.read_text().split(), 10, "the part to fork", every=0.05)
        assert parts_of(config) == {"vision": part.pid}
    finally:
        for pid in children:
            os.kill(int(pid), signal.SIGKILL)
        part.kill()
        part.wait()
