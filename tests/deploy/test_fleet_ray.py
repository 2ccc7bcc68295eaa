"""``adaptiveh fleet`` on Ray's own multi-node test cluster on one machine: a head node and a "robot" node
(a custom resource tells them apart). The arm is placed on the robot node, where Ray starts its robot-io
and actor with the supervisor's command lines; through a Zenoh router (this test's own session, also its
probe) it plays the plans of its actor and streams its transitions to a real learner; SIGTERM to the
command stops the arm's parts. Also: the fleet a config grows to, and the errors that name what is wrong.

Ray's footprint is kept small for a 2-core machine: one CPU per node, no dashboard, loopback only.
"""

from __future__ import annotations

import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

# Ray on loopback only, no usage report (read when Ray is imported: set before).
RAY_ENV = {
    "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",  # despite the name: node IP = 127.0.0.1 on Linux too
    "RAY_USAGE_STATS_ENABLED": "0",
    "RAY_GRACEFUL_SHUTDOWN_DRAIN_TIMEOUT_S": "0",
    "RAY_AUTH_MODE": "disabled",
}
os.environ.update(RAY_ENV)

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install -e '.[ray]'): no adaptiveh fleet")

from bus_probe import BusProbe  # noqa: E402
from loopback import free_endpoint, free_port, unique_name  # noqa: E402
from polling import wait_until  # noqa: E402
from ray.cluster_utils import Cluster  # noqa: E402
from stack_helpers import running_part  # noqa: E402

from bus import messages as m  # noqa: E402
from bus.signing import mac_key  # noqa: E402
from bus.transport import Bus, ZenohConfig, open_session  # noqa: E402
from deploy.config import compose_stack_yaml  # noqa: E402
from deploy.part_env import TOKEN_ENV  # noqa: E402
from deploy.ray_fleet import FleetError, check_reachable, fleet_config  # noqa: E402
from deploy.stack import running_parts  # noqa: E402

ARM = "left"


@pytest.fixture
def cluster(monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[Cluster, str]]:
    """A head node and a robot node (resource ``robot``), one CPU each; yields it and the robot node's id."""
    temp = Path(f"/tmp/rayfleet-{os.getpid()}")  # Ray's socket paths must stay short: not under pytest's tmp
    monkeypatch.setenv("RAY_TMPDIR", str(temp))  # also where Ray notes the cluster's address, not /tmp/ray
    small = {"num_cpus": 1, "node_ip_address": "127.0.0.1"}
    cluster = Cluster(initialize_head=True, head_node_args={**small, "include_dashboard": False})
    try:
        robot = cluster.add_node(**small, resources={"robot": 1})
        yield cluster, robot.node_id
    finally:
        cluster.shutdown()
        shutil.rmtree(temp, ignore_errors=True)


def fleet_yaml(directory: Path, endpoint: str) -> tuple[Path, dict]:
    """configs/fleet.yaml made private to the test: one arm, the router at ``endpoint``."""
    cfg = compose_stack_yaml("configs/fleet.yaml")
    cfg.update(name=unique_name("fleet"), zenoh={"mode": "client", "connect": [endpoint]})
    cfg["fleet"] = {"arms": [{"name": ARM, "seed": 3}]}
    cfg["learner"].update(steps=100_000, checkpoint_dir=str(directory / "learner"))
    cfg["recording"]["dir"] = str(directory / "rec")
    path = directory / "fleet.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path, cfg


def wait_placed(out: Path, proc: subprocess.Popen, timeout: float = 90.0) -> str:
    """The node id ``adaptiveh fleet`` printed for the arm once placed."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        found = re.search(rf"^{ARM}: node (\w+) ", out.read_text(), re.M)
        if found:
            return found.group(1)
        time.sleep(0.5)
    pytest.fail(f"adaptiveh fleet placed nothing (exit {proc.poll()}):\n{out.read_text()[-3000:]}")


def playing(statuses: list[m.ChunkStatus]) -> bool:
    """Some chunk was accepted and played in part (not held, not refused)."""
    return any(s.verdict == m.ChunkStatus.ACCEPTED and s.executed for s in statuses)


def learned(transitions: list[m.Transition], acks: list[m.TransitionAck]) -> bool:
    """The learner says it learned from the stream of the arm's transitions."""
    streams = {t.stream for t in transitions if t.arm == ARM}
    return any(a.stream in streams and a.learned > 0 for a in acks)


def restarted(config: Path, before: dict[str, int]) -> bool:
    """Both of the arm's parts run again, neither the process it was."""
    now = running_parts(config)
    return set(now) == set(before) and not set(now.values()) & set(before.values())


