"""The real arm (Panda or FR3) through franky: motions run in franky's C++ 1 kHz loop, never in Python.

Each control period the controller hands over one IK target. It becomes an asynchronous franky
``JointWaypointMotion`` that preempts the previous one; franky plans it with Ruckig from the arm's
current position, velocity and acceleration, so the commanded motion is jerk-limited across the seam.
``franka.stream`` picks the waypoint (bench/franka_bench.py measured both):

- ``velocity``: reach the target in one period (``minimum_time``) *moving at the velocity the last two
  targets imply*, then a rest waypoint one more period ahead. While targets keep coming every period
  the rest waypoint is never reached and the motions join into one; if they stop, the arm comes to
  rest by itself, one period's travel further on (clipped to the joint limits).
- ``rest``: the target alone, approached to a stop: stop-and-go at the control rate.

``hold()`` preempts with a braking waypoint at the arm's full dynamic limits (jerk-limited, so a hold
never trips a discontinuity reflex) and keeps commanding that position until the next command. A
reflex, a rejected command or a lost connection ends franky's motion with an exception, which
``fault()`` reports as a ``Fault`` until ``recover()`` runs
libfranka's automatic error recovery, or reconnects when the connection was lost (a dead libfranka
connection cannot be reused). Connecting verifies the arm against ``robot.model``
(``franky_model.verify_model``). franky is imported here only, so the stack runs without it.
"""

from __future__ import annotations

import importlib
import logging
import time
from types import ModuleType
from typing import Any

import numpy as np

from robot_io.backends.franky_model import (
    ModelMismatch,
    libfranka_version,
    server_version_for,
    verify_model,
)
from robot_io.backends.protocol import Fault, JointState
from robot_io.config import RobotConfig
from robot_io.description import RobotDescription

log = logging.getLogger(__name__)

CONNECTION_LOST = "connection_lost"
BRAKE_FRACTION = 0.8  # of the joint acceleration limits, for where a hold stops


class SimulatedTarget:
    """A scripted target for franky-sim, whose world no camera sees (``franka.simulated_target``).

    It has the fields robot-io's ground-truth publisher reads from the PyBullet scene (``target``,
    ``target_velocity``), and moves by the control period each ``step``, like the mock's target.
    """

    def __init__(self, config: RobotConfig) -> None:
        from sim.panda_scene import TargetMotion, TargetState

        self.motion = TargetMotion.preset(config.target_motion)
        self._state_cls = TargetState
        self.target = TargetState.start(self.motion, config.seed)

    def reset(self, seed: int | None) -> None:
        self.target = self._state_cls.start(self.motion, seed)

    def advance(self, dt: float) -> None:
        self.target.advance(dt)

    def target_velocity(self) -> np.ndarray:
        return self.target.velocity.copy()


