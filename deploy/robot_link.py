"""A learner session's link to one robot-io: what the arm and the target report as it arrives, the reset
that takes the arm over, whether robot-io restarted or obeys another session since, and the one book of
the plans sent and how each fared (``deploy.plan_channel.PlanBook``).

The reach env (``deploy.zenoh_env``) is the task on top of it: observations, rewards, steps and the plan
channel. Every wait here returns at once with ``LinkStopped`` when the node is stopping (``stop``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from bus import messages as m
from bus.learner_session import REFUSALS, LearnerSession
from bus.transport import Bus, QueryCancelled
from common.errors import AdaptiveHError
from deploy.plan_channel import PlanBook
from learner.plans import Plan
from robot_io.step_cap import cap_step_length

log = logging.getLogger(__name__)
SUSPENDED = ("estop", "paused", "fault")  # robot modes in which a tick is not a step of the task
WHY_REFUSED = {
    "foreign": "another learner session has the arm",
    "forged": "our signature is not robot-io's: is the learner's operator token the stack's?",
}


class LinkStopped(AdaptiveHError, RuntimeError):
    """The node is shutting down while a wait for the robot was under way."""


class TakenOver(AdaptiveHError, RuntimeError):
    """robot-io obeys another learner session now: this one's chunks are refused as foreign."""


def seen_at(target: m.Target | None) -> float:
    """When the target was observed: the camera frame's time, else the message's (ground truth)."""
    if target is None:
        return -np.inf
    return target.frame_stamp if target.frame_stamp > 0 else target.stamp


def usable(target: m.Target | None, when: float, limit_s: float) -> bool:
    """A fix not older than ``limit_s`` at time ``when`` (a state's stamp, or now)."""
    return target is not None and when - seen_at(target) <= limit_s


def fixed_since(target: m.Target | None, stamp: float) -> bool:
    """A target fixed by a fresh detection (not a prediction) observed at or after ``stamp``."""
    return target is not None and target.status == m.Target.TRACKING and seen_at(target) >= stamp


