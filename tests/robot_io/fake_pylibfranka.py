"""A stand-in for pylibfranka at its API boundary (same class, method and attribute names).

It simulates a 1 kHz robot that follows joint position commands exactly and, like libfranka's motion
generator checks, ends the control loop with ``ControlException`` when a command jumps (velocity,
acceleration or jerk beyond the Panda limits), and refuses ``read_once`` while a control loop runs.
Tests can inject a reflex with ``robot.inject_reflex``.
"""

from __future__ import annotations

import threading
import time
from enum import Enum

import numpy as np

Q_MAX_VEL = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])
Q_MAX_ACC = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])
Q_MAX_JERK = np.full(7, 7500.0)
DT = 0.001


class FrankaException(Exception):
    pass


class ControlException(FrankaException, RuntimeError):
    pass


class InvalidOperationException(FrankaException, RuntimeError):
    pass


class NetworkException(FrankaException, RuntimeError):
    pass


class RealtimeConfig(Enum):
    kEnforce = 0
    kIgnore = 1


class ControllerMode(Enum):
    JointImpedance = 0
    CartesianImpedance = 1


class Duration:
    def __init__(self, seconds: float) -> None:
        self._s = seconds

    def to_sec(self) -> float:
        return self._s


class RobotState:
    def __init__(self, q: np.ndarray, dq: np.ndarray) -> None:
        self.q = q.copy()
        self.dq = dq.copy()
        self.q_d = q.copy()


class JointPositions:
    def __init__(self, q: list[float]) -> None:
        if len(q) != 7:
            raise ValueError("JointPositions needs 7 values")
        self.q = list(q)
        self.motion_finished = False


class ActiveControl:
    def __init__(self, robot: Robot) -> None:
        self.robot = robot
        self._first = True

    def readOnce(self) -> tuple[RobotState, Duration]:
        time.sleep(DT)  # the robot's packets pace the loop
        r = self.robot
        with r.lock:
            if r.reflex:
                r.reflex = False
                r.control_active = False
                raise ControlException("libfranka: Move command aborted: cartesian_reflex")
            state = RobotState(r.q, r.dq)
        duration = Duration(0.0 if self._first else DT)
        self._first = False
        return state, duration

    def writeOnce(self, command: JointPositions) -> None:
        r = self.robot
        q_new = np.asarray(command.q, float)
        with r.lock:
            dq = (q_new - r.q) / DT
            ddq = (dq - r.dq) / DT
            jerk = (ddq - r.ddq) / DT
            for name, value, limit in (
                ("joint_velocity_violation", dq, Q_MAX_VEL),
                ("joint_motion_generator_acceleration_discontinuity", ddq, Q_MAX_ACC),
                ("joint_motion_generator_jerk_discontinuity", jerk, Q_MAX_JERK),
            ):
                if np.any(np.abs(value) > limit):
                    r.control_active = False
                    r.errors.append(name)
                    raise ControlException(
                        f"libfranka: Move command aborted: motion aborted by reflex! [{name}]"
                    )
            r.q, r.dq, r.ddq = q_new, dq, ddq
            r.writes += 1
            if command.motion_finished:
                r.control_active = False
                r.dq[:] = 0.0
                r.ddq[:] = 0.0


class Robot:
    def __init__(
        self, robot_ip_address: str, realtime_config: RealtimeConfig = RealtimeConfig.kEnforce
    ) -> None:
        self.ip = robot_ip_address
        self.realtime_config = realtime_config
        self.lock = threading.Lock()
        self.q = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
        self.dq = np.zeros(7)
        self.ddq = np.zeros(7)
        self.control_active = False
        self.reflex = False
        self.errors: list[str] = []
        self.calls: list[str] = []
        self.writes = 0
        self.collision_behavior: tuple | None = None
        self.joint_impedance: list[float] | None = None

    def set_collision_behavior(self, lower_torque, upper_torque, lower_force, upper_force) -> None:
        if len(lower_torque) != 7 or len(upper_torque) != 7 or len(lower_force) != 6 or len(upper_force) != 6:
            raise ValueError("set_collision_behavior: wrong threshold lengths")
        self.calls.append("set_collision_behavior")
        self.collision_behavior = (
            list(lower_torque),
            list(upper_torque),
            list(lower_force),
            list(upper_force),
        )

    def set_joint_impedance(self, K_theta) -> None:
        self.calls.append("set_joint_impedance")
        self.joint_impedance = list(K_theta)

    def read_once(self) -> RobotState:
        with self.lock:
            if self.control_active:
                raise InvalidOperationException(
                    "libfranka robot: Cannot perform this operation while another controller or motion "
                    "generator is running."
                )
            return RobotState(self.q, self.dq)

    def start_joint_position_control(self, control_type: ControllerMode) -> ActiveControl:
        with self.lock:
            if self.control_active:
                raise InvalidOperationException("a control loop is already running")
            self.control_active = True
        self.calls.append(f"start_joint_position_control:{control_type.name}")
        return ActiveControl(self)

    def automatic_error_recovery(self) -> None:
        self.calls.append("automatic_error_recovery")
        with self.lock:
            self.dq[:] = 0.0
            self.ddq[:] = 0.0

    def stop(self) -> None:
        self.calls.append("stop")
        with self.lock:
            self.control_active = False

    def inject_reflex(self) -> None:
        with self.lock:
            self.reflex = True
