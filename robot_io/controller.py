"""The robot interface's core: one control period at a time, Cartesian action → safe joint command.

Used in-process by NS Reach and the benchmarks, and by deploy's robot-io node behind Zenoh, so both
paths run the same queue, IK and safety. Not thread-safe except ``push_chunk`` and the operator
commands, which only touch the queue and the safety flags under a lock; the control thread calls
``tick``.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.errors import AdaptiveHError
from common.throttle import EVENT_EVERY_S, Throttle
from robot_io.action_queue import UNLABELLED, ActionQueue, ChunkLabel, ChunkReport
from robot_io.backends import RobotBackend, make_backend
from robot_io.command_gate import CommandGate, TakeoverRefused, Verdict
from robot_io.config import RobotConfig
from robot_io.description import RobotDescription
from robot_io.ik import DifferentialIK
from robot_io.kinematics import Kinematics
from robot_io.recovery import RecoveryPolicy
from robot_io.safety import Safety, SafetyRecord
from robot_io.step_cap import cap_step_length

UNREACHABLE_M = 0.01  # IK ending this far from its goal with no progress means the goal is out of reach
STEP_TOLERANCE = 1e-9  # relative: a step capped to exactly max_step_m by the sender is not "above" it


class ArmHeld(AdaptiveHError, RuntimeError):
    """A motion was asked for (a reset) while the arm is e-stopped, paused, faulted or held."""


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
    tick: int = 0  # control ticks so far (a state read between ticks repeats the last one's)
    played_chunk: int = -1  # the chunk and index of the action this tick took from the queue; -1: none
    played_index: int = -1
    session: str = ""  # the learner session the arm obeys; chunk numbers above are that session's
    chunk_stamp: float = 0.0  # the send times of chunk_seq and played_chunk (with the numbers: exact)
    played_stamp: float = 0.0
    ee_cmd: np.ndarray = field(default_factory=lambda: np.zeros(3))  # the commanded TCP (ee_pos if none)


@dataclass
class TickResult:
    state: ArmState
    applied: np.ndarray | None = None  # the action executed this period, if any
    events: list[SafetyRecord] = field(default_factory=list)
    reports: list[ChunkReport] = field(default_factory=list)


class RobotController:
    def __init__(self, config: RobotConfig, backend: RobotBackend | None = None, world: Any = None) -> None:
        """``backend`` as given, or the configured one in ``world`` (``backends.make_backend``)."""
        self.config = config
        self.backend = backend if backend is not None else make_backend(config, world)
        self.kin = Kinematics(RobotDescription(config.model))
        self.home = np.asarray(config.home_q, float)
        self.queue = ActionQueue()
        self.gate = CommandGate(config.max_chunk_seq_gap)
        self._refusals = Throttle("refused", EVENT_EVERY_S)
        self.safety = Safety(config.workspace, config.watchdog_timeout_s)
        self.recovery = RecoveryPolicy(config.franka.auto_recover, config.franka.auto_recover_limit)
        self.box = (np.asarray(config.workspace.lo), np.asarray(config.workspace.hi))
        self.ik = DifferentialIK(
            config.ik,
            self.kin.description,
            config.velocity_scale,
            config.joint_margin_rad,
            self.home,
            self.box,
        )
        self._lock = threading.Lock()
        self._pending: list[str] = []  # operator commands, applied at the next tick
        self._jog: list[np.ndarray] = []
        self._unreachable = False
        self._braked = False
        self.ticks = 0
        self._played = (-1, -1, 0.0)  # (chunk, index, chunk stamp) taken by the last tick

    # -- called from other threads -------------------------------------------------------------------
    def plan_problem(self, actions: np.ndarray) -> str | None:
        """Why ``actions`` (N x 3) is not a playable plan, or None. A plan is refused whole, never
        trimmed or clipped: a learner that sends a 9 cm step or 10,000 actions has a bug, and playing
        part of what it meant would hide it."""
        actions = np.asarray(actions, float)
        if actions.ndim != 2 or actions.shape[1] != 3:
            return f"actions of shape {actions.shape}, not N x 3"
        if not len(actions):
            return "no actions (a plan has at least one; send zeros to stay put)"
        if len(actions) > self.config.max_plan_actions:
            limit = self.config.max_plan_actions
            return f"{len(actions)} actions, more than robot.max_plan_actions = {limit}"
        if not np.all(np.isfinite(actions)):
            return "contains NaN or inf"
        norms = np.linalg.norm(actions, axis=1)
        worst = int(np.argmax(norms))
        if norms[worst] > self.config.max_step_m * (1 + STEP_TOLERANCE):
            return (
                f"step {worst} moves {norms[worst]:.4f} m, above robot.max_step_m = {self.config.max_step_m}"
            )
        return None

    def refuse_plan(self, kind: str, detail: str) -> None:
        """A bad plan: nothing of it plays and the arm holds where it is. The rest of the current chunk
        is dropped (reported with ``preempted_by`` -1: no plan replaced it), because it is what the
        learner meant to replace; the chunk number, the watchdog and the safety mode do not change, so
        the next valid plan plays at once (and a learner that only sends bad plans is held by the
        watchdog)."""
        with self._lock:
            dropped = self.queue.clear()
            self.safety.report(kind, f"{detail}; refused whole, arm holds (dropped {dropped} queued)")

    def push_chunk(
        self,
        session: str,
        chunk_seq: int,
        actions: np.ndarray,
        now: float,
        stamp: float = 0.0,
        label: ChunkLabel = UNLABELLED,
    ) -> Verdict:
        """Queue a chunk of the obeyed session (preempting the rest of the current one). Refused, and
        reported as a ``foreign_command`` safety event, when the gate says it is not that session's next
        (``robot_io.command_gate``); refused whole as a bad plan; refused while held, bar the watchdog."""
        with self._lock:
            refusal = self.gate.check(session, chunk_seq)
            if refusal is not None:
                self._report_refusal(self.gate.describe(refusal, session, chunk_seq), now)
                return refusal
        problem = self.plan_problem(actions)
        if problem is not None:
            self.refuse_plan("bad_plan", f"chunk {chunk_seq}: {problem}")
            return "bad_plan"
        with self._lock:
            if not self.safety.accepts_commands():
                self.gate.admitted(chunk_seq)  # its number is used: a learner resending while held never
                return "held"  # runs more than the gap ahead, and a copy of this one is stale
            if self.gate.check(session, chunk_seq) is not None:  # a newer one got in while unlocked
                return "stale"
            if not self.queue.push(chunk_seq, actions, stamp, label):  # the gate admits only newer numbers
                raise AssertionError(f"queue refused chunk {chunk_seq} after {self.queue.chunk_seq}")
            self.gate.admitted(chunk_seq)
            self.safety.command_received(now)
            return "accepted"

    def report_refusal(self, detail: str, now: float) -> None:
        """A command not obeyed (stale, foreign, forged): one ``foreign_command`` event per window, so a
        flood of forgeries does not flood the operator (or the recording); the next event says how many
        were refused meanwhile."""
        with self._lock:
            self._report_refusal(detail, now)

    def _report_refusal(self, detail: str, now: float) -> None:
        shown = self._refusals.report(detail, now=now)
        if shown is not None:
            self.safety.report("foreign_command", shown)

    def learner_alive(self, session: str, alive: bool) -> None:
        """A learner session's liveliness token came or went (only a live session may take over)."""
        with self._lock:
            self.gate.alive(session, alive)

    def learner_confirmed_alive(self, session: str) -> None:
        """The network confirmed ``session``'s token before the subscriber announced it (a reset that
        outran the announcement); ignored when the subscriber has already seen it go."""
        with self._lock:
            self.gate.confirmed_alive(session)

    def learner_is_alive(self, session: str) -> bool:
        """Whether ``session``'s liveliness token has been seen and not lost."""
        with self._lock:
            return self.gate.is_alive(session)

    def obey(self, session: str) -> None:
        """In-process use (benchmarks, tests): the caller is the learner, alive by construction."""
        self.learner_alive(session, True)
        self.take_over(session)

    def take_over(self, session: str, next_seq: int = 0) -> None:
        """Obey ``session`` from now on (its chunks numbered from ``next_seq``); the rest of the previous
        session's chunk is dropped. Raises ``TakeoverRefused`` for a session without a live token."""
        with self._lock:
            try:
                previous = self.gate.take_over(session, next_seq)
            except TakeoverRefused as exc:
                self.safety.report("foreign_command", f"reset refused: {exc}")
                raise
            if previous == session:
                return
            dropped = self.queue.restart(session)
            was = repr(previous[:16]) if previous else "none"
            self.safety.report(
                "takeover", f"learner session {session[:16]!r} took over (was {was}; dropped {dropped})"
            )

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
        ee_pos, ee_vel = self.kin.ee_position_velocity(js.q, js.dq)
        ee_cmd = ee_pos if js.q_cmd is None else self.kin.ee_position(js.q_cmd)
        return ArmState(
            ee_cmd=ee_cmd,
            q=js.q,
            dq=js.dq,
            ee_pos=ee_pos,
            ee_vel=ee_vel,
            mode=self.safety.mode,
            chunk_seq=self.queue.chunk_seq,
            queue_len=len(self.queue),
            stamp=js.stamp,
            tick=self.ticks,
            played_chunk=self._played[0],
            played_index=self._played[1],
            session=self.queue.session,
            chunk_stamp=self.queue.chunk_stamp,
            played_stamp=self._played[2],
        )

    def _safety_pass(self, now: float) -> bool:
        """Apply operator commands, driver faults and the watchdog; True when the arm must brake now."""
        with self._lock:
            released = "release" in self._pending
            for command in self._pending:
                getattr(self.safety, command)()
            self._pending.clear()
        self._handle_fault(released)
        with self._lock:
            for held_back in self._refusals.overdue(now):
                self.safety.report("foreign_command", f"commands ignored: {held_back}")
            self.safety.check_watchdog(now, queue_empty=len(self.queue) == 0)
            if self.safety.may_move:
                self._braked = False
                return False
            self.queue.clear()
            brake = not self._braked or self.safety.mode == "estop"
            self._braked = True
            return brake

    def _handle_fault(self, released: bool) -> None:
        """A driver fault holds the arm (``driver_error``, mode ``fault``); recovery, tried on release
        or automatically (``RecoveryPolicy``), clears it. Recovery can take a reconnect, so it runs
        outside the lock: e-stops and chunks are not blocked meanwhile."""
        fault = self.backend.fault()
        with self._lock:
            new = fault is not None and self.safety.hold("driver_error", str(fault))
            held = "driver_error" in self.safety.reasons
            if new:
                self.queue.clear()
        why = self.recovery.reason(fault, new, released, held)
        if why is None:
            return
        ok = self.backend.recover()
        with self._lock:
            if ok:
                self.safety.clear("driver_error", why)
            else:
                what = why.split(":")[0]
                self.safety.report("driver_error", f"{what}: recovery failed, the arm stays held")

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
            played = self.queue.take() if self.safety.may_move else None
            if played is not None:
                self.safety.command_received(now)
            # Taken under the same lock as the pop: a chunk arriving later does not change what ran.
            self._played = (
                (played.chunk_seq, played.index, played.chunk_stamp) if played is not None else (-1, -1, 0.0)
            )
            self.ticks += 1
            paused = self.safety.mode == "paused"
        applied = None
        if braking:
            self.backend.hold()
        elif played is not None:
            applied = self._execute(played.action)
        elif jogs and paused:
            for jog in jogs:
                applied = self._execute(jog)
        if applied is not None and self._held_meanwhile(played is not None):
            self.backend.hold()  # an e-stop (or lost learner) came in since the check: brake this tick too
            applied = None
        self.backend.step()
        with self._lock:
            return TickResult(self.state(), applied, self.safety.drain(), self.queue.reports())

    def _held_meanwhile(self, chunk_action: bool) -> bool:
        """A hold that arrived during this tick, after its safety pass: an e-stop stops a jog too, any hold
        stops a learner's action, which then counts as not played."""
        with self._lock:
            held = self.safety.mode == "estop" or (chunk_action and not self.safety.may_move)
            if held and chunk_action:
                self._played = (-1, -1, 0.0)
            return held

    def step_action(self, action: np.ndarray) -> TickResult:
        """In-process use (NS Reach, benchmarks): execute one action now and advance one period."""
        applied = self._execute(np.asarray(action, float)) if self.safety.may_move else None
        self.backend.step()
        return TickResult(self.state(), applied, self.safety.drain(), [])

    def _anchor(self, q: np.ndarray, q_cmd: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where this period's action starts (configuration and end effector), and the measured end
        effector. The commanded configuration while it leads the measured arm by at most a lead and a
        step (the action moves the commanded end effector, as on any position-controlled arm, so a
        lagging arm's command keeps going the way it went); else the measured one (the arm was pushed
        off its command)."""
        ee = self.kin.ee_position(q)
        if q_cmd is None:
            return q, ee, ee
        ee_cmd = self.kin.ee_position(q_cmd)
        if float(np.linalg.norm(ee_cmd - ee)) <= self.config.command_lead_m + self.config.max_step_m:
            return q_cmd, ee_cmd, ee
        return q, ee, ee

    def _goal(self, ee0: np.ndarray, ee_measured: np.ndarray, action: np.ndarray) -> np.ndarray:
        """``ee0 + action``, held within ``command_lead_m`` of the measured end effector (a slow arm's
        command never runs away from it, and a blocked arm stops it), clipped into
        the workspace box. Leading by a bounded amount, instead of re-anchoring on the measured arm when the
        command got ahead, keeps the command monotone: re-anchoring made it jump back and forth a step
        each period on franky-sim, and the arm hardly moved (docs/robot_interface.md)."""
        goal = ee0 + action
        lead = goal - ee_measured
        norm = float(np.linalg.norm(lead))
        if norm > self.config.command_lead_m:
            goal = ee_measured + lead * (self.config.command_lead_m / norm)
        return self.safety.clip_goal(goal)

    def _execute(self, action: np.ndarray) -> np.ndarray:
        """Displace the end-effector goal by ``action`` (≤ max_step_m), clip, solve IK, check, send."""
        action = cap_step_length(np.asarray(action, float).reshape(3), self.config.max_step_m)
        js = self.backend.read_state()
        q0, ee0, ee_measured = self._anchor(js.q, js.q_cmd)
        goal = self._goal(ee0, ee_measured, action)
        start_error = float(np.linalg.norm(ee0 - goal))
        result = self.ik.solve(q0, goal, self.config.period)
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
            q0,
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

    def reset(
        self,
        seed: int | None = None,
        clock: Callable[[], float] | None = None,
        while_homing: Callable[[ArmState], None] | None = None,
    ) -> ArmState:
        """Home pose and (in simulation) a new target motion; clears the queue and the watchdog. Refused
        with ``ArmHeld`` while the operator or a fault holds the arm: homing is a motion too.

        ``clock`` (the control loop's): the reset counts as a command when homing is done, so the watchdog
        holds the arm if no chunk follows within its timeout (a commander that went quiet after homing,
        e.g. waiting for a target); without it the watchdog waits for the first chunk. ``while_homing``:
        called with the arm's state about once a period while a real arm moves home."""
        with self._lock:
            if not self.safety.accepts_commands():
                held = ", ".join(sorted(self.safety.reasons - {"watchdog"}))
                raise ArmHeld(f"the arm is held ({held}): no reset until it is released")
            self.queue.clear()
            self._played = (-1, -1, 0.0)
            self.safety.clear("watchdog", "reset")
            self.safety.last_command = None
        moving = None if while_homing is None else (lambda: while_homing(self.state()))
        self.backend.reset(self.home, seed, moving)
        if clock is not None:
            with self._lock:
                self.safety.last_command = clock()
        self._unreachable = False
        return self.state()

    def close(self) -> None:
        self.backend.close()
