"""The robot-interface process: robot_io's controller behind Zenoh.

It ticks the controller at the control rate and publishes ``state`` every tick (with the tick's number
and which chunk action it played), ``cmd/status`` for every chunk change (executed, dropped,
preempted_by) and ``events/safety`` for every intervention. It takes ``cmd/chunk`` and ``control``,
answers ``reset``, declares ``alive/robot_io`` and holds the arm while a watched peer's liveliness
token (the learner's, by default) is gone. Physics (pybullet) and IK run on the control thread only;
Zenoh callbacks just queue work for it, and an e-stop wakes it at once.

A chunk is a plan and is refused whole when it is malformed: bytes that do not decode (NaN, a length
that is not a multiple of 3: ``bad_message``) or a decoded plan that breaks the robot's rules (empty,
longer than ``robot.max_plan_actions``, a step above ``robot.max_step_m``, a predicted path of another
length: ``bad_plan``). Nothing of it plays and the arm holds where it is; see
``RobotController.refuse_plan`` for what changes and what does not.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import numpy as np

from deploy import messages as m
from deploy.config import StackConfig
from deploy.node import Node
from robot_io.controller import ArmState, RobotController, TickResult

log = logging.getLogger(__name__)


def robot_state_message(s: ArmState, stamp: float = 0.0) -> m.RobotState:
    """The state message of ``s``; a publisher stamps it when it is put, a reset reply with ``stamp``."""
    return m.RobotState(
        stamp=stamp,
        q=s.q.tolist(),
        dq=s.dq.tolist(),
        ee_pos=s.ee_pos.tolist(),
        ee_vel=s.ee_vel.tolist(),
        mode=m.enum(m.RobotState, "mode", s.mode),
        chunk_seq=s.chunk_seq,
        queue_len=s.queue_len,
        tick=s.tick,
        played_chunk=s.played_chunk,
        played_index=s.played_index,
    )


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
        self.controller = controller or RobotController(settings.robot)
        self.period = settings.robot.period
        self.watch_peers = watch_peers
        self.control_token = control_token
        super().__init__(settings.name, settings.zenoh)
        self._pub_state = self.bus.publisher(m.STATE)
        self._pub_status = self.bus.publisher(m.CHUNK_STATUS)
        self._pub_safety = self.bus.publisher(m.EVENTS_SAFETY)
        self._pub_truth = self.bus.publisher(m.TARGET_TRUTH) if self.scene is not None else None
        self._wake = threading.Event()
        self._resets: list[tuple[int, threading.Event, list[m.ResetReply]]] = []
        self._lock = threading.Lock()
        self.ticks = 0
        self.bus.subscribe(m.CMD_CHUNK, self._on_chunk, on_bad=self._on_bad)
        self.bus.subscribe(m.CONTROL, self._on_control, on_bad=self._on_bad)
        self.bus.queryable(m.RESET, self._on_reset)
        self.bus.watch_alive(self._on_alive)
        self.declare_alive()

    @property
    def scene(self):
        """The PyBullet scene when the backend is the mock (its target is published as ground truth)."""
        return getattr(self.controller.backend, "scene", None)

    # -- Zenoh callbacks (Zenoh threads) -------------------------------------------------------------
    def _on_bad(self, topic: str, exc: Exception) -> None:
        if topic == m.CMD_CHUNK.name:  # a plan that does not even decode: refused whole, the arm holds
            self.controller.refuse_plan("bad_message", f"{topic}: {exc}")
            self._wake.set()  # the control thread publishes the event and the dropped rest at once
            return
        self._publish_safety("bad_message", f"{topic}: {exc}", self.controller.safety.mode != "running")

    def _on_chunk(self, msg: m.ActionChunk) -> None:
        actions = m.action_array(msg)  # decode already checked the length
        if msg.predicted_ee and len(msg.predicted_ee) != len(msg.actions):
            n_pred = len(msg.predicted_ee) // 3
            self.controller.refuse_plan(
                "bad_plan", f"chunk {msg.seq}: {n_pred} predicted positions for {len(actions)} actions"
            )
            outcome = "bad_plan"
        else:
            outcome = self.controller.push_chunk(msg.seq, actions, time.monotonic())
        if outcome == "accepted":
            return
        if outcome == "bad_plan":
            self._wake.set()
        log.info("chunk %d not played: %s (mode %s)", msg.seq, outcome, self.controller.safety.mode)
        self._pub_status(m.ChunkStatus(chunk_seq=msg.seq, executed=0, dropped=len(actions), done=True))

    def _on_control(self, msg: m.Control) -> None:
        command = m.label(msg, "command")
        # An e-stop is always obeyed; everything else needs the operator token when one is set.
        if command != "estop" and self.control_token and msg.token != self.control_token:
            self._on_bad(m.CONTROL.name, m.MessageError(f"{command}: wrong operator token"))
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
        done, box = threading.Event(), []
        with self._lock:
            self._resets.append((request.seed, done, box))
        self._wake.set()
        if not done.wait(timeout=30.0):
            return m.ResetReply(ok=False, detail="reset timed out")
        return box[0]

    # -- publishing ----------------------------------------------------------------------------------
    def _publish_safety(self, kind: str, detail: str, held: bool) -> None:
        self._pub_safety(m.SafetyEvent(kind=m.enum(m.SafetyEvent, "kind", kind), detail=detail, held=held))

    def _publish(self, result: TickResult) -> None:
        for record in result.events:
            log.info("safety %s: %s", record.kind, record.detail)
            self._publish_safety(record.kind, record.detail, record.held)
        for report in result.reports:
            self._pub_status(
                m.ChunkStatus(
                    chunk_seq=report.chunk_seq,
                    executed=report.executed,
                    dropped=report.dropped,
                    preempted_by=report.preempted_by,
                    done=report.done,
                )
            )
        self._pub_state(robot_state_message(result.state))
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
        for seed, done, box in resets:
            try:
                state = self.controller.reset(seed if seed >= 0 else None)  # -1: keep the target's motion
                reply = m.ResetReply(ok=True, state=robot_state_message(state, time.time()))
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
        next_tick = time.monotonic()
        while not self.stopping:
            now = time.monotonic()
            if now >= next_tick:
                self._publish(self.controller.tick(now))
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
