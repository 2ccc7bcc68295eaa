"""The operator token (issue #31): never in a log, and never needed to stop the arm.

Under ``adaptiveh up`` the parts' logs are 0600 and none holds the token; the monitor prints its URL
without one. A ``POST /api/control`` that asks for an e-stop is published as one (signed with the
stack's key, jog zero) without the token and however malformed; every other command still needs the
token and a valid body. A standalone ``adaptiveh monitor`` prints its made-up token only to a terminal;
otherwise it leaves it in a 0600 file, removed when the monitor ends."""

from __future__ import annotations

import http.client
import json
import os
import pty
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any
from urllib.parse import urlsplit

import pytest
from bus_probe import BusProbe
from loopback import unique_name
from stack_helpers import parts_of, start_up, write_stack_config

from bus import messages as m
from bus.signing import mac_key
from bus.transport import Bus, ZenohConfig, open_session
from deploy.commands import write_private
from deploy.commands.up import tell_token
from deploy.config import load_stack_config
from deploy.part_env import TOKEN_ENV
from monitor.server import MonitorConfig, MonitorServer

TOKEN = "operator-secret-0123"
ZERO = [0.0, 0.0, 0.0]
ESTOP_BODIES = {  # each asks for an e-stop without the token; the stack's monitor gets these three
    "plain": (b'{"command": "estop"}', {}),
    "garbage jog": (b'{"command": "ESTOP", "jog": ["x", null, 1e999]}', {"X-Token": "wrong"}),
    "not JSON": (b'{"command": "estop", jog: [', {}),
}
ODD_ESTOPS = {  # and these the endpoint alone (tests/monitor/test_monitor_control.py: the usual ones)
    "bare word": (b"estop", {"Content-Type": "text/plain"}),
    "not UTF-8": (b"\xff\xfe estop \xc0", {}),
    "nested deep": (b"[" * 10_000 + b'"estop"', {}),
    "no command field": (b'{"cmd": "estop"}', {}),
    "not an object": (b'["estop"]', {}),
}


def post(url: str, body: bytes, headers: dict[str, str] | None = None) -> tuple[int, dict[str, Any]]:
    """What the page's buttons do, with any body: (HTTP status, JSON reply)."""
    parts = urlsplit(url)
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=15)
    try:
        conn.request("POST", "/api/control", body, {"Content-Type": "application/json", **(headers or {})})
        reply = conn.getresponse()
        return reply.status, json.loads(reply.read())
    finally:
        conn.close()


def estops(controls: list) -> list:
    return [c for c in controls if c.command == m.Control.ESTOP]


@pytest.fixture
def monitor(endpoint: str) -> Iterator[tuple[MonitorServer, BusProbe, list]]:
    """A monitor with the stack's token on its own loopback bus, and the controls it publishes (only
    those signed with the stack's key arrive)."""
    bus = Bus(open_session(ZenohConfig(listen=(endpoint,))), unique_name("tok"), mac_key(TOKEN))
    server = MonitorServer(bus, MonitorConfig(port=0, foxglove_port=None), TOKEN).start()
    probe = BusProbe(bus)
    controls = probe.collect(m.CONTROL, arrival=False)
    try:
        yield server, probe, controls
    finally:
        server.stop()


@pytest.mark.parametrize("case", ODD_ESTOPS)
def test_an_estop_needs_no_token_and_no_valid_body(monitor, case):
    server, probe, controls = monitor
    body, headers = ODD_ESTOPS[case]
    code, reply = post(server.url, body, headers)
    assert (code, reply["command"]) == (200, "estop"), reply
    probe.wait(lambda: estops(controls), 5, "the e-stop on the bus")
    time.sleep(0.2)
    assert [list(c.jog) for c in controls] == [ZERO]  # one e-stop, nothing else, jog zero


def test_an_estop_whose_body_lies_about_its_length_still_stops(monitor):
    """Content-Length promises more than comes: what came before the handler's time-out is read."""
    server, probe, controls = monitor
    parts = urlsplit(server.url)
    with socket.create_connection((parts.hostname, parts.port), timeout=15) as sock:
        body = b'{"command": "estop"'
        sock.sendall(b"POST /api/control HTTP/1.0\r\nContent-Length: 999\r\n\r\n" + body)
        assert b" 200 " in sock.recv(4096).split(b"\r\n")[0]
    probe.wait(lambda: estops(controls), 5, "the e-stop on the bus")


