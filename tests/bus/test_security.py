"""Security for several machines, on loopback with real Zenoh sessions and the shipped config
(configs/multi_machine_tls.yaml: mutual TLS, user/password, the router's access control by identity).

A router in this process; certificates from scripts/make_test_certs.sh (one CA, one per identity) and a
second, foreign CA. Who cannot connect: a certificate of another CA, none at all, plain TCP, a wrong
password. Who cannot command: a valid identity other than the learner (its puts on ``cmd/**`` are
dropped at the router), other than the monitor on ``control``. The real robot-io and learner run a
learning episode through it, and robot-io refuses a control without the operator token.
"""

from __future__ import annotations

import logging
import os
import subprocess
import time
from pathlib import Path

import pytest
import yaml
import zenoh
from bus_probe import BusProbe
from loopback import free_port, unique_name
from polling import wait_until
from stack_helpers import learn_one_episode, running_part

from bus import messages as m
from bus.security import IDENTITY_ENV
from bus.transport import Bus, ZenohConfig, open_session
from common.config import ConfigError
from deploy.config import compose_stack_yaml
from deploy.part_env import TOKEN_ENV
from deploy.stack import check
from monitor.server import MonitorConfig, MonitorServer

ROOT = Path(__file__).parents[2]
SHIPPED = ROOT / "configs" / "multi_machine_tls.yaml"
SIM = ROOT / "configs" / "sim.yaml"
TOKEN = "operator-secret-1234"


def _make_certs(out: Path, *ids: str) -> Path:
    env = {**os.environ, **({"IDENTITIES": " ".join(ids)} if ids else {})}
    subprocess.run(
        [str(ROOT / "scripts" / "make_test_certs.sh"), str(out)], check=True, capture_output=True, env=env
    )
    return out


def _shipped(certs: Path, endpoint: str) -> dict:
    """The shipped config with its certificates under ``certs`` and its router on ``endpoint``."""
    copy = certs.parent / "multi_machine_tls.yaml"  # its base, sim.yaml, by absolute path from here
    copy.write_text(
        SHIPPED.read_text().replace("certs/test", str(certs)).replace("base: sim.yaml", f"base: {SIM}")
    )
    cfg = compose_stack_yaml(copy)
    cfg["zenoh"]["connect"] = [endpoint]
    cfg["zenoh"]["router"]["listen"] = [endpoint]
    return cfg


def _zenoh(base: dict, **tls_auth: dict) -> ZenohConfig:
    """``base``'s zenoh section with ``tls``/``auth`` keys replaced."""
    z = {**base, **{k: {**base[k], **v} for k, v in tls_auth.items()}}
    return ZenohConfig.model_validate(z)


@pytest.fixture(scope="module")
def bus(tmp_path_factory):
    """(the shipped config, made private; a router with it; a factory of sessions by identity)."""
    tmp = tmp_path_factory.mktemp("sec")
    certs = _make_certs(tmp / "certs")
    endpoint = f"tls/127.0.0.1:{free_port()}"
    cfg = _shipped(certs, endpoint)
    cfg["name"] = unique_name("sec")
    router_cfg = _zenoh(cfg["zenoh"]).model_copy(
        update={"mode": "router", "listen": (endpoint,), "connect": ()}
    )
    router = open_session(router_cfg, identity="router")
    sessions: list[Bus] = []

    def join(identity: str, **tls_auth: dict) -> Bus:
        sessions.append(Bus(open_session(_zenoh(cfg["zenoh"], **tls_auth), identity=identity), cfg["name"]))
        return sessions[-1]

    yield cfg, tmp, join
    for b in sessions:
        b.close()
    router.close()


def _heard(listener: Bus, *keys: str) -> dict[str, list[bytes]]:
    got: dict[str, list[bytes]] = {k: [] for k in keys}
    for k in keys:
        listener.declare(
            lambda session, k=k: session.declare_subscriber(
                listener.key(k), lambda s, k=k: got[k].append(s.payload.to_bytes())
            )
        )
    return got


