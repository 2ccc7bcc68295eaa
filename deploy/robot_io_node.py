"""The robot-interface process: robot_io's controller behind Zenoh.

It ticks the controller at the control rate and publishes ``state`` every tick (with the tick's number
and which chunk action it played), ``cmd/status`` for every chunk change (executed, dropped,
preempted_by) and ``events/safety`` for every intervention. It takes ``cmd/chunk`` and ``control``,
answers ``reset``, declares ``alive/robot_io`` and holds the arm while a watched peer's liveliness
token (the learner's, by default) is gone. Physics (pybullet) and IK run on the control thread only;
Zenoh callbacks just queue work for it, and an e-stop wakes it at once.

Commands are obeyed from one learner session at a time (``robot_io.command_gate``): a reset naming a
session whose token ``alive/learner/<session>`` is alive takes the arm over; chunks of other sessions,
stale or implausibly numbered ones are refused (``foreign_command`` event, a ``cmd/status`` with the
verdict, so the sender knows), and so is a reset from a session without a live token. States and
statuses name the session, so a learner's acknowledgements are exactly its own.

A chunk is a plan and is refused whole when it is malformed: bytes that do not decode (NaN, a length
that is not a multiple of 3: ``bad_message``) or a decoded plan that breaks the robot's rules (empty,
longer than ``robot.max_plan_actions``, a step above ``robot.max_step_m``, a predicted path of another
length: ``bad_plan``). Nothing of it plays and the arm holds where it is; see
``RobotController.refuse_plan`` for what changes and what does not.
"""

from __future__ import annotations

import logging
import os
import secrets
import threading
import time
from collections.abc import Callable

import numpy as np

from bus import messages as m
from bus.learner_session import SESSIONS
from bus.node import Node
from bus.signing import ForgedMessage, Fresh, authentic
from common.throttle import EVENT_EVERY_S, Throttle
from deploy.config import StackConfig
from robot_io.action_queue import ChunkLabel
from robot_io.command_gate import TakeoverRefused
from robot_io.config import RobotConfig
from robot_io.controller import ArmHeld, ArmState, RobotController, TickResult

log = logging.getLogger(__name__)
LIVELINESS_QUERY_S = 1.0  # how long a reset waits for the network to confirm its session's token


def robot_state_message(s: ArmState, instance: str, stamp: float = 0.0) -> m.RobotState:
    """The state message of ``s`` from robot-io ``instance``; a publisher stamps it when it is put, a
    reset reply with ``stamp``."""
    return m.RobotState(
        instance=instance,
        stamp=stamp,
        q=s.q.tolist(),
        dq=s.dq.tolist(),
        ee_pos=s.ee_pos.tolist(),
        ee_vel=s.ee_vel.tolist(),
        ee_cmd=s.ee_cmd.tolist(),
        mode=m.enum(m.RobotState, "mode", s.mode),
        chunk_seq=s.chunk_seq,
        queue_len=s.queue_len,
        tick=s.tick,
        played_chunk=s.played_chunk,
        played_index=s.played_index,
        session=s.session,
        chunk_stamp=s.chunk_stamp,
        played_stamp=s.played_stamp,
    )


def prioritize_this_thread(nice: int) -> None:
    """Ask Linux for ``nice`` on the calling thread (its own task); a refusal is logged, once, as what it
    costs: under CPU contention the control loop then waits its turn like any other thread."""
    if not nice or not hasattr(os, "setpriority") or not hasattr(threading, "get_native_id"):
        return
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), nice)
    except OSError as exc:
        log.warning(
            "robot-io's control thread keeps its priority (robot.control_thread_nice %d refused: %s); grant"
            " CAP_SYS_NICE for real arms, or ticks may come late when the CPU is busy",
            nice,
            exc,
        )


def _controller(robot: RobotConfig) -> RobotController:
    """The controller in its simulated world when the config has one (the mock arm, franky-sim's scripted
    target): robot-io on a real arm never imports the simulator."""
    if not robot.simulated:
        return RobotController(robot)
    from tasks.sim_world import robot_controller

    return robot_controller(robot)


