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

``hold()`` preempts with a braking waypoint at ``HOLD_DYNAMICS`` of the arm's dynamic limits
(``JOINT_DYNAMICS_LIMITS``, set at connect; jerk-limited, with a margin for lost cycles, so a hold
does not trip a discontinuity reflex) and keeps commanding that position until the next command. A
reflex, a rejected command or a lost connection ends franky's motion with an exception, which
``fault()`` reports as a ``Fault`` until ``recover()`` runs
libfranka's automatic error recovery, or reconnects when the connection was lost (a dead libfranka
connection cannot be reused). Connecting verifies the arm against ``robot.model``
(``franky_model.verify_model``). franky is imported here only, so the stack runs without it.

Scheduling: libfranka raises the thread that *constructs* its Robot to the highest SCHED_FIFO priority
(whenever the OS allows it; ``realtime: enforce`` only makes a refusal fatal), expecting to run the 1 kHz
loop from it. franky runs that loop in a thread of its own, started by whichever thread calls ``move``
and inheriting that thread's scheduling. So the connecting thread is put back as it was (otherwise
robot-io's Python and Zenoh threads, started from it later, ran at FIFO 99, above and beside the 1 kHz
loop: measured on franka-sim, lost cycles and discontinuity reflexes), and the priority libfranka
obtained is held only around ``move``, so a 1 kHz thread it starts inherits it.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import os
import time
from collections.abc import Callable, Iterator
from types import ModuleType
from typing import Any

import numpy as np

from common.config import ConfigError
from robot_io.backends.franky_model import (
    ModelMismatch,
    libfranka_version,
    server_version_for,
    verify_model,
)
from robot_io.backends.memory_lock import MemoryLockError, lock_memory
from robot_io.backends.protocol import Fault, JointState
from robot_io.config import RobotConfig
from robot_io.description import RobotDescription

log = logging.getLogger(__name__)

CONNECTION_LOST = "connection_lost"
# The joint acceleration (rad/s^2) and jerk (rad/s^3) limits of each arm's FCI: a commanded motion past
# them ends in a *_discontinuity reflex. franky starts with the Panda's (libfranka's FER rate limits)
# whatever arm it connects to; the FR3's are lower on most joints (10 and 5000 on every joint, its
# datasheet's and what franka-sim enforces). Set at connect from robot.model.
JOINT_DYNAMICS_LIMITS = {
    "panda": (
        (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0),
        (7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0),
    ),
    "fr3": ((10.0,) * 7, (5000.0,) * 7),
}
# A hold brakes at these fractions of those limits (velocity, acceleration, jerk). The FCI judges the
# commands it receives by differencing them (sent as float32: ~0.5 rad/s^2 of rounding at q ~ 2 rad),
# and a command that misses its 1 ms cycle is replaced by a constant-acceleration extrapolation, so the
# next one reads up to about twice the planned jerk: braking at 0.9 of the FR3's jerk limit tripped
# jerk reflexes on franka-sim after single lost cycles. A lost cycle while decelerating hard reads as a
# velocity step too (franky extrapolates from the robot's reported dq_d/ddq_d): with 3 busy loops beside
# franka-sim, braking at 0.8 of the acceleration limit ended 6 of 100 brakes in a reflex, at 0.4 none
# (bench/franka_sim_brakes.py --burn 3). 0.4 (4 rad/s^2 on an FR3) still stills a 0.2 rad/s joint within
# two control periods; the jerk is franka.dynamics' default.
HOLD_DYNAMICS = (1.0, 0.4, 0.3)
AT_REST_RAD_S = 1e-3


def _scheduling() -> tuple[int, int] | None:
    """This thread's scheduling policy and priority (None where the OS has no such call)."""
    if not hasattr(os, "sched_getscheduler"):
        return None
    return os.sched_getscheduler(0), os.sched_getparam(0).sched_priority


def _set_scheduling(scheduling: tuple[int, int] | None) -> None:
    if scheduling is not None:
        os.sched_setscheduler(0, scheduling[0], os.sched_param(scheduling[1]))