def test_an_arm_placed_on_the_robot_node_plays_plans_for_the_learner(cluster, tmp_path):
    ray_cluster, robot_node = cluster
    endpoint, token = free_endpoint(), secrets.token_urlsafe(12)
    path, cfg = fleet_yaml(tmp_path, endpoint)
    router = Bus(open_session(ZenohConfig(mode="router", listen=(endpoint,))), cfg["name"], mac_key(token))
    probe = BusProbe(router)  # only what the parts signed with the token
    transitions = probe.collect(m.TRANSITIONS, arrival=False)  # the fleet's key: every arm's
    acks = probe.collect(m.TRANSITION_ACKS, arrival=False)  # what the learner learned, by stream
    played: list[m.ChunkStatus] = []  # the arm's own key, guarded as the probe's lists are

    def on_status(status: m.ChunkStatus) -> None:
        with probe.lock:
            played.append(status)

    router.subscribe(m.CHUNK_STATUS, on_status, arm=ARM)
    node_config = tmp_path / "nodes" / cfg["name"] / ARM / "config.yaml"
    out = tmp_path / "fleet.out"
    try:
        with running_part("learn", cfg, tmp_path, lambda: None, token=token), out.open("w") as sink:
            fleet = subprocess.Popen(
                [sys.executable, "-m", "deploy.cli", "fleet", "--ray", ray_cluster.address, "--arms", "1",
                 "--config", str(path), "--resource", "robot", "--node-dir", str(tmp_path / "nodes")],
                stdout=sink, stderr=subprocess.STDOUT, env={**os.environ, TOKEN_ENV: token},
            )  # fmt: skip
            try:
                assert wait_placed(out, fleet) == robot_node  # the Ray actor reports the node it runs on
                first = running_parts(node_config)  # the supervisor's command lines, on the robot node
                assert set(first) == {f"robot-io@{ARM}", f"act@{ARM}"}
                probe.wait(
                    lambda: any(t.arm == ARM and len(t.predicted) for t in transitions), 60, "the arm's ticks"
                )
                probe.wait(lambda: playing(played), 30, "the arm playing its actor's plans")
                probe.wait(lambda: learned(transitions, acks), 30, "the learner learning from the arm")
                os.kill(first[f"robot-io@{ARM}"], signal.SIGKILL)  # Ray restarts the arm, both its parts
                wait_until(lambda: restarted(node_config, first), 60, "Ray restarting the arm", every=0.5)
                seen = len(played)
                probe.wait(lambda: playing(played[seen:]), 60, "the restarted arm playing plans")
                told = f"arm {ARM} restarted by Ray (restart 1)"  # the command noticed it too
                wait_until(
                    lambda: told in out.read_text(), 30, "adaptiveh fleet telling the restart", every=0.5
                )
                fleet.send_signal(signal.SIGTERM)
                assert fleet.wait(timeout=60) == 0, out.read_text()[-3000:]
            finally:
                fleet.kill()
        assert running_parts(node_config) == {}  # stopped with the command
        assert {t.arm for t in transitions} == {ARM}
    finally:
        router.close()


def test_a_fleet_grows_past_its_named_arms(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"base": str(Path("configs/fleet.yaml").resolve()), "fleet": {
        "arms": [{"name": ARM, "seed": 5}, {"name": "right", "seed": 6}]}}))  # fmt: skip
    data, cfg = fleet_config(path, 4, ("tcp/10.0.0.1:7447",))
    assert [(a.name, a.seed) for a in cfg.fleet.arms] == [(ARM, 5), ("right", 6), ("arm2", 2), ("arm3", 3)]
    assert cfg.zenoh.mode == "client" and cfg.zenoh.connect == ("tcp/10.0.0.1:7447",)
    assert data["fleet"]["arms"][3] == {"name": "arm3", "seed": 3}  # what the nodes read
    path.write_text(
        yaml.safe_dump({**yaml.safe_load(path.read_text()), "zenoh": {"connect": ["tcp/r:7447"]}})
    )
    _, cut = fleet_config(path, 1)  # the config's own routers, the arms their clients
    assert [a.name for a in cut.fleet.arms] == [ARM] and cut.zenoh.mode == "client"


def test_errors_name_what_is_wrong(tmp_path):
    with pytest.raises(FleetError, match="no fleet section"):
        fleet_config("configs/sim.yaml", 2, ("tcp/10.0.0.1:7447",))
    with pytest.raises(FleetError, match="zenoh.connect is empty"):
        fleet_config("configs/fleet.yaml", 2)
    with pytest.raises(FleetError, match="expected HOST:PORT"):
        check_reachable("headnode")
    config = tmp_path / "c.yaml"
    config.write_text(yaml.safe_dump({"base": str(Path("configs/fleet.yaml").resolve())}))
    address = f"127.0.0.1:{free_port()}"
    proc = subprocess.run(
        [sys.executable, "-m", "deploy.cli", "fleet", "--ray", address, "--arms", "1", "--config",
         str(config), "--connect", "tcp/127.0.0.1:7447"],
        capture_output=True, text=True, timeout=60, env={**os.environ, TOKEN_ENV: "t"},
    )  # fmt: skip
    assert proc.returncode == 2 and f"no Ray cluster at {address}" in proc.stderr, proc.stderr