def test_the_learner_commands_and_every_identity_reads(bus):
    """(a) The learner's chunk reaches robot-io and a read-only identity; robot-io's chunk report and the
    reset service (query, reply) flow back: the access control lets the genuine traffic through."""
    _, _, join = bus
    learner, robot, vision = join("learner"), join("robot-io"), join("vision")
    at_robot, at_vision = _heard(robot, "cmd/chunk"), _heard(vision, "cmd/chunk")
    at_learner = _heard(learner, "cmd/status")
    robot.declare(
        lambda s: s.declare_queryable(robot.key(m.RESET), lambda q: q.reply(q.key_expr, b"reset done"))
    )
    time.sleep(0.5)  # the subscriptions reach the publishers through the router
    learner.session.put(learner.key("cmd/chunk"), b"chunk 1")
    robot.session.put(robot.key("cmd/status"), b"chunk 1 executed")
    wait_until(
        lambda: at_robot["cmd/chunk"] and at_vision["cmd/chunk"] and at_learner["cmd/status"],
        what="the learner's chunk at robot-io and vision, and robot-io's status at the learner",
    )
    assert at_robot["cmd/chunk"] == at_vision["cmd/chunk"] == [b"chunk 1"]
    replies = list(learner.session.get(learner.key(m.RESET), payload=b"seed 3", timeout=5))
    assert [r.ok.payload.to_bytes() for r in replies] == [b"reset done"]


@pytest.mark.parametrize(
    "who",
    ["certificate of another CA", "another CA altogether", "no client certificate", "plain tcp"],
)
def test_a_session_without_a_certificate_of_our_ca_cannot_connect(bus, who):
    """(b) The router refuses the connection: such a session cannot put anything, commands included."""
    cfg, tmp, _ = bus
    rogue = tmp / "rogue"
    if not rogue.exists():
        _make_certs(rogue, "learner")  # CN learner, but signed by a CA the router does not trust
    base = cfg["zenoh"]
    if (
        who == "certificate of another CA"
    ):  # trusts our CA (so it accepts the router), presents a foreign cert
        zc = _zenoh(base, tls={"cert": str(rogue / "learner.pem"), "key": str(rogue / "learner.key")})
    elif who == "another CA altogether":
        zc = _zenoh(
            base,
            tls={
                "ca": str(rogue / "ca.pem"),
                "cert": str(rogue / "learner.pem"),
                "key": str(rogue / "learner.key"),
            },
        )
    elif who == "no client certificate":
        none = {f"transport/link/tls/connect_{k}": None for k in ("certificate", "private_key")}
        zc = _zenoh(base).model_copy(update={"options": none})
    else:
        zc = ZenohConfig(mode="client", connect=(base["connect"][0].replace("tls/", "tcp/"),))
    t0 = time.monotonic()
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        open_session(zc, identity="learner")
    assert time.monotonic() - t0 < 10


def test_only_the_learner_puts_commands_and_only_the_monitor_controls(bus):
    """(c) Valid certificates and passwords, wrong identities: what they put on ``cmd/**`` or ``control``
    (or a liveliness token in the learner's name) is dropped at the router; the owners' puts arrive."""
    _, _, join = bus
    listener = join("supervisor")
    got = _heard(listener, "cmd/chunk", "cmd/status", "control")
    alive: list[str] = []
    prefix = listener.key(m.LIVELINESS) + "/"
    listener.declare(
        lambda session: session.liveliness().declare_subscriber(
            prefix + "**", lambda s: alive.append(str(s.key_expr).removeprefix(prefix))
        )
    )
    ids = {who: join(who) for who in ("learner", "robot-io", "vision", "monitor", "supervisor")}
    time.sleep(0.5)
    for who, b in ids.items():
        for key in ("cmd/chunk", "cmd/status", "control"):
            b.session.put(b.key(key), who.encode())
    ids["vision"].declare_alive("learner/impostor")  # a stranger claiming to be a learner session
    ids["vision"].declare_alive("vision")
    ids["learner"].declare_alive("learner")
    wait_until(
        lambda: got["cmd/chunk"] and got["cmd/status"] and got["control"] and len(alive) >= 2,
        what="a chunk, a status, a control and two tokens",
    )
    time.sleep(0.5)  # anything else would have arrived by now
    assert got == {"cmd/chunk": [b"learner"], "cmd/status": [b"robot-io"], "control": [b"monitor"]}
    assert sorted(alive) == ["learner", "vision"]  # vision's own token arrives, its learner one does not