class FrankyBackend:
    name = "franka"

    def __init__(
        self,
        config: RobotConfig,
        description: RobotDescription | None = None,
        lib: ModuleType | None = None,
        target: Any = None,
    ) -> None:
        """``target``: the scripted target ``franka.simulated_target`` asks for (franky-sim's world has none
        a camera sees; ``tasks.sim_world.ScriptedTarget``), stepped with the arm."""
        self.config = config
        self.fc = config.franka
        self.franky = lib if lib is not None else importlib.import_module("franky")
        self.description = description or RobotDescription(config.model)
        limits = self.description.limits
        self.lower = limits.lower + config.joint_margin_rad
        self.upper = limits.upper - config.joint_margin_rad
        self.period_ms = max(1, round(config.period * 1000))
        # Each motion carries its own dynamics factor (the robot-wide one stays 1), so a hold's braking
        # never carries over into the next motion.
        factor = self.franky.RelativeDynamicsFactor
        self._stream_dynamics = factor(*self.fc.dynamics)
        self._hold_dynamics = factor(*HOLD_DYNAMICS)
        self._home_dynamics = factor(*(self.fc.home_dynamics * d for d in self.fc.dynamics))
        if self.fc.simulated_target and target is None:
            raise ConfigError(
                "robot.franka.simulated_target needs a scripted target: build the controller with "
                "tasks.sim_world.robot_world(config) as its world"
            )
        self.scene = target if self.fc.simulated_target else None
        if self.fc.lock_memory:  # once: the lock holds for the process, reconnects included
            self._lock_memory()
        self.robot: Any = None
        self._loop_scheduling: tuple[int, int] | None = None
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
        before = _scheduling()
        try:
            robot = f.Robot(self.fc.ip, realtime_config=realtime)
            after = _scheduling()
        finally:
            _set_scheduling(before)  # libfranka raised this thread; the priority is for the 1 kHz loop
        self._loop_scheduling = after if after is not None and after != before else None
        lib = libfranka_version()
        self.report = verify_model(robot, f, self.description, server_version_for(lib) if lib else None)
        acceleration, jerk = JOINT_DYNAMICS_LIMITS[self.description.model.name]
        for limit, ours in ((robot.joint_acceleration_limit, acceleration), (robot.joint_jerk_limit, jerk)):
            limit.set(np.minimum(np.asarray(limit.max, float), ours))  # franky refuses more than its max
        robot.relative_dynamics_factor = f.RelativeDynamicsFactor(1.0, 1.0, 1.0)  # each motion has its own
        robot.set_collision_behavior(
            list(self.fc.lower_torque_thresholds),
            list(self.fc.upper_torque_thresholds),
            list(self.fc.lower_force_thresholds),
            list(self.fc.upper_force_thresholds),
        )
        robot.set_joint_impedance(list(self.fc.joint_impedance))
        self._vmax = np.asarray(robot.joint_velocity_limit.get(), float)
        self.robot = robot
        self._q = np.asarray(robot.current_joint_state.position, float)
        self._last_target = None
        self._stopping = True
        log.info("franky connected to %s (%s): %s", self.fc.ip, self.description.model.name, self.report)

    def _lock_memory(self) -> None:
        try:
            lock_memory()
            log.info("memory locked (mlockall): no page fault stalls the 1 kHz loop")
        except MemoryLockError as exc:
            if self.fc.realtime == "enforce":
                raise
            log.warning("memory not locked (realtime: ignore, going on): %s", exc)

    def _set_fault(self, exc: BaseException) -> None:
        """Name what stopped the arm: libfranka's error flags, or a lost connection."""
        if self._fault is not None:
            return
        self._stopping = True  # the reflex (or lost link) ended our motion: no command runs, none to brake
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

    @contextlib.contextmanager
    def _loop_priority(self) -> Iterator[None]:
        """Around ``move``: the scheduling libfranka obtained, for a 1 kHz thread ``move`` may start."""
        before = _scheduling() if self._loop_scheduling is not None else None
        if before is not None:
            try:
                _set_scheduling(self._loop_scheduling)
            except OSError as exc:  # no longer permitted: the loop runs at this thread's priority
                log.warning("franka: cannot raise the 1 kHz loop's priority: %s", exc)
                before = self._loop_scheduling = None
        try:
            yield
        finally:
            if before is not None:
                _set_scheduling(before)

    def _move(self, motion: Any) -> None:
        try:
            with self._loop_priority():
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
            # Within the velocity limit the waypoint is planned with: Ruckig refuses a faster target (a
            # planner error ends the motion), e.g. when the controller re-anchors on the measured arm.
            vmax = self._vmax * self.fc.dynamics[0]
            v = np.clip((q - self._last_target) / self.config.period, -vmax, vmax)
            coast = np.clip(q + v * self.config.period, self.lower, self.upper)
            waypoints = [
                f.JointWaypoint(f.JointState(q, v), minimum_time=f.Duration(self.period_ms)),
                f.JointWaypoint(f.JointState(coast)),
            ]
        self._last_target = q.copy()
        self._stopping = False
        self._move(f.JointWaypointMotion(waypoints, self._stream_dynamics))

    def hold(self) -> None:
        """Brake to rest where the *command* can stop at full deceleration. franky's JointStopMotion
        would head back to the measured position, which lags the command while moving (a reversal)."""
        self._last_target = None
        if self._fault is not None or self._stopping:
            return
        self._stopping = True
        try:
            state = self.robot.state
            amax = HOLD_DYNAMICS[1] * np.asarray(self.robot.joint_acceleration_limit.get(), float)
            jmax = HOLD_DYNAMICS[2] * np.asarray(self.robot.joint_jerk_limit.get(), float)
        except Exception as exc:
            self._set_fault(exc)
            return
        q_d, dq_d, ddq_d = (np.asarray(x, float) for x in (state.q_d, state.dq_d, state.ddq_d))
        # One braking time for all joints, as franky's time-synchronized profile has: the longest
        # jerk-limited stop (full deceleration, the ramps to and from it, and undoing the present
        # acceleration). Each joint's stop point is then where decelerating over that time takes it; a
        # per-joint point that a longer synchronized profile reaches early makes Ruckig overshoot it and
        # come back.
        duration = np.max(np.abs(dq_d) / amax + amax / jmax + np.abs(ddq_d) / jmax)
        stop = np.clip(q_d + dq_d * duration / 2, self.lower, self.upper)
        self._hold_at(stop)

    def _hold_at(self, q: np.ndarray) -> None:
        """Go to ``q`` and keep commanding it (the motion never ends by itself), so a held arm stays
        under position control rather than idle; the next command preempts it."""
        f = self.franky
        self._move(f.JointWaypointMotion([f.JointWaypoint(f.JointState(q))], self._hold_dynamics, False))

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

    def reset(
        self,
        q_home: np.ndarray,
        seed: int | None,
        while_moving: Callable[[], None] | None = None,
        timeout_s: float = 30.0,
    ) -> None:
        """Brake to rest, then move home point to point at ``franka.home_dynamics`` and wait there
        (``while_moving`` about once a control period); a fault raises.

        The braking comes first: the move home starts from the arm's motion at its own, gentler dynamics,
        and from a hand heading down it ran the hand onto the table (docs/howto/real_arm.md)."""
        if self.scene is not None:
            self.scene.reset(seed)
        if self.fault() is not None:
            raise RuntimeError(f"franka fault, release to recover first: {self._fault}")
        f = self.franky
        home = f.JointWaypoint(f.JointState(np.asarray(q_home, float)))
        deadline = time.monotonic() + timeout_s
        self.hold()
        if self._fault is not None:
            raise RuntimeError(f"franka fault while braking to go home: {self._fault}")
        self._last_target = None
        self._stopping = True
        try:
            self._wait(deadline, "come to rest", while_moving, until=self._at_rest)
            with self._loop_priority():
                self.robot.move(f.JointWaypointMotion([home], self._home_dynamics), asynchronous=True)
            self._wait(deadline, "reach home", while_moving, until=lambda: self.robot.join_motion(timeout=0))
            self._hold_at(np.asarray(q_home, float))
        except TimeoutError:
            raise
        except Exception as exc:
            self._set_fault(exc)
            raise RuntimeError(f"franka fault while going home: {self._fault}") from exc

    def _at_rest(self) -> bool:
        """The commanded motion has stopped (the hold's, which never ends by itself)."""
        return float(np.max(np.abs(np.asarray(self.robot.state.dq_d, float)))) < AT_REST_RAD_S

    def _wait(
        self, deadline: float, what: str, while_moving: Callable[[], None] | None, until: Callable[[], bool]
    ) -> None:
        """Poll ``until`` once a control period, calling ``while_moving`` meanwhile; past ``deadline`` a
        ``TimeoutError`` names ``what`` the arm did not do."""
        while not until():
            if time.monotonic() > deadline:
                raise TimeoutError(f"franka did not {what} in time")
            if while_moving is not None:
                while_moving()
            time.sleep(self.config.period)

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