def test_every_other_command_needs_the_token_and_a_valid_body(monitor):
    server, probe, controls = monitor
    refused = [
        (403, b'{"command": "release"}', {}),
        (403, b'{"command": "release"}', {"X-Token": "wrong"}),
        (403, b'{"command": "release", "note": "not an estop"}', {}),  # a readable command is taken as is
        (403, b'{"command": "release"}', {"X-Token": "t\u00f6ken".encode().decode("latin-1")}),
        (400, b'{"command": "release", "jog": "garbage"}', {"X-Token": TOKEN}),
        (400, b'{"command": "jog", "jog": [1, 2]}', {"X-Token": TOKEN}),
        (400, b'{"command": "dance"}', {"X-Token": TOKEN}),
        (400, b'{"command": "release"', {"X-Token": TOKEN}),
        (400, b"release", {"X-Token": TOKEN}),
    ]
    for code, body, headers in refused:
        assert post(server.url, body, headers)[0] == code, body
    assert post(server.url, b'{"command": "release", "token": "' + TOKEN.encode() + b'"}')[0] == 200
    probe.wait(lambda: controls, 5, "the release on the bus")
    time.sleep(0.2)
    assert [c.command for c in controls] == [m.Control.RELEASE]  # none of the refused ones went out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_up_keeps_the_token_out_of_its_logs_and_obeys_an_estop_without_it(tmp_path):
    path, _ = write_stack_config(tmp_path, "tok", steps=100000)
    cfg = load_stack_config(path)
    up, token = start_up(path)
    logs = tmp_path / "logs"
    probe = None
    try:
        assert len(token) >= 12
        monitor_log = (logs / "monitor.log").read_text()
        url = next(x for x in monitor_log.splitlines() if x.startswith("monitor: ")).split(" ")[1]
        assert "token" not in monitor_log and url.endswith("/"), monitor_log
        probe = BusProbe(Bus(open_session(cfg.zenoh), cfg.name, mac_key(token)))  # signed ones only
        controls, states = probe.collect(m.CONTROL, arrival=False), probe.collect(m.STATE, arrival=False)
        probe.wait(lambda: states, 30, "robot-io's state")
        for case, (body, headers) in ESTOP_BODIES.items():
            assert post(url, body, headers)[0] == 200, case
        probe.wait(lambda: len(estops(controls)) == 3, 10, "three signed e-stops from the monitor")
        assert all(list(c.jog) == ZERO for c in controls)
        probe.wait(lambda: m.label(states[-1], "mode") == "estop", 10, "the arm e-stopped")
        assert post(url, b'{"command": "release"}')[0] == 403
        assert post(url, b'{"command": "release"}', {"X-Token": token})[0] == 200
        probe.wait(lambda: m.label(states[-1], "mode") == "running", 10, "the arm released")
        up.send_signal(signal.SIGTERM)
        out = up.communicate(timeout=90)[0]
    finally:
        if probe is not None:
            probe.bus.close()
        for pid in parts_of(path).values():
            os.kill(pid, signal.SIGKILL)
        if up.poll() is None:
            up.kill()
    assert token not in out and "token=" not in out  # after its first line, which up's test reads
    assert logs.stat().st_mode & 0o777 == 0o700
    files = list(logs.iterdir())
    assert {f.name for f in files} >= {"robot_io.log", "vision.log", "monitor.log", "learner.log"}
    for f in files:
        assert f.stat().st_mode & 0o777 == 0o600, f
        assert token not in f.read_text(errors="replace"), f


def _start_monitor(tmp_path: Path, stdout: int | IO[str]) -> subprocess.Popen:
    """``adaptiveh monitor`` with no token of its own (it makes one up), its token files under tmp_path."""
    path, _ = write_stack_config(tmp_path, "tokmon")
    env = {k: v for k, v in os.environ.items() if k != TOKEN_ENV} | {"XDG_RUNTIME_DIR": str(tmp_path / "run")}
    cmd = [sys.executable, "-m", "deploy.cli", "monitor", "--config", str(path), "--log-level", "WARNING"]
    return subprocess.Popen(cmd, stdout=stdout, stderr=subprocess.STDOUT, text=True, env=env)


