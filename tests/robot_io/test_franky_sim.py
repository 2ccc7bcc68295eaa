"""The real-arm path end to end: robot-io (a subprocess) on franky, against franky-sim (a subprocess).

franky-sim serves libfranka's network protocol from a MuJoCo FR3, so this drives the same franky and
libfranka code as on the arm: connect and model check, chunks played over Zenoh, an e-stop, and a
lost connection (the simulator killed) that holds the arm in mode FAULT until the operator's release
reconnects after the simulator is back. The test is the learner and the operator.
"""

from __future__ import annotations

import itertools
import subprocess
import sys
import time

import numpy as np
import pytest
import yaml
from bus_probe import BusProbe, control, send_chunk
from loopback import free_port, unique_name

from bus import messages as m
from bus.learner_session import LearnerSession
from bus.transport import Bus, ZenohConfig, open_session

franky = pytest.importorskip("franky")
pytest.importorskip("franky_sim")
from franka_simulators import FrankySimServer  # noqa: E402

RATE = 20.0
PERIOD = 1.0 / RATE
HOST = f"127.0.{np.random.randint(1, 250)}.{np.random.randint(2, 250)}"


class Probe(BusProbe):
    """robot-io's states (arrival on the monotonic clock, as the e-stop timing needs), events, truth."""

    def __init__(self, bus: Bus) -> None:
        super().__init__(bus)
        self.states = self.collect(m.STATE)
        self.events = self.collect(m.EVENTS_SAFETY, arrival=False)
        self.truth = self.collect(m.TARGET_TRUTH, arrival=False)
        self.chunks = itertools.count(1)  # robot-io obeys a session's chunks in rising order only
        self.episodes = itertools.count(1)

    def latest(self) -> m.RobotState:
        with self.lock:
            return self.states[-1][1]

    def wait_played(self, seq: int, timeout: float = 10.0) -> None:
        """Chunk ``seq`` played to its end: the newest state names it and the queue is empty."""
        state = self.latest
        self.wait(lambda: state().chunk_seq == seq and state().queue_len == 0, timeout, "the chunk played")

    def kinds(self) -> list[str]:
        with self.lock:
            return [m.label(e, "kind") for e in self.events]


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    server = FrankySimServer(HOST).start()
    port = free_port()
    name = unique_name("f")
    cfg = {
        "name": name,
        "zenoh": {"mode": "peer", "listen": [f"tcp/127.0.0.1:{port}"]},
        "robot": {
            "backend": "franka",
            "model": "fr3",
            "control_rate_hz": RATE,
            "watchdog_timeout_s": 1.0,
            # lock_memory as on the real arm (a refusal only warns under realtime: ignore)
            "franka": {"ip": HOST, "home_dynamics": 0.5, "simulated_target": True, "lock_memory": True},
            # a franka config names its arm's tracking (the plan model's; robot-io itself does not use it)
            "tracking": {"gain": 1.175, "step_m": 0.02, "velocity_ratio": 0.15},
        },
    }
    folder = tmp_path_factory.mktemp("franky")
    path, log = folder / "robot.yaml", folder / "robot_io.log"
    path.write_text(yaml.safe_dump(cfg))
    # Its output to a file, shown if it does not come up: a pipe nobody reads would block it once full.
    with log.open("w") as out:  # the child keeps its own copy of the file
        proc = subprocess.Popen(
            [sys.executable, "-m", "deploy.cli", "robot-io", "--config", str(path), "--log-level", "WARNING"],
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    bus = Bus(open_session(ZenohConfig(connect=(f"tcp/127.0.0.1:{port}",))), name)
    bus.declare_alive("learner")
    probe = Probe(bus)
    probe.learner = LearnerSession(bus)  # the test is the learner: robot-io obeys this session
    try:
        probe.wait(lambda: len(probe.states) > 3, 60, "robot-io's first states")
    except AssertionError:
        proc.kill()
        server.kill()
        proc.wait()
        pytest.fail("robot-io did not come up:\n" + log.read_text())
    yield bus, probe, server
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
    bus.close()
    server.kill()


@pytest.fixture
def arm(stack):
    """The arm running and homed by this session's reset, whatever the test before left (an e-stop, a
    fault with the simulator down), so that each test stands alone and in any order."""
    bus, probe, server = stack
    if server.proc is None:
        server.start()
    if probe.latest().mode in (m.RobotState.ESTOP, m.RobotState.FAULT):
        control(bus, "release")
        probe.wait(lambda: probe.latest().mode == m.RobotState.RUNNING, 20, "running after release")
    reply = probe.learner.reset(next(probe.episodes), timeout=30)
    assert reply.ok, reply.detail
    return stack


def test_01_reset_homes_the_fr3_and_the_scripted_target_is_published(stack):
    bus, probe, _ = stack
    reply = probe.learner.reset(next(probe.episodes), timeout=30)
    assert reply.ok, reply.detail
    assert reply.state.mode == m.RobotState.RUNNING
    # FR3 home (our FK: 0.307, 0, 0.487). The reply is read as franky's motion ends; franky-sim's PD
    # tracks it with a lag that grows on a loaded machine (1.1 cm once in CI, on 2 busy cores), then
    # settles within a few millimetres (it sags under gravity).
    home = np.array([0.307, 0.0, 0.487])
    assert np.linalg.norm(reply.state.ee_pos - home) < 0.03, reply.state.ee_pos
    probe.wait(lambda: np.linalg.norm(probe.latest().ee_pos - home) < 0.01, 5, "the arm settled at home")
    truth = probe.wait(lambda: probe.truth[-1] if probe.truth else None, 5, "sim/target_truth")
    assert truth.valid and 0.3 < truth.position[0] < 0.7


def test_02_chunks_play_on_the_arm(arm):
    bus, probe, _ = arm
    y0, events = probe.latest().ee_pos[1], len(probe.kinds())
    seq = next(probe.chunks)
    send_chunk(bus, seq, np.tile([0.0, 0.01, 0.0], (20, 1)), probe.learner.id)  # 20 cm at 1 cm per period
    probe.wait_played(seq)
    probe.wait(lambda: probe.latest().ee_pos[1] - y0 > 0.04, 5, "the end effector to follow")
    assert "driver_error" not in probe.kinds()[events:]


def test_03_estop_holds_the_arm_at_once(arm):
    bus, probe, _ = arm
    send_chunk(bus, next(probe.chunks), np.tile([0.0, -0.01, 0.0], (40, 1)), probe.learner.id)
    probe.wait(lambda: np.linalg.norm(probe.latest().ee_vel) > 0.03, 10, "the arm moving")
    t_stop = time.time()  # the probe stamps arrivals on the wall clock
    control(bus, "estop")
    probe.wait(lambda: any(t > t_stop and s.mode == m.RobotState.ESTOP for t, s in probe.states), 2, "ESTOP")
    # The command is still within two periods of the robot's clock (test_franky_backend measures it);
    # franky-sim's PD then settles the simulated joints. The end effector is what is checked: after
    # streamed motions franky-sim's joint 7 (the flange roll, which does not move the TCP) keeps
    # reporting ~0.08 rad/s while commanded still, a simulator artifact.
    probe.wait(lambda: np.linalg.norm(probe.latest().ee_vel) < 0.005, 5, "the end effector still")
    assert probe.latest().queue_len == 0
    control(bus, "release")
    probe.wait(lambda: probe.latest().mode == m.RobotState.RUNNING, 5, "running after release")


def test_04_lost_connection_holds_in_fault_and_release_recovers(arm):
    bus, probe, server = arm
    events = len(probe.events)
    server.kill()
    probe.wait(lambda: probe.latest().mode == m.RobotState.FAULT, 10, "mode FAULT")
    # The event and the state travel on two keys: Zenoh orders each key, not the two together.
    fault = probe.wait(
        lambda: next((e for e in list(probe.events)[events:] if m.label(e, "kind") == "driver_error"), None),
        5,
        "the driver_error event",
    )
    assert "connection_lost" in fault.detail and fault.held
    send_chunk(bus, next(probe.chunks), np.tile([0.0, 0.01, 0.0], (5, 1)), probe.learner.id)
    time.sleep(0.3)
    assert probe.latest().mode == m.RobotState.FAULT  # no command reaches a faulted arm
    control(bus, "release")  # the simulator is still down: recovery fails, the arm stays held
    failed = lambda: any("recovery failed" in e.detail for e in list(probe.events)[events:])  # noqa: E731
    probe.wait(failed, 10, "a failed recovery")
    assert probe.latest().mode == m.RobotState.FAULT
    server.start()
    control(bus, "release")
    probe.wait(lambda: probe.latest().mode == m.RobotState.RUNNING, 20, "running after recovery")
    # The clearing event travels on its own key (no order with the state's): wait for it as well.
    cleared = "driver_error cleared: operator release"
    probe.wait(
        lambda: any(cleared in e.detail for e in list(probe.events)[events:]), 5, "the recovery's event"
    )
    reply = probe.learner.reset(next(probe.episodes), timeout=30)
    assert reply.ok, reply.detail
    y0, seq = probe.latest().ee_pos[1], next(probe.chunks)
    send_chunk(bus, seq, np.tile([0.0, 0.01, 0.0], (10, 1)), probe.learner.id)
    probe.wait_played(seq)
    # 10 cm commanded: the arm follows 11 cm, but in three runs of about 25 (not reproduced under load)
    # the restarted simulator's arm lagged and followed 4.3 cm (each goal then starts from the measured arm).
    probe.wait(lambda: probe.latest().ee_pos[1] - y0 > 0.03, 5, "the end effector to follow")


def test_05_a_config_naming_the_wrong_arm_is_refused():
    from robot_io.backends.franky_backend import FrankyBackend
    from robot_io.backends.franky_config import FrankaConfig
    from robot_io.backends.franky_model import ModelMismatch
    from robot_io.config import RobotConfig

    other = HOST.rsplit(".", 1)[0] + ("." + str(int(HOST.rsplit(".", 1)[1]) % 250 + 1))
    with FrankySimServer(other):  # its own server: robot-io holds the first one's only connection
        cfg = RobotConfig(backend="franka", model="panda", franka=FrankaConfig(ip=other))
        with pytest.raises(ModelMismatch, match="robot.model is 'panda'.*FR3.*joint limits are narrower"):
            FrankyBackend(cfg)