class RobotLink:
    """States, target and chunk statuses of one robot over ``bus``; ``keep_ticks`` bounds the ticks kept
    unread (None: every one, for an actor that reads each tick)."""

    def __init__(
        self,
        bus: Bus,
        target_topic: m.Topic[m.Target],
        target_timeout_s: float,
        max_step_m: float,
        keep_ticks: int | None,
    ) -> None:
        self.bus, self.target_topic = bus, target_topic
        self.target_timeout_s, self.max_step_m = target_timeout_s, max_step_m
        self.cond = threading.Condition()
        self.state: m.RobotState | None = None  # the newest
        self.target: m.Target | None = None  # the newest valid fix
        self.target_lost = False
        self.ticks: deque[tuple[m.RobotState, m.Target | None]] = deque(maxlen=keep_ticks)  # unread
        self._buffered_tick = -1  # the newest tick buffered (a state between ticks repeats it)
        self.stop = threading.Event()  # set by the node to abandon a wait for the robot
        self.book = PlanBook()
        self.session = LearnerSession(bus)  # chunks numbered from 0, obeyed once ``reset`` took over
        self.refused: dict[str, int] = {}  # own chunks robot-io refused, by verdict
        self.chunk_seq = -1  # the last chunk sent
        self.target_waits = 0  # target outages waited out
        self.outage_ticks = 0  # ticks passed over while the target was lost
        self.suspended_ticks = 0  # ticks passed over while the arm was e-stopped, paused or faulted
        self.robot_restarts = 0  # robot-io processes that replaced the one before
        self._taken_over_by = ""
        self._obeyed_since_tick: int | None = None  # the tick of our takeover (reset); None before it
        self._instance = ""  # the robot-io process whose states these are (RobotState.instance)
        self._restarted = False  # a new robot-io since the last ``consume_restart``
        bus.subscribe(m.STATE, self._on_state)
        bus.subscribe(target_topic, self._on_target)
        bus.subscribe(m.CHUNK_STATUS, self._on_status)

    # -- Zenoh callbacks -----------------------------------------------------------------------------
    def _on_state(self, msg: m.RobotState) -> None:
        with self.cond:
            if msg.instance != self._instance:
                self._new_robot_io(msg.instance)
            self.state = msg
            since = self._obeyed_since_tick
            if since is not None and msg.tick > since and not self.session.mine(msg):
                self._taken_over_by = msg.session or "(none)"  # the arm obeys another session since ours
            if msg.tick > self._buffered_tick:
                self._buffered_tick = msg.tick
                self.ticks.append((msg, self.target))
            self.cond.notify_all()

    def _new_robot_io(self, instance: str) -> None:
        """A robot-io process that is not the one before (a restart): its ticks count from 0 and it obeys
        no session yet, so the tick bookkeeping starts over and the episode ends at the next step (the
        reset that follows takes the new process over). Caller holds the lock."""
        if self._instance:
            log.warning("robot-io restarted (%s after %s): ending the episode", instance, self._instance)
            self.robot_restarts += 1
            self._restarted = True
        self._instance = instance
        self._buffered_tick = -1
        self._obeyed_since_tick = None
        self.ticks.clear()

    def _on_target(self, msg: m.Target) -> None:
        with self.cond:
            self.target_lost = not msg.valid
            if msg.valid:
                self.target = msg
            self.cond.notify_all()

    def _on_status(self, msg: m.ChunkStatus) -> None:
        if not self.session.mine(msg):
            return  # another session's chunk (a stranger, or the learner before a restart)
        verdict = m.label(msg, "verdict")
        if verdict in REFUSALS:
            self._on_refused(msg, verdict)
            return
        self.book.on_status(msg)

    def _on_refused(self, msg: m.ChunkStatus, verdict: str) -> None:
        """robot-io refused our chunk: say so (once per kind, then every 100th), let a waiting step resend."""
        self.book.on_refused(msg)
        with self.cond:
            n = self.refused[verdict] = self.refused.get(verdict, 0) + 1
            self.cond.notify_all()
        if n == 1 or n % 100 == 0:
            log.warning(
                "robot-io refused our chunk %d as %s (%d so far): %s",
                msg.chunk_seq,
                verdict,
                n,
                WHY_REFUSED.get(verdict, "a forged or corrupted chunk number got in before ours; resending"),
            )

    # -- the robot now -------------------------------------------------------------------------------
    @property
    def robot_mode(self) -> str:
        return m.label(self.state, "mode") if self.state is not None else "unknown"

    def wait(self, pred: Callable[[], bool], timeout: float) -> bool:
        """Wait for ``pred`` up to ``timeout``; ``LinkStopped`` as soon as the node is stopping."""
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                if self.stop.is_set():
                    raise LinkStopped("stopped while waiting for the robot")
                left = deadline - time.monotonic()
                # Short slices: a stop request sets an Event, which does not wake this condition.
                if self.cond.wait_for(pred, min(max(left, 0.0), 0.25)):
                    return True
                if left <= 0:
                    return False

    def target_fresh(self) -> bool:
        """The newest target report is a valid fix observed within ``target_timeout_s``."""
        return not self.target_lost and usable(self.target, time.time(), self.target_timeout_s)

    def await_target(self) -> None:
        """Block until the target is fresh again: a lost or stale target is never acted on (vision down,
        the target out of view). The wait is logged once per outage."""
        if self.wait(self.target_fresh, 0.0):
            return
        log.warning("target lost or stale on %s; waiting for a fresh fix", self.bus.key(self.target_topic))
        t0 = time.monotonic()
        while not self.wait(self.target_fresh, 1.0):
            pass
        self.target_waits += 1
        log.warning("target back after %.1f s", time.monotonic() - t0)

    def consume_restart(self) -> bool:
        """Whether robot-io restarted since the last call (then this step ends the episode)."""
        with self.cond:
            restarted, self._restarted = self._restarted, False
        return restarted

    def check_taken_over(self) -> None:
        """Raise ``TakenOver`` when robot-io obeys another session: a learner never fights another one
        for the arm behind the operator's back (its supervisor decides whether to start it again)."""
        with self.cond:
            other = self._taken_over_by
        if other:
            raise TakenOver(
                f"robot-io obeys learner session {other[:16]!r}, not ours ({self.session.id}); stopping"
            )

    @property
    def taken_over(self) -> bool:
        return bool(self._taken_over_by)

    # -- taking the arm over -------------------------------------------------------------------------
    def reset(self, seed: int | None, timeout_s: float) -> m.RobotState:
        """Home the arm through robot-io's ``reset`` queryable and take it over (an e-stopped, paused or
        faulted arm: the operator decides, so the deadline waits); the state the reply names."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self.stop.is_set():
                raise LinkStopped("stopped while resetting the robot")
            try:
                reply = self.session.reset(
                    seed if seed is not None else -1, timeout=min(10.0, timeout_s), cancel=self.stop
                )
                if reply.ok:
                    break
                err = reply.detail
            except QueryCancelled as exc:
                raise LinkStopped("stopped while resetting the robot") from exc
            except (TimeoutError, m.MessageError) as exc:
                err = str(exc)
            if self.robot_mode in SUSPENDED:
                deadline = time.monotonic() + timeout_s
            if time.monotonic() > deadline:
                raise TimeoutError(f"robot reset failed: {err}")
            time.sleep(0.5)
        state = reply.state
        with self.cond:
            if state.instance != self._instance:
                self._new_robot_io(state.instance)
            self._restarted = False  # this reset took the robot-io that answered it over
            self._taken_over_by = ""  # the reset made this session the one the arm obeys
            self._obeyed_since_tick = state.tick
            if state.tick >= (self.state.tick if self.state is not None else -1):
                self.state = state
        # Only a target detected after the reset: a reset moves the (simulated) target, and the last
        # message from before it (or the tracker coasting on the old track) put 20-40 cm jumps inside
        # episodes (measured), which wrecked the critic.
        if not self.wait(lambda: fixed_since(self.target, state.stamp), timeout_s):
            raise TimeoutError(f"no valid target on {self.bus.key(self.target_topic)} since the reset")
        self.drain_ticks()  # the episode starts at the newest tick: the ticks after it are its steps
        return state

    # -- plans and ticks -----------------------------------------------------------------------------
    def publish(self, plan: Plan) -> int:
        """Send ``plan`` as one chunk (its steps capped by the arm's rule), entered in the book; its seq."""
        actions = cap_step_length(np.reshape(plan.actions, (-1, 3)), self.max_step_m)
        predicted = np.asarray(plan.predicted, float)[1 : len(actions) + 1, 0:3]
        msg = m.ActionChunk(
            actions=actions.ravel().tolist(),
            segment=plan.segment,
            predicted_ee=predicted.ravel().tolist(),
            opened_by=m.enum(m.ActionChunk, "opened_by", plan.opened_by),
        )
        self.chunk_seq = self.book.send(lambda: self.session.send(msg), plan, actions)
        return self.chunk_seq

    def drain_ticks(self) -> list[tuple[m.RobotState, m.Target | None]]:
        """The ticks not yet read, oldest first; none remain."""
        with self.cond:
            ticks = list(self.ticks)
            self.ticks.clear()
        return ticks

    def next_tick(self, timeout_s: float) -> tuple[m.RobotState, m.Target | None]:
        """The oldest tick not yet read, waiting for it; ticks while suspended are passed over."""
        while True:
            if not self.wait(lambda: bool(self.ticks), timeout_s):
                log.warning("no robot state for %.1f s; waiting for robot-io", timeout_s)
                continue
            with self.cond:
                state, target = self.ticks.popleft()
            if m.label(state, "mode") in SUSPENDED:
                self.suspended_ticks += 1
                continue
            return state, target

    def backlog(self) -> int:
        """Ticks that played and are not yet read (more than none: the reader lags)."""
        with self.cond:
            return len(self.ticks)

    def counts(self) -> dict[str, Any]:
        """What the link saw, for a node's summary: the book's counts and the robot's interruptions."""
        return {
            **self.book.counts(),
            "target_waits": self.target_waits,
            "outage_ticks": self.outage_ticks,
            "suspended_ticks": self.suspended_ticks,
            "robot_restarts": self.robot_restarts,
        }