def _stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise


def test_a_standalone_monitor_not_on_a_terminal_writes_its_token_to_a_private_file(tmp_path):
    mon = _start_monitor(tmp_path, subprocess.PIPE)
    try:
        lines = []
        while not (lines and lines[-1].startswith("monitor token file: ")):
            line = mon.stdout.readline()
            assert line, f"the monitor ended: {lines}"
            lines.append(line.rstrip("\n"))
        url = next(x for x in lines if x.startswith("monitor: ")).split(" ")[1]
        token_file = Path(lines[-1].split(" ")[3])
        assert token_file.parent.parent == tmp_path / "run"
        assert token_file.stat().st_mode & 0o777 == 0o600
        assert token_file.parent.stat().st_mode & 0o777 == 0o700
        token = token_file.read_text().strip()
        assert len(token) >= 12 and not any(token in x for x in lines) and "token=" not in url
        assert post(url, b'{"command": "pause"}', {"X-Token": "wrong"})[0] == 403
        assert post(url, b'{"command": "pause"}', {"X-Token": token})[0] == 200  # the file's is the one
    finally:
        _stop(mon)
    assert not token_file.exists()  # the token died with the monitor
    assert token not in mon.stdout.read()


def test_a_standalone_monitor_on_a_terminal_prints_its_token_there(tmp_path):
    master, slave = pty.openpty()
    mon = _start_monitor(tmp_path, slave)
    os.close(slave)
    try:
        out, deadline = b"", time.monotonic() + 30
        while b"monitor token: " not in out or not out.endswith(b"\n"):
            assert time.monotonic() < deadline and mon.poll() is None, out
            if select.select([master], [], [], 0.5)[0]:
                out += os.read(master, 4096)
        assert b"token=" not in out
        assert not (tmp_path / "run").exists()  # no file written: the terminal is not a log
    finally:
        _stop(mon)
        os.close(master)


def test_up_never_repeats_a_token_the_operator_gave(capsys):
    tell_token(TOKEN, "/etc/adaptiveh/token")
    assert TOKEN not in capsys.readouterr().out
    tell_token(TOKEN, "")  # a made-up one: printed, the first line of up's output
    assert capsys.readouterr().out == f"operator token: {TOKEN}\n"


def test_a_private_file_is_0600_from_the_start_and_replaces_what_was_there(tmp_path):
    loose, elsewhere = tmp_path / "d" / "token", tmp_path / "elsewhere"
    loose.parent.mkdir()
    loose.write_text("old")
    loose.chmod(0o644)
    write_private(loose, "secret")
    assert loose.stat().st_mode & 0o777 == 0o600 and loose.read_text() == "secret"
    loose.unlink()
    loose.symlink_to(elsewhere)  # a link planted at the path is replaced, never followed
    write_private(loose, "secret")
    assert not loose.is_symlink() and not elsewhere.exists()


def test_the_monitor_command_gives_its_page_and_live_view_the_stacks_key_and_limits(tmp_path, monkeypatch):
    """The page and the Foxglove live view of ``adaptiveh monitor`` believe only what the stack signed and
    plot only in-range values (a rewrite of the command once dropped both for the live view)."""
    import argparse

    import monitor.foxglove.live as live
    from bus.node import Node
    from bus.signing import mac_key
    from deploy.commands import monitor as command

    path, _ = write_stack_config(tmp_path, "mk")
    seen: dict[str, Any] = {}

    def fake_live(session, robot, setup, host, port, exclude=(), key=None, limits=None):
        seen.update(key=key, live_limits=limits)
        return None

    def stop_at_once(node: Node, duration: float = 0.0) -> None:
        seen["page_limits"] = node.state.limits
        node.stop()

    monkeypatch.setattr(live, "start_live", fake_live)
    monkeypatch.setattr("bus.node.run_until_stopped", stop_at_once)
    monkeypatch.setenv(TOKEN_ENV, "operator")
    args = argparse.Namespace(
        config=str(path), port=0, foxglove_port=0, token_file="", log_level="WARNING", duration=0.0
    )
    assert command.run(args) == 0
    assert seen["key"] == mac_key("operator")
    assert seen["live_limits"].longest_segment == 50 and seen["page_limits"].longest_segment == 50
