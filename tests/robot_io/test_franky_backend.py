"""FrankyBackend on franky-sim (the robot's own clock), and the controller's fault policy.

Timings are read from the robot state's own clock (``RobotState.time``): franky-sim runs slower than
real time on a loaded machine, and the arm's stopping time is a property of the commanded motion.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from polling import wait_until

from robot_io.backends.franky_config import FrankaConfig
from robot_io.backends.protocol import Fault, JointState
from robot_io.config import RobotConfig
from robot_io.controller import RobotController

ROOT = Path(__file__).resolve().parents[2]
HOST = f"127.0.{np.random.randint(1, 250)}.{np.random.randint(2, 250)}"
PERIOD = 0.05


@pytest.fixture(scope="module")
def backend():
    pytest.importorskip("franky")
    pytest.importorskip("franky_sim")
    from franka_simulators import FrankySimServer

    from robot_io.backends.franky_backend import FrankyBackend

    with FrankySimServer(HOST):
        b = FrankyBackend(RobotConfig(backend="franka", model="fr3", franka=FrankaConfig(ip=HOST)))
        yield b
        b.close()


def test_connect_checks_the_model(backend):
    assert backend.report.flange_error_m < 1e-3 and backend.report.limits_checked
    assert backend.report.server_version == 10


def test_streamed_targets_move_and_hold_stills_the_command_within_two_periods(backend):
    q = backend.read_state().q
    for _ in range(15):  # joint 1 at 0.2 rad/s of wall time (faster in the robot's time when it lags)
        q = q + np.array([0.01, 0, 0, 0, 0, 0, 0])
        backend.send_joint_command(q)
        time.sleep(PERIOD)
    state = backend.robot.state
    assert abs(state.dq_d[0]) > 0.1, "the streamed motion should be under way"
    speed = abs(state.dq_d[0])
    t0 = state.time.to_sec()
    backend.hold()

    def stopped():
        state = backend.robot.state
        return state if np.max(np.abs(state.dq_d)) < 0.01 else None

    state = wait_until(stopped, 5, "the hold to stop the arm", every=0.002)
    still_s = state.time.to_sec() - t0
    # Two periods is the bound for the 0.2 rad/s the hold is sized for (HOLD_DYNAMICS); when franky-sim lags
    # under load the stream reaches more (0.32 rad/s seen in a full run), and a brake at a fixed
    # deceleration needs proportionally longer.
    bound = 2 * PERIOD * max(1.0, speed / 0.2)
    assert still_s <= bound, (
        f"the command came to rest {1000 * still_s:.0f} ms (robot time) after hold at {speed:.2f} rad/s "
        f"(bound {1000 * bound:.0f} ms)"
    )
    assert backend.fault() is None


def test_a_hold_brakes_at_its_own_dynamics_and_leaves_the_robot_wide_factor_alone(backend):
    """Each motion carries its own dynamics factor: a hold used to set franky's robot-wide factor to its
    braking dynamics, and the move home after it ran at home_dynamics times those (on the rehearsal's
    settings 0.3 x (1, 0.4, 0.3) instead of 0.3 x (1, 1, 1): ~1.5 s more per episode)."""
    q = backend.read_state().q
    for _ in range(5):
        q = q + np.array([0.01, 0, 0, 0, 0, 0, 0])
        backend.send_joint_command(q)
        time.sleep(PERIOD)
    backend.hold()
    wait_until(lambda: np.max(np.abs(backend.robot.state.dq_d)) < 0.01, 5, "the hold to stop the arm")
    factor = backend.robot.relative_dynamics_factor
    assert (factor.velocity, factor.acceleration, factor.jerk) == (1.0, 1.0, 1.0)
    assert backend.fault() is None


def test_a_fault_ends_the_stream_so_the_arm_is_where_the_reflex_left_it(backend):
    """After a reflex no command runs: the state reports no command (the controller anchors on the measured
    arm) and a hold has nothing to brake, until recovery."""
    q = backend.read_state().q
    backend.send_joint_command(q + np.array([0.005, 0, 0, 0, 0, 0, 0]))
    assert backend.read_state().q_cmd is not None
    time.sleep(0.3)  # the streamed motion ends by itself (its coast waypoint)
    backend._set_fault(RuntimeError("libfranka: Move command aborted: motion aborted by reflex!"))
    assert backend.read_state().q_cmd is None and backend.fault() is not None
    assert backend.recover() and backend.fault() is None
    assert backend.read_state().q_cmd is None


class ScriptedFaults:
    """A backend whose driver faults on cue: the controller's policy is what is under test."""

    name = "scripted"

    def __init__(self) -> None:
        self.current: Fault | None = None
        self.recoveries = 0
        self.recover_ok = True

    def read_state(self) -> JointState:
        return JointState(np.array(RobotConfig().home_q), np.zeros(7), 0.0)

    def send_joint_command(self, q: np.ndarray) -> None: ...
    def hold(self) -> None: ...
    def reset(self, q_home: np.ndarray, seed: int | None) -> None: ...
    def step(self) -> None: ...
    def close(self) -> None: ...

    def fault(self) -> Fault | None:
        return self.current

    def recover(self) -> bool:
        self.recoveries += 1
        if self.recover_ok:
            self.current = None
        return self.recover_ok


