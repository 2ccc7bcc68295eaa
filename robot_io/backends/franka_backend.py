"""The real arm through pylibfranka (the Python bindings of libfranka).

libfranka needs a joint command every millisecond. A dedicated thread runs that loop on pylibfranka's
own control interface (``Robot.start_joint_position_control`` → ``readOnce``/``writeOnce``), paced by
the robot's packets. It follows the latest IK target with a velocity- and acceleration-limited
reference smoothed by a 20 ms moving average (which keeps both bounds and caps the jerk at
2·a_max/20 ms), so libfranka's motion generator never sees a discontinuity. The control loop at the
learner's rate only swaps the target, so it never blocks the 1 kHz loop.
(pylibfranka's ``AsyncPositionControlHandler`` also keeps the loop inside libfranka, but it
exposes no robot state while active, and the learner needs the state.)

Errors (reflexes, collisions, network) end the loop; ``fault()`` reports them and ``recover()`` runs
``automatic_error_recovery`` and restarts the loop. The module is imported lazily so the rest of the
stack runs where pylibfranka is not installed; tests inject a fake with the same class and method names.
"""

from __future__ import annotations

import importlib
import logging
import threading
import time
from collections import deque
from types import ModuleType

import numpy as np

from robot_io.backends.protocol import JointState
from robot_io.config import RobotConfig
from robot_io.description import RobotDescription

log = logging.getLogger(__name__)

# Panda joint acceleration limits (rad/s^2, Franka datasheet); the interpolator uses a fraction.
MAX_JOINT_ACCEL = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])
ACCEL_SCALE = 0.3
SMOOTHING_TICKS = 20  # moving-average length (ms): jerk <= 2 * a_max / 0.02 s = 600 rad/s^3 at 6 rad/s^2


def interpolate(
    q: np.ndarray, v: np.ndarray, target: np.ndarray, dt: float, vmax: np.ndarray, amax: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One 1 kHz step towards ``target``: speed capped by vmax and by the braking distance."""
    err = target - q
    v_des = np.sign(err) * np.minimum(vmax, np.sqrt(2.0 * amax * np.abs(err)))
    a = np.clip((v_des - v) / dt, -amax, amax)
    v = v + a * dt
    return q + v * dt, v


class FrankaBackend:
    name = "franka"

    def __init__(self, config: RobotConfig, lib: ModuleType | None = None) -> None:
        self.config = config
        self.lib = lib if lib is not None else importlib.import_module("pylibfranka")
        fc = config.franka
        realtime = (
            self.lib.RealtimeConfig.kEnforce if fc.realtime == "enforce" else self.lib.RealtimeConfig.kIgnore
        )
        self.robot = self.lib.Robot(fc.ip, realtime)
        self.vmax = RobotDescription().limits.velocity * config.velocity_scale
        self.amax = MAX_JOINT_ACCEL * ACCEL_SCALE
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: str | None = None
        self._braking = False
        self._configure()
        self._start()

    # -- connection ----------------------------------------------------------------------------------
    def _configure(self) -> None:
        fc = self.config.franka
        self.robot.set_collision_behavior(
            list(fc.lower_torque_thresholds),
            list(fc.upper_torque_thresholds),
            list(fc.lower_force_thresholds),
            list(fc.upper_force_thresholds),
        )
        self.robot.set_joint_impedance(list(fc.joint_impedance))

    def _start(self) -> None:
        state = self.robot.read_once()  # allowed only while no control loop runs
        with self._lock:
            self._q = np.array(state.q, float)
            self._dq = np.array(state.dq, float)
            self._stamp = time.monotonic()
            self._target = self._q.copy()
            self._error = None
            self._braking = False
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="franka-1khz", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        try:
            control = self.robot.start_joint_position_control(self.lib.ControllerMode.JointImpedance)
            state, _ = control.readOnce()
            q_d, v = np.array(state.q, float), np.zeros(7)
            window = deque([q_d.copy()] * SMOOTHING_TICKS, maxlen=SMOOTHING_TICKS)
            smooth_sum = q_d * SMOOTHING_TICKS
            while True:
                state, duration = control.readOnce()
                dt = duration.to_sec() or 0.001
                with self._lock:
                    self._q, self._dq = np.array(state.q, float), np.array(state.dq, float)
                    self._stamp = time.monotonic()
                    braking = self._braking or self._stop.is_set()
                    target = self._target.copy()
                if braking:  # decelerate at a_max where we are, then stay there
                    v = v - np.sign(v) * np.minimum(np.abs(v), self.amax * dt)
                    q_d = q_d + v * dt
                    with self._lock:
                        self._target = q_d.copy()
                else:
                    q_d, v = interpolate(q_d, v, target, dt, self.vmax, self.amax)
                stopping = self._stop.is_set()
                smooth_sum += q_d - window[0]
                window.append(q_d.copy())
                command = self.lib.JointPositions((smooth_sum / SMOOTHING_TICKS).tolist())
                settled = not np.any(np.abs(v) > 1e-6) and np.max(np.abs(window[0] - q_d)) < 1e-9
                if stopping and settled:
                    command.motion_finished = True
                    control.writeOnce(command)
                    return
                control.writeOnce(command)
        except Exception as exc:  # pylibfranka raises FrankaException subclasses; keep any for the report
            with self._lock:
                self._error = f"{type(exc).__name__}: {exc}"
            log.error("franka control loop ended: %s", self._error)

    # -- protocol ------------------------------------------------------------------------------------
    def read_state(self) -> JointState:
        with self._lock:
            return JointState(self._q.copy(), self._dq.copy(), self._stamp)

    def send_joint_command(self, q: np.ndarray) -> None:
        with self._lock:
            self._braking = False
            self._target = np.asarray(q, float).copy()

    def hold(self) -> None:
        with self._lock:
            self._braking = True

    def fault(self) -> str | None:
        with self._lock:
            return self._error

    def recover(self) -> bool:
        for attempt in range(1, self.config.franka.recover_attempts + 1):
            self._shutdown_loop()
            try:
                self.robot.automatic_error_recovery()
                self._start()
                return True
            except Exception as exc:
                log.warning("franka recovery attempt %d failed: %s", attempt, exc)
                with self._lock:
                    self._error = f"{type(exc).__name__}: {exc}"
        return False

    def reset(self, q_home: np.ndarray, seed: int | None, timeout_s: float = 20.0) -> None:
        """Drive home at the interpolator's limits and wait until there (``seed`` is for simulation)."""
        self.send_joint_command(q_home)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            state = self.read_state()
            if self.fault() is not None:
                raise RuntimeError(f"franka fault while going home: {self.fault()}")
            if np.max(np.abs(state.q - q_home)) < 1e-3 and np.max(np.abs(state.dq)) < 1e-2:
                return
            time.sleep(0.005)
        raise TimeoutError(f"franka did not reach home within {timeout_s} s")

    def step(self) -> None:
        """The arm moves on its own 1 kHz loop; the caller paces the control period."""

    def _shutdown_loop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def close(self) -> None:
        self._shutdown_loop()
        try:
            self.robot.stop()
        except Exception as exc:
            log.warning("franka stop on close: %s", exc)