def test_a_wrong_password_cannot_connect(bus, monkeypatch):
    """(d) A valid learner certificate with a wrong password, or another identity's, is refused."""
    cfg, tmp, _ = bus
    monkeypatch.setenv("SEC_TEST_PW", "not-the-password")
    for auth in (
        {"password_file": "", "password_env": "SEC_TEST_PW"},
        {"password_file": str(tmp / "certs" / "vision.password")},  # user learner, vision's password
    ):
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            open_session(_zenoh(cfg["zenoh"], auth=auth), identity="learner")
    b = Bus(open_session(_zenoh(cfg["zenoh"]), identity="learner"), "x")  # the right one still connects
    b.close()


def test_user_password_alone_identifies_by_user_name(tmp_path):
    """Without TLS (tcp + user/password), the access control goes by user name: vision's command is
    dropped, the learner's arrives, a wrong password cannot connect."""
    certs = _make_certs(tmp_path / "c", "learner", "vision", "router")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    auth = {"user": "{identity}", "password_file": str(certs / "{identity}.password")}
    router = {"listen": [endpoint], "dictionary_file": str(certs / "usrpwd.txt"), "access_control": "roles"}
    base = {"mode": "client", "connect": [endpoint], "auth": auth, "router": router}
    r = open_session(
        ZenohConfig.model_validate({**base, "mode": "router", "connect": [], "listen": [endpoint]}), "router"
    )
    name = unique_name("pw")
    buses = [
        Bus(open_session(ZenohConfig.model_validate(base), identity=who), name)
        for who in ("learner", "vision")
    ]
    try:
        got = _heard(buses[0], "cmd/chunk")
        time.sleep(0.5)
        buses[1].session.put(buses[1].key("cmd/chunk"), b"vision")
        buses[0].session.put(buses[0].key("cmd/chunk"), b"learner")
        wait_until(lambda: got["cmd/chunk"], what="a chunk")
        time.sleep(0.3)
        assert got["cmd/chunk"] == [b"learner"]
        wrong = {**auth, "password_file": str(certs / "vision.password")}
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            open_session(ZenohConfig.model_validate({**base, "auth": wrong}), identity="learner")
    finally:
        for b in buses:
            b.close()
        r.close()


def test_config_errors_name_the_key(bus, tmp_path):
    cfg, tmp, _ = bus
    base = cfg["zenoh"]
    with pytest.raises(ValueError, match=r"connect: \['tcp/10.0.0.1:7447'\] with zenoh.tls set"):
        _zenoh({**base, "connect": ["tcp/10.0.0.1:7447"]})
    with pytest.raises(ValueError, match="tls.ca\n.*no such file /nowhere/ca.pem"):
        _zenoh(base, tls={"ca": "/nowhere/ca.pem"})
    with pytest.raises(ValueError, match="router.access_control: roles tells identities apart"):
        ZenohConfig.model_validate(
            {"tls": {**base["tls"], "mtls": False}, "connect": base["connect"], "router": {}}
        )
    shared_user = {"auth": {"user": "adaptiveh", "password_env": "X"}, "router": {"dictionary_file": "d"}}
    with pytest.raises(ValueError, match="roles by user name needs zenoh.auth.user to contain {identity}"):
        ZenohConfig.model_validate(shared_user)  # one user for every part: no telling them apart
    with pytest.raises(ConfigError, match=r"zenoh.tls.cert: no such file .*/nobody.pem \(identity nobody\)"):
        open_session(_zenoh(base), identity="nobody")
    with pytest.raises(
        ConfigError, match=f"zenoh.tls.cert: .* needs this process's identity: set {IDENTITY_ENV}"
    ):
        open_session(_zenoh(base), identity="")
    loose = tmp_path / "learner.password"
    loose.write_text("x")
    loose.chmod(0o644)
    with pytest.raises(ConfigError, match="zenoh.auth.password_file: .* readable by others"):
        open_session(_zenoh(base, auth={"password_file": str(loose)}), identity="learner")


