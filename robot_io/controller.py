"""The robot interface's core: one control period at a time, Cartesian action → safe joint command.

Used in-process by NS Reach and the benchmarks, and by deploy's robot-io node behind Zenoh, so both
paths run the same queue, IK and safety. Not thread-safe except ``push_chunk`` and the operator
commands, which only touch the queue and the safety flags under a lock; the control thread calls
``tick``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from robot_io.action_queue import ActionQueue, ChunkReport
from robot_io.backends import RobotBackend, make_backend
from robot_io.config import RobotConfig
from robot_io.ik import DifferentialIK
from robot_io.kinematics import Kinematics
from robot_io.safety import Safety, SafetyRecord

UNREACHABLE_M = 0.01  # IK ending this far from its goal with no progress means the goal is out of reach


@dataclass(frozen=True)
class ArmState:
    q: np.ndarray
    dq: np.ndarray
    ee_pos: np.ndarray
    ee_vel: np.ndarray
    mode: str
    chunk_seq: int
    queue_len: int
    stamp: float


@dataclass
class TickResult:
    state: ArmState
    applied: np.ndarray | None = None  # the action executed this period, if any
    events: list[SafetyRecord] = field(default_factory=list)
    reports: list[ChunkReport] = field(default_factory=list)


class RobotController:
    def __init__(self, config: RobotConfig, backend: RobotBackend | None = None) -> None:
        self.config = config
        self.backend = backend if backend is not None else make_backend(config)
        self.kin = Kinematics()
        self.home = np.asarray(config.home_q, float)
        self.ik = DifferentialIK(
            config.ik, self.kin.description, config.velocity_scale, config.joint_margin_rad, self.home
        )
        self.queue = ActionQueue()
        self.safety = Safety(config.workspace, config.watchdog_timeout_s)
        self.box = (np.asarray(config.workspace.lo), np.asarray(config.workspace.hi))
        self._lock = threading.Lock()
        self._pending: list[str] = []  # operator commands, applied at the next tick
        self._jog: list[np.ndarray] = []
        self._unreachable = False
        self._braked = False

    # -- called from other threads -------------------------------------------------------------------
    def push_chunk(self, chunk_seq: int, actions: np.ndarray, now: float) -> bool:
        """Queue a chunk (preempting the rest of the current one); refused while held, bar the watchdog."""
        with self._lock:
            if not self.safety.accepts_commands():
                return False
            accepted = self.queue.push(chunk_seq, actions)
            if accepted:
                self.safety.command_received(now)
            return accepted

    def operator(self, command: str, jog: np.ndarray | None = None) -> None:
        """pause | resume | estop | release | jog, from the monitor; e-stop also acts at once."""
        if command not in ("pause", "resume", "estop", "release", "jog"):
            raise ValueError(f"unknown operator command {command!r}")
        with self._lock:
            if command == "jog":
                self._jog.append(np.asarray(jog, float))
            elif command == "estop":
                self.safety.estop()
                self.queue.clear()
            else:
                self._pending.append(command)

    def peer_lost(self, peer: str) -> None:
        with self._lock:
            if self.safety.hold("liveliness", f"liveliness token of {peer} disappeared"):
                self.queue.clear()

    def peer_back(self, peer: str) -> None:
        with self._lock:
            self.safety.clear("liveliness", f"{peer} is back")

    # -- control thread ------------------------------------------------------------------------------
    def state(self) -> ArmState:
        js = self.backend.read_state()
        return ArmState(
            q=js.q,
            dq=js.dq,
            ee_pos=self.kin.ee_position(js.q),
            ee_vel=self.kin.ee_velocity(js.q, js.dq),
            mode=self.safety.mode,
            chunk_seq=self.queue.chunk_seq,
            queue_len=len(self.queue),
            stamp=js.stamp,
        )

    def _safety_pass(self, now: float) -> bool:
        """Apply operator commands, driver faults and the watchdog; True when the arm must brake now."""
        with self._lock:
            for command in self._pending:
                getattr(self.safety, command)()
            self._pending.clear()
            fault = self.backend.fault()
            if fault is not None:
                self.safety.hold("driver_error", fault)
            self.safety.check_watchdog(now, queue_empty=len(self.queue) == 0)
            if self.safety.may_move:
                self._braked = False
                return False
            self.queue.clear()
            brake = not self._braked or self.safety.mode == "estop"
            self._braked = True
            return brake

    def react(self, now: float) -> TickResult:
        """Apply holds at once (between ticks, e.g. on an e-stop) without advancing the period."""
        if self._safety_pass(now):
            self.backend.hold()
        with self._lock:
            return TickResult(self.state(), None, self.safety.drain(), self.queue.reports())

    def tick(self, now: float) -> TickResult:
        """One control period: safety first, then the next queued action (or a jog while paused)."""
        braking = self._safety_pass(now)
        with self._lock:
            jogs, self._jog = self._jog, []
            action = self.queue.pop() if self.safety.may_move else None
            if action is not None:
                self.safety.command_received(now)
            paused = self.safety.mode == "paused"
        applied = None
        if braking:
            self.backend.hold()
        elif action is not None:
            applied = self._execute(action)
        elif jogs and paused:
            for jog in jogs:
                applied = self._execute(jog)
        self.backend.step()
        with self._lock:
            return TickResult(self.state(), applied, self.safety.drain(), self.queue.reports())

    def step_action(self, action: np.ndarray) -> TickResult:
        """In-process use (NS Reach, benchmarks): execute one action now and advance one period."""
        applied = self._execute(np.asarray(action, float)) if self.safety.may_move else None
        self.backend.step()
        return TickResult(self.state(), applied, self.safety.drain(), [])

    def _execute(self, action: np.ndarray) -> np.ndarray:
        """Displace the end-effector goal by ``action`` (≤ max_step_m), clip, solve IK, check, send."""
        action = np.asarray(action, float).reshape(3)
        norm = float(np.linalg.norm(action))
        if norm > self.config.max_step_m:
            action = action * (self.config.max_step_m / norm)
        js = self.backend.read_state()
        goal = self.safety.clip_goal(self.kin.ee_position(js.q) + action)
        start_error = float(np.linalg.norm(self.kin.ee_position(js.q) - goal))
        result = self.ik.solve(js.q, goal, self.config.period)
        # Out of reach: the QP ends far from the goal and cannot get any closer (limits are active).
        stalled = result.error > UNREACHABLE_M and start_error - result.error < 1e-3
        if stalled and not self._unreachable:
            self.safety.report(
                "ik_unreachable",
                f"goal {np.round(goal, 3).tolist()} out of reach; moving to the closest point",
            )
        self._unreachable = stalled
        check = self.kin.check(
            result.q,
            js.q,
            self.config.period,
            self.config.joint_margin_rad,
            self.config.velocity_scale,
            self.box,
        )
        if not check.ok:
            self.safety.report(check.kind, f"command refused: {check.detail}")
            self.backend.hold()
            return np.zeros(3)
        self.backend.send_joint_command(result.q)
        return action

    def reset(self, seed: int | None = None) -> ArmState:
        """Home pose and (in simulation) a new target motion; clears the queue and the watchdog."""
        with self._lock:
            self.queue.clear()
            self.safety.last_command = None
            self.safety.clear("watchdog", "reset")
        self.backend.reset(self.home, seed)
        self._unreachable = False
        return self.state()

    def close(self) -> None:
        self.backend.close()