def test_listed_reflexes_recover_automatically_a_bounded_number_of_times():
    cfg = RobotConfig(
        franka=FrankaConfig(auto_recover=("communication_constraints_violation",), auto_recover_limit=2)
    )
    backend = ScriptedFaults()
    c = RobotController(cfg, backend=backend)
    for expected in (1, 2):
        backend.current = Fault(("communication_constraints_violation",), "reflex")
        result = c.tick(0.0)
        assert backend.recoveries == expected and c.safety.mode == "running"
        assert [e.kind for e in result.events] == ["driver_error", "release"]
    backend.current = Fault(("communication_constraints_violation",), "reflex")
    c.tick(0.0)
    assert backend.recoveries == 2 and c.safety.mode == "fault"  # the budget is spent: the operator decides
    c.operator("release")
    c.tick(0.0)
    assert backend.recoveries == 3 and c.safety.mode == "running" and c.recovery.auto_used == 0


def test_other_faults_hold_until_a_release_whose_recovery_succeeds():
    backend = ScriptedFaults()
    c = RobotController(RobotConfig(), backend=backend)
    backend.current = Fault(("joint_velocity_violation",), "reflex")
    c.tick(0.0)
    assert backend.recoveries == 0 and c.safety.mode == "fault" and c.state().mode == "fault"
    backend.recover_ok = False
    c.operator("release")
    events = c.tick(0.0).events
    assert c.safety.mode == "fault" and any("recovery failed" in e.detail for e in events)
    backend.recover_ok = True
    c.operator("release")
    c.tick(0.0)
    assert c.safety.mode == "running"
    c.obey("the-learner")
    assert c.push_chunk("the-learner", 1, np.zeros((2, 3)), 0.0) == "accepted"


def test_reset_brakes_a_hand_moving_down_before_its_gentler_move_home():
    """The move home runs at ``franka.home_dynamics``: started while the hand heads for the table, it
    carried the hand ~15 cm on (at the real arm's settings on franky-sim), under the box's floor. Reset
    brakes first: the hand goes on by its braking distance, a few centimetres."""
    pytest.importorskip("franky_sim")
    from franka_simulators import FrankySimServer

    from deploy.config import load_stack_config

    host = f"127.0.{np.random.randint(1, 250)}.{np.random.randint(2, 250)}"
    robot = load_stack_config(ROOT / "configs/gaps/franka_limits.yaml").robot
    franka = robot.franka.model_copy(update={"ip": host, "simulated_target": False})
    config = robot.model_copy(update={"franka": franka})
    with FrankySimServer(host):
        controller = RobotController(config)
        try:
            controller.reset()
            for goal, periods in (((0.5, 0.0, 0.3), 80), ((0.6, 0.3, 0.0), 28)):  # then toward the table
                for _ in range(periods):
                    away = np.asarray(goal) - controller.state().ee_pos
                    controller.step_action(away * min(1.0, config.max_step_m / np.linalg.norm(away)))
                    time.sleep(config.period)
            start = controller.state()
            assert start.ee_vel[2] < -0.1, "the hand should be moving down"
            lowest = [start.ee_pos[2]]
            controller.reset(while_homing=lambda state: lowest.append(state.ee_pos[2]))
        finally:
            controller.close()
    went_on = start.ee_pos[2] - min(lowest)
    assert went_on < 0.06, f"the hand went on {100 * went_on:.1f} cm down after homing began"