class FrankyBackend:
    name = "franka"

    def __init__(
        self, config: RobotConfig, description: RobotDescription | None = None, lib: ModuleType | None = None
    ) -> None:
        self.config = config
        self.fc = config.franka
        self.franky = lib if lib is not None else importlib.import_module("franky")
        self.description = description or RobotDescription(config.model)
        limits = self.description.limits
        self.lower = limits.lower + config.joint_margin_rad
        self.upper = limits.upper - config.joint_margin_rad
        self.period_ms = max(1, round(config.period * 1000))
        self.scene = SimulatedTarget(config) if self.fc.simulated_target else None
        self.robot: Any = None
        self.report = None
        self._fault: Fault | None = None
        self._last_target: np.ndarray | None = None
        self._stopping = True  # no motion of ours is running
        self._q = np.zeros(7)
        self._connect()

    # -- connection ----------------------------------------------------------------------------------
    def _connect(self) -> None:
        f = self.franky
        realtime = f.RealtimeConfig.Enforce if self.fc.realtime == "enforce" else f.RealtimeConfig.Ignore
        robot = f.Robot(self.fc.ip, realtime_config=realtime)
        lib = libfranka_version()
        self.report = verify_model(robot, f, self.description, server_version_for(lib) if lib else None)
        robot.relative_dynamics_factor = f.RelativeDynamicsFactor(*self.fc.dynamics)
        robot.set_collision_behavior(
            list(self.fc.lower_torque_thresholds),
            list(self.fc.upper_torque_thresholds),
            list(self.fc.lower_force_thresholds),
            list(self.fc.upper_force_thresholds),
        )
        robot.set_joint_impedance(list(self.fc.joint_impedance))
        self.robot = robot
        self._q = np.asarray(robot.current_joint_state.position, float)
        self._last_target = None
        self._stopping = True
        log.info("franky connected to %s (%s): %s", self.fc.ip, self.description.model.name, self.report)

    def _set_fault(self, exc: BaseException) -> None:
        """Name what stopped the arm: libfranka's error flags, or a lost connection."""
        if self._fault is not None:
            return
        text = f"{type(exc).__name__}: {exc}"
        if isinstance(exc, self.franky.NetworkException) or "Net Exception" in str(exc):
            self._fault = Fault((CONNECTION_LOST,), text)
        else:
            self._fault = Fault(self._error_names() or ("control_exception",), text)
        log.error("franka fault: %s", self._fault)

    def _error_names(self) -> tuple[str, ...]:
        try:
            errors = self.robot.state.last_motion_errors
        except Exception:
            return ()
        names = [n for n in dir(errors) if not n.startswith("_")]
        return tuple(n for n in names if getattr(errors, n, False) is True)

    def _move(self, motion: Any) -> None:
        try:
            self.robot.move(motion, asynchronous=True)
        except Exception as exc:  # franky rethrows a stored motion error here, or refuses the move
            self._set_fault(exc)

    # -- protocol ------------------------------------------------------------------------------------
    def read_state(self) -> JointState:
        if self._fault is None or self._fault.kinds != (CONNECTION_LOST,):
            try:
                state = self.robot.state
                self._q = np.asarray(state.q, float)
                q_cmd = None if self._stopping or self._last_target is None else self._last_target.copy()
                return JointState(self._q.copy(), np.asarray(state.dq, float), time.monotonic(), q_cmd)
            except Exception as exc:
                self._set_fault(exc)
        return JointState(self._q.copy(), np.zeros(7), time.monotonic())  # the last known position

    def send_joint_command(self, q: np.ndarray) -> None:
        if self._fault is not None:
            return
        f = self.franky
        q = np.asarray(q, float)
        if self.fc.stream == "rest" or self._last_target is None:
            waypoints = [f.JointWaypoint(f.JointState(q))]
        else:
            v = (q - self._last_target) / self.config.period
            coast = np.clip(q + v * self.config.period, self.lower, self.upper)
            waypoints = [
                f.JointWaypoint(f.JointState(q, v), minimum_time=f.Duration(self.period_ms)),
                f.JointWaypoint(f.JointState(coast)),
            ]
        self._last_target = q.copy()
        if self._stopping:  # leaving a hold: back to the streaming dynamics
            self.robot.relative_dynamics_factor = f.RelativeDynamicsFactor(*self.fc.dynamics)
        self._stopping = False
        self._move(f.JointWaypointMotion(waypoints))

    def hold(self) -> None:
        """Brake to rest where the *command* can stop at full deceleration. franky's JointStopMotion
        would head back to the measured position, which lags the command while moving (a reversal)."""
        self._last_target = None
        if self._fault is not None or self._stopping:
            return
        self._stopping = True
        try:
            state = self.robot.state
            amax = np.asarray(self.robot.joint_acceleration_limit.max, float)
        except Exception as exc:
            self._set_fault(exc)
            return
        q_d, dq_d = np.asarray(state.q_d, float), np.asarray(state.dq_d, float)
        # Braking distance at 80% of the limit: the jerk-limited profile needs a little more room than a
        # constant deceleration, and a target too close makes it overshoot and come back.
        stop = np.clip(q_d + dq_d * np.abs(dq_d) / (2 * BRAKE_FRACTION * amax), self.lower, self.upper)
        self.robot.relative_dynamics_factor = 1.0  # braking may use the arm's full limits
        self._hold_at(stop)

    def _hold_at(self, q: np.ndarray) -> None:
        """Go to ``q`` and keep commanding it (the motion never ends by itself), so a held arm stays
        under position control rather than idle; the next command preempts it."""
        f = self.franky
        self._move(f.JointWaypointMotion([f.JointWaypoint(f.JointState(q))], 1.0, False))

    def fault(self) -> Fault | None:
        if self._fault is None and self.robot is not None:
            try:
                self.robot.poll_motion()
            except Exception as exc:
                self._set_fault(exc)
        return self._fault

    def recover(self) -> bool:
        """Clear the fault: libfranka's automatic error recovery, or a new connection after a lost one."""
        try:
            if self._fault is not None and CONNECTION_LOST in self._fault.kinds:
                self._connect()
            elif not self.robot.recover_from_errors():
                return False
        except ModelMismatch:
            raise
        except Exception as exc:
            log.warning("franka recovery failed: %s: %s", type(exc).__name__, exc)
            return False
        self._fault = None
        self._last_target = None
        self._stopping = True
        return True

    def reset(self, q_home: np.ndarray, seed: int | None, timeout_s: float = 30.0) -> None:
        """Move home point to point at ``franka.home_dynamics`` and wait there; a fault raises."""
        if self.scene is not None:
            self.scene.reset(seed)
        if self.fault() is not None:
            raise RuntimeError(f"franka fault, release to recover first: {self._fault}")
        f = self.franky
        home = f.JointWaypoint(f.JointState(np.asarray(q_home, float)))
        self._last_target = None
        self._stopping = True
        try:
            self.robot.move(f.JointWaypointMotion([home], self.fc.home_dynamics), asynchronous=True)
            if not self.robot.join_motion(timeout=timeout_s):
                raise TimeoutError(f"franka did not reach home within {timeout_s} s")
            self._hold_at(np.asarray(q_home, float))
        except TimeoutError:
            raise
        except Exception as exc:
            self._set_fault(exc)
            raise RuntimeError(f"franka fault while going home: {self._fault}") from exc

    def step(self) -> None:
        """The arm moves on franky's own loop; only the scripted target advances with the period."""
        if self.scene is not None:
            self.scene.advance(self.config.period)

    def close(self) -> None:
        if self.robot is None:
            return
        try:
            if self._fault is None and self.robot.is_in_control:
                self.robot.stop()  # ends the holding motion; the arm is at rest by then
        except Exception as exc:
            log.warning("franka stop on close: %s", exc)
        self.robot = None