class RobotIONode(Node):
    """Run with ``start()``/``stop()`` (or as a context manager); the control loop is its one worker."""

    alive_as = "robot_io"

    def __init__(
        self,
        settings: StackConfig,
        controller: RobotController | None = None,
        watch_peers: tuple[str, ...] = ("learner",),
        control_token: str = "",
    ) -> None:
        self.settings = settings
        self.controller = controller or _controller(settings.robot)
        self.period = settings.robot.period
        self.instance = secrets.token_hex(6)  # RobotState.instance: this process, not the one before it
        self.watch_peers = watch_peers
        self._fresh_reset, self._fresh_control = Fresh(), Fresh()
        self._bad_events = Throttle("bad messages", EVENT_EVERY_S)
        super().__init__(settings.bus_key, settings.zenoh, token=control_token, fleet=settings.name)
        self.mac_key = self.bus.signing_key  # with a token, only signed chunks, resets and controls
        self._pub_state = self.bus.publisher(m.STATE)
        self._pub_status = self.bus.publisher(m.CHUNK_STATUS)
        self._pub_safety = self.bus.publisher(m.EVENTS_SAFETY)
        self._pub_truth = self.bus.publisher(m.TARGET_TRUTH) if self.scene is not None else None
        self._wake = threading.Event()
        self._resets: list[tuple[m.ResetRequest, threading.Event, list[m.ResetReply]]] = []
        self._lock = threading.Lock()
        self.ticks = 0
        # Judged here, not by the bus: a forged chunk gets its verdict, an e-stop is obeyed from anyone.
        self.bus.subscribe(m.CMD_CHUNK, self._on_chunk, on_bad=self._on_bad, verify=False)
        arm = settings.arm or ""
        self.bus.subscribe(m.CONTROL, lambda c: self._on_control(c, arm), on_bad=self._on_bad, verify=False)
        if arm:  # an arm of a fleet also obeys the fleet's (E-STOP all)
            self.bus.subscribe(
                m.FLEET_CONTROL, lambda c: self._on_control(c, ""), on_bad=self._on_bad, verify=False
            )
        self.bus.queryable(m.RESET, self._on_reset)
        self.bus.watch_alive(self._on_alive)
        self.bus.watch_alive(self.controller.learner_alive, below=SESSIONS)
        self.declare_alive()

    @property
    def scene(self):
        """The PyBullet scene when the backend is the mock (its target is published as ground truth)."""
        return getattr(self.controller.backend, "scene", None)

    # -- Zenoh callbacks (Zenoh threads) -------------------------------------------------------------
    def _on_bad(self, topic: str, exc: Exception, data: bytes = b"") -> None:
        # A stop request is obeyed whatever else is wrong with it (fields, session, signature).
        if topic == m.CONTROL.name and m.says_estop(data):
            self.controller.operator("estop", np.zeros(3))
            self._wake.set()
        # A plan that does not even decode: refused whole, the arm holds. Not with a token: bytes that do
        # not decode cannot be shown to be the learner's, and a stranger's must not stop its plan.
        if topic == m.CMD_CHUNK.name and self.mac_key is None:
            self.controller.refuse_plan("bad_message", f"{topic}: {exc}")
            self._wake.set()  # the control thread publishes the event and the dropped rest at once
            return
        detail = self._bad_events.report(f"{topic}: {exc}")  # a flood must not flood
        if detail is not None:
            self._publish_safety("bad_message", detail, self.controller.safety.mode != "running")

    def _on_chunk(self, msg: m.ActionChunk) -> None:
        actions = m.action_array(msg)
        if self.mac_key is not None and not authentic(msg, self.mac_key):
            detail = f"chunk {msg.seq} of session {msg.session[:16]!r}: not signed with the stack's token"
            self.controller.report_refusal(detail, time.monotonic())
            outcome = "forged"
        elif msg.predicted_ee and len(msg.predicted_ee) != len(msg.actions):
            n_pred = len(msg.predicted_ee) // 3
            self.controller.refuse_plan(
                "bad_plan", f"chunk {msg.seq}: {n_pred} predicted positions for {len(actions)} actions"
            )
            outcome = "bad_plan"
        else:
            label = ChunkLabel(msg.segment, msg.opened_by)
            outcome = self.controller.push_chunk(
                msg.session, msg.seq, actions, time.monotonic(), msg.stamp, label
            )
        if outcome == "accepted":
            return
        self._wake.set()  # the control thread publishes the safety event (and a bad plan's dropped rest)
        log.info("chunk %d not played: %s (mode %s)", msg.seq, outcome, self.controller.safety.mode)
        self._pub_status(
            m.ChunkStatus(
                chunk_seq=msg.seq,
                executed=0,
                dropped=len(actions),
                preempted_by=-1,  # refused, not preempted (0 would name the session's first chunk)
                done=True,
                session=msg.session,
                verdict=m.enum(m.ChunkStatus, "verdict", outcome),
                chunk_stamp=msg.stamp,
                segment=msg.segment,
                opened_by=msg.opened_by,
                preempted_by_opening=m.ActionChunk.NONE,
            )
        )

    def _on_control(self, msg: m.Control, key_arm: str) -> None:
        """An operator's command that came on the control key of ``key_arm`` ("": the fleet's, or a stack's
        only arm's)."""
        command = m.label(msg, "command")
        # An e-stop is always obeyed; everything else needs the operator token when one is set.
        if command != "estop" and self.mac_key is not None:
            why = "not signed with the stack's key" if not authentic(msg, self.mac_key) else ""
            if not why and msg.arm != key_arm:
                why = f"signed for arm {msg.arm!r}, come on {key_arm or 'the fleet'!r}'s key (a replay)"
            if not why and not self._fresh_control(msg.stamp):
                why = "not newer than the last one obeyed (a replay)"
            if why:
                refusal = ForgedMessage(f"control {command}: {why}", msg)
                self.bus.report_bad(m.CONTROL.name, refusal)
                self._on_bad(m.CONTROL.name, refusal)
                return
        self.controller.operator(command, np.asarray(msg.jog))
        self._wake.set()

    def _on_alive(self, name: str, alive: bool) -> None:
        if name not in self.watch_peers:
            return
        if alive:
            self.controller.peer_back(name)
        else:
            self.controller.peer_lost(name)
        self._wake.set()

    def _on_reset(self, request: m.ResetRequest) -> m.ResetReply:
        if self.mac_key is not None:  # a reset moves the arm home: only a fresh, signed request
            why = "not signed with the stack's key" if not authentic(request, self.mac_key) else ""
            if not why and not self._fresh_reset(request.stamp):
                why = "not newer than the last reset (a replay)"
            if why:
                self.controller.report_refusal(
                    f"reset of session {request.session[:16]!r}: {why}", time.monotonic()
                )
                self._wake.set()
                return m.ResetReply(ok=False, detail=f"reset refused: {why}")
        self._confirm_alive(request.session)
        done, box = threading.Event(), []
        with self._lock:
            self._resets.append((request, done, box))
        self._wake.set()
        if not done.wait(timeout=30.0):
            return m.ResetReply(ok=False, detail="reset timed out")
        return box[0]

    def _confirm_alive(self, session: str) -> None:
        """A new learner's reset can arrive before its token's announcement does (measured: under load,
        the first reset was refused as a forgery). Before the gate judges a session it has not seen
        alive, ask the network whether that token exists now; a session without one is still refused."""
        if not session or self.controller.learner_is_alive(session):
            return
        try:
            alive = self.bus.alive_now(f"{SESSIONS}/{session}", timeout=LIVELINESS_QUERY_S)
        except ConnectionError as exc:  # the gate then refuses it, as it would have without asking
            log.warning("could not confirm session %r: %s", session[:16], exc)
            return
        if alive:
            self.controller.learner_confirmed_alive(session)

    # -- publishing ----------------------------------------------------------------------------------
    def _report_held_back(self, now: float) -> None:
        """Bad messages the throttle held back, once their window ends (a burst with nothing after)."""
        for detail in self._bad_events.overdue(now):
            self._publish_safety("bad_message", detail, self.controller.safety.mode != "running")

    def _publish_safety(self, kind: str, detail: str, held: bool) -> None:
        self._pub_safety(m.SafetyEvent(kind=m.enum(m.SafetyEvent, "kind", kind), detail=detail, held=held))

    def _publish(self, result: TickResult) -> None:
        for record in result.events:
            log.info("safety %s: %s", record.kind, record.detail)
            self._publish_safety(record.kind, record.detail, record.held)
        for report in result.reports:
            by = report.preempted_by_label
            self._pub_status(
                m.ChunkStatus(
                    chunk_seq=report.chunk_seq,
                    executed=report.executed,
                    dropped=report.dropped,
                    preempted_by=report.preempted_by,
                    done=report.done,
                    session=report.session,
                    verdict=m.ChunkStatus.ACCEPTED,
                    chunk_stamp=report.chunk_stamp,
                    segment=report.label.segment,
                    opened_by=report.label.opening,
                    preempted_by_opening=by.opening if by is not None else m.ActionChunk.NONE,
                )
            )
        self._publish_world(result.state)

    def _publish_world(self, state: ArmState) -> None:
        """The arm's state and, in simulation, the target's truth: each tick, and while homing."""
        self._pub_state(robot_state_message(state, self.instance))
        if self._pub_truth is not None:
            scene = self.scene
            self._pub_truth(
                m.Target(
                    position=scene.target.position.tolist(),
                    velocity=scene.target_velocity().tolist(),
                    covariance=[0.0] * 9,  # the truth: no uncertainty
                    valid=True,
                    status=m.Target.TRACKING,
                    frame_stamp=time.time(),  # when observed, on the wall clock like a camera frame's
                )
            )

    # -- control thread ------------------------------------------------------------------------------
    def _serve_resets(self) -> None:
        with self._lock:
            resets, self._resets = self._resets, []
        for request, done, box in resets:
            seed = request.seed if request.seed >= 0 else None  # -1: keep the target's motion
            try:
                # A reset is how a learner session takes over, numbering on from its next chunk.
                self.controller.take_over(request.session, request.next_chunk)
                state = self.controller.reset(seed, time.monotonic, self._publish_world)
                reply = m.ResetReply(ok=True, state=robot_state_message(state, self.instance, time.time()))
            except (TakeoverRefused, ArmHeld) as exc:  # a foreign session (a safety event), or held
                reply = m.ResetReply(ok=False, detail=f"reset refused: {exc}")
            except Exception as exc:
                log.exception("reset failed")
                reply = m.ResetReply(ok=False, detail=f"{type(exc).__name__}: {exc}")
            box.append(reply)
            done.set()

    def workers(self) -> dict[str, Callable[[], None]]:
        return {"robot-io": self.run}

    def wake(self) -> None:
        self._wake.set()

    def close(self) -> None:
        super().close()
        self.controller.close()

    def run(self) -> None:
        """Tick at the control rate until stopped; between ticks serve resets and e-stops at once."""
        prioritize_this_thread(self.controller.config.control_thread_nice)
        next_tick = time.monotonic()
        while not self.stopping:
            now = time.monotonic()
            if now >= next_tick:
                self._publish(self.controller.tick(now))
                self._report_held_back(now)
                self.ticks += 1
                next_tick += self.period
                if next_tick <= time.monotonic():  # fell behind (a long reset): never burst;
                    next_tick = time.monotonic() + self.period  # the learner gets a full period to answer
            self._wake.wait(timeout=max(0.0, next_tick - time.monotonic()))
            if self._wake.is_set():
                self._wake.clear()
                self._serve_resets()
                result = self.controller.react(time.monotonic())
                if result.events or result.reports:
                    self._publish(result)
