"""The robot side of ``learner.plans.PlanChannel`` over Zenoh: which plan a chunk was, late sending, drops.

``deploy.zenoh_env.ZenohReachEnv`` is the channel; this module keeps its parts that know nothing of the
reach task: :class:`PlanBook` (chunk number <-> plan, and what a preemption dropped),
:class:`DelayedSender` (a learner latency that never blocks the learner: the old plan keeps playing
meanwhile) and :func:`played` (which plan action a robot tick ran, from the tick's own report).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bus import messages as m
from learner.plans import Plan
from learner.segments import Opening

log = logging.getLogger(__name__)
MOVING_M = 1e-9  # a planned step longer than this is motion (zeros are the "stay put" of closed loop)


@dataclass(frozen=True)
class SentPlan:
    """A plan as it went out: the chunk number the robot reports it by, and why it was sent."""

    plan: Plan
    actions: np.ndarray  # as sent (steps capped): what the robot plays
    seq: int
    stamp: float = 0.0  # the chunk's stamp: with the number, what the robot names it by


@dataclass(frozen=True)
class PlanDrop:
    """What a preemption dropped of one plan: ``dropped`` planned actions, ``moving`` of them non-zero."""

    plan_id: int
    by_plan_id: int  # the plan that preempted it
    by_opening: str  # why that plan was made, as robot-io's status echoes it ("retreat", ...)
    executed: int
    dropped: int
    moving: int
    path_m: float  # planned end-effector travel abandoned (sum of the dropped steps' lengths)


class PlanBook:
    """Chunk number -> sent plan (the newest ``keep``), and the one account of what a newer plan dropped
    of the planned actions, as robot-io reports it (``counts``: what the actor and the learner report).

    Thread-safe: the sender records from its thread, the learner looks up ticks, Zenoh reports status.
    """

    def __init__(self, keep: int = 64) -> None:
        self._lock = threading.Lock()
        self._by_seq: dict[int, SentPlan] = {}
        self._order: deque[int] = deque()
        self.keep = keep
        self.newest_seq = -1
        self.dropped_planned = 0  # planned actions dropped by a newer plan, total
        self.dropped_moving = 0  # of which non-zero motions
        self.preemptions = 0
        self.retreat_preemptions = 0  # of them by a plan made after a retreat, the actions they dropped
        self.retreat_dropped = 0
        self.retreat_dropped_moving = 0
        self.foreign_ticks = 0  # ticks that played a chunk not in the book (reported as holds)
        self.drops: deque[PlanDrop] = deque(maxlen=256)
        self._refused: set[int] = set()  # sent plans robot-io's status refused (of the newest ``keep``)

    def send(self, put: Callable[[], tuple[int, float]], plan: Plan, actions: np.ndarray) -> int:
        """``put()`` the chunk (it returns the chunk's number and stamp) and record it, under the lock: a
        robot tick or status naming the chunk is never looked up before its entry exists. No Zenoh
        callback is waited on while the lock is held (a put does not wait for subscribers)."""
        with self._lock:
            seq, stamp = put()
            self._by_seq[seq] = SentPlan(plan, actions, seq, stamp)
            self._order.append(seq)
            self.newest_seq = max(self.newest_seq, seq)
            while len(self._order) > self.keep:
                old = self._order.popleft()
                self._by_seq.pop(old, None)
                self._refused.discard(old)
            return seq

    def get(self, seq: int) -> SentPlan | None:
        with self._lock:
            return self._by_seq.get(seq)

    def newest(self) -> SentPlan | None:
        with self._lock:
            return self._by_seq.get(self.newest_seq)

    def on_refused(self, msg: m.ChunkStatus) -> None:
        """robot-io refused the chunk ``msg`` names: recorded when it is one of ours (number and stamp)."""
        with self._lock:
            sent = self._by_seq.get(msg.chunk_seq)
            if sent is not None and sent.stamp == msg.chunk_stamp:
                self._refused.add(msg.chunk_seq)

    def refused(self, seq: int) -> bool:
        with self._lock:
            return seq in self._refused

    def on_status(self, msg: m.ChunkStatus) -> PlanDrop | None:
        """Account for a plan preempted by another plan; None for anything else (a refusal, an e-stop's
        clear and a plan run to its end drop no planned action in favour of a newer plan)."""
        if msg.preempted_by < 0 or not msg.dropped:
            return None
        with self._lock:
            sent, by = self._by_seq.get(msg.chunk_seq), self._by_seq.get(msg.preempted_by)
            if sent is None or sent.stamp != msg.chunk_stamp:
                return None  # not one of our plans (another learner, a forgery)
            rest = sent.actions[msg.executed : msg.executed + msg.dropped]
            lengths = np.linalg.norm(rest, axis=1)
            drop = PlanDrop(
                plan_id=sent.plan.plan_id,
                by_plan_id=by.plan.plan_id if by is not None else -1,
                by_opening=m.label(msg, "preempted_by_opening"),
                executed=msg.executed,
                dropped=msg.dropped,
                moving=int(np.sum(lengths > MOVING_M)),
                path_m=float(lengths.sum()),
            )
            self.dropped_planned += drop.dropped
            self.dropped_moving += drop.moving
            self.preemptions += 1
            if drop.by_opening == Opening.RETREAT:
                self.retreat_preemptions += 1
                self.retreat_dropped += drop.dropped
                self.retreat_dropped_moving += drop.moving
            self.drops.append(drop)
            return drop

    def counts(self) -> dict[str, int]:
        """The account as run results report it."""
        with self._lock:
            return {
                "preemptions": self.preemptions,
                "dropped_planned": self.dropped_planned,
                "dropped_planned_moving": self.dropped_moving,
                "retreat_preemptions": self.retreat_preemptions,
                "retreat_dropped": self.retreat_dropped,
                "retreat_dropped_moving": self.retreat_dropped_moving,
                "foreign_ticks": self.foreign_ticks,
            }


def played(state: m.RobotState, book: PlanBook, session: str) -> tuple[int, int, np.ndarray]:
    """(plan_id, index, action) of what the tick that produced ``state`` ran: the robot names the chunk
    and index it took from its queue; none (-1, -1, zero) is a hold, as is a chunk that was not one of
    our plans (its actions are unknown here), and any chunk while the arm obeys another ``session``."""
    if state.played_chunk < 0:
        return -1, -1, np.zeros(3)
    if state.session != session:
        book.foreign_ticks += 1
        return -1, -1, np.zeros(3)
    sent = book.get(state.played_chunk)
    if sent is None or sent.stamp != state.played_stamp or not 0 <= state.played_index < len(sent.actions):
        # E.g. a restarted learner's first ticks, while the last process's plan plays out.
        log.debug("tick %d played chunk %d, not a known plan", state.tick, state.played_chunk)
        book.foreign_ticks += 1
        return -1, -1, np.zeros(3)
    return sent.plan.plan_id, state.played_index, sent.actions[state.played_index].copy()


class DelayedSender:
    """Runs ``publish(item)`` ``delay_s`` after ``submit(item)``, in submission order, on its own thread.

    The learner's thinking time made real: ``submit`` returns at once and the robot keeps playing the
    old plan until the new one is published. ``cancel`` forgets what is still waiting (a reset: a plan
    of the last episode must not play in the next).
    """

    def __init__(self, publish: Callable[[object], None], delay_s: float, stop: threading.Event) -> None:
        self.publish = publish
        self.delay_s = delay_s
        self.stop = stop
        self._cond = threading.Condition()
        self._pending: deque[tuple[float, object]] = deque()
        self._thread: threading.Thread | None = None

    def submit(self, item: object) -> None:
        with self._cond:
            self._pending.append((time.monotonic() + self.delay_s, item))
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="plan-sender", daemon=True)
                self._thread.start()
            self._cond.notify_all()

    def cancel(self) -> int:
        with self._cond:
            n = len(self._pending)
            self._pending.clear()
            return n

    def pending(self) -> int:
        with self._cond:
            return len(self._pending)

    def _run(self) -> None:
        while not self.stop.is_set():
            with self._cond:
                if not self._pending:
                    self._cond.wait(0.25)  # short: ``stop`` is an Event, which does not wake this
                    continue
                due, item = self._pending[0]
                left = due - time.monotonic()
                if left > 0:
                    self._cond.wait(min(left, 0.25))
                    continue
                self._pending.popleft()
                # Published under the lock so a ``cancel`` (reset) never races a plan of the old episode.
                try:
                    self.publish(item)
                except Exception:  # a failed put must not kill the sender; the learner sees no plan play
                    log.exception("publishing a delayed plan failed")