def test_check_finds_each_parts_certificate_and_password(tmp_path):
    """``adaptiveh up --check`` on a secured config: a part whose files are missing is named."""
    certs = _make_certs(tmp_path / "c", "learner", "actor", "robot-io", "monitor", "supervisor")  # no vision
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(_shipped(certs, "tls/127.0.0.1:7447")))
    ok, lines = check(path)
    assert not ok and "zenoh identity learner: certificate and credentials found" in lines
    assert [line for line in lines if line.startswith("MISSING")] == [
        f"MISSING for zenoh identity vision: zenoh.tls.cert: no such file {certs}/vision.pem"
        " (identity vision); test certificates: scripts/make_test_certs.sh"
    ]


def test_the_parts_run_through_the_secured_router_and_a_control_needs_the_token(
    bus, tmp_path, monkeypatch, caplog
):
    """The real robot-io and learner (identities from their commands) learn one episode through the TLS
    router. A control without the operator token: robot-io refuses it with a safety event; the monitor's
    page refuses it (403) and logs it. A control or chunk from vision never reaches robot-io at all."""
    cfg, _, join = bus
    monkeypatch.setenv(TOKEN_ENV, TOKEN)
    monkeypatch.delenv(IDENTITY_ENV, raising=False)
    # The learner drives the arm itself here (closed loop), through the router under its identity.
    learner = {**cfg["learner"], "steps": 60, "target_topic": "sim/target_truth", "execution": "closed_loop"}
    part = {**cfg, "learner": learner}
    part["learner"]["checkpoint_dir"] = str(tmp_path / "l")
    part.pop("vision")
    probe = BusProbe(join("supervisor"))
    safety, states = probe.collect(m.EVENTS_SAFETY, arrival=False), probe.collect(m.STATE, arrival=False)
    up = lambda: probe.wait(lambda: len(states) > 3, 60, "robot-io's state through the router")  # noqa: E731
    with running_part("robot-io", part, tmp_path, up):
        monitor, vision = join("monitor"), join("vision")
        time.sleep(0.3)
        refused = lambda: [e for e in safety if "not signed with the stack's key" in e.detail]  # noqa: E731
        stranger = m.Control(command=m.Control.RELEASE, jog=[0, 0, 0]).SerializeToString()
        vision.session.put(vision.key(m.CONTROL), stranger)  # even with a token it would be dropped
        vision.session.put(vision.key(m.CMD_CHUNK), b"\xff\xff not a chunk")
        monitor.session.put(monitor.key(m.CONTROL), stranger)
        probe.wait(refused, 5, "robot-io refusing the control without the token")
        time.sleep(0.5)
        assert len(refused()) == 1  # the monitor's; vision's control never arrived
        assert not [e for e in safety if m.CMD_CHUNK.name in e.detail]  # nor vision's chunk

        server = MonitorServer(monitor, MonitorConfig(port=0, foxglove_port=None), token=TOKEN)
        with caplog.at_level(logging.WARNING, logger="monitor.server"):
            assert server.control("release", None, "")[0] == 403
            assert server.control("release", None, "wrong")[0] == 403
        # Both refused, one line: anyone who reaches the page can repeat a request (rate-limited log).
        assert caplog.text.count("control 'release' refused: wrong or missing token") == 1
        server.httpd.server_close()

        config = tmp_path / "learner.yaml"
        config.write_text(yaml.safe_dump(part))
        res = learn_one_episode(config, tmp_path / "l")
        assert res["global_step"] == 60
