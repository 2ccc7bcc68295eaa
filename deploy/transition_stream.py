"""Nothing an actor streams is lost while its learner is away.

Each actor process numbers its transitions from 0 on a stream of its own (``Transition.stream``,
``step``) and keeps each in its :class:`Outbox` until the learner has checkpointed it
(``TransitionAck.saved``). The learner's :class:`Inbox` takes each stream in order, without a gap or a
repeat, and says how far it learned (``learned``). When the learner lacks what the actor sent (a
restarted learner resumes from its checkpoint; a message lost or refused on the way) the actor sends
again from ``learned``: at once to a new learner process, else after a second in which the learner acks
without progress (a gap: it waits for what it lacks), backing off while it still makes none. To nobody
(no learner yet, or one stopped or paused: no acks) nothing is sent again until a learner speaks. The
outbox is bounded: an overflow drops the oldest, counts it and says so, and ``first_kept`` tells the
learner those steps are gone for good.
"""

from __future__ import annotations

import secrets
import threading
import time
from collections import deque
from collections.abc import Callable

from bus import messages as m
from bus.transport import Bus

RESEND_AFTER_S = 1.0  # no progress this long while the learner lacks some: send again from ``learned``
RESEND_MAX_S = 8.0  # the wait doubles up to this while the learner still makes none
RESEND_BATCH = 200  # transitions sent again per call: the actor's control loop is never held up long
ACK_EVERY_S = 0.2


class Outbox:
    """The actor's side: numbers, sends and keeps each transition until the learner has saved it."""

    def __init__(
        self,
        publish: Callable[[m.Transition], object],
        limit: int,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.stream = secrets.token_hex(8)
        self.limit = limit
        self.sent = 0  # transitions numbered so far: the next one's step
        self.lost = 0  # dropped by an overflow before the learner saved them
        self.resent = 0
        self._publish, self._clock = publish, clock
        self._kept: deque[m.Transition] = deque()  # steps first_kept .. sent-1, contiguous
        self._lock = threading.Lock()
        self._learned = 0
        self._learner = ""  # the learner process heard from last ("": none yet)
        self._heard_at = self._progress_at = clock()
        self._wait = RESEND_AFTER_S
        self._cursor: int | None = None  # sending again: the next step to send

    def send(self, msg: m.Transition) -> bool:
        """Number ``msg``, keep it and publish it; True when keeping it dropped an unsaved one."""
        with self._lock:
            msg.stream, msg.step = self.stream, self.sent
            self.sent += 1
            self._kept.append(msg)
            dropped = len(self._kept) > self.limit
            if dropped:
                self._kept.popleft()
                self.lost += 1
            msg.first_kept = self._kept[0].step
        self._publish(msg)
        return dropped

    def on_ack(self, ack: m.TransitionAck) -> None:
        """The learner's account of this stream: forget what it saved; note how far it learned. A learner
        that has heard of no stream yet says hello (``stream`` empty): it has learned none of this one."""
        if ack.stream not in (self.stream, ""):
            return
        with self._lock:
            while self._kept and self._kept[0].step < ack.saved:
                self._kept.popleft()
            new_learner = ack.learner != self._learner
            self._heard_at = self._clock()
            if new_learner or ack.learned > self._learned:
                self._progress_at, self._wait = self._clock(), RESEND_AFTER_S
            self._learner, self._learned = ack.learner, ack.learned
            if new_learner and ack.learned < self.sent:
                self._cursor = ack.learned  # a learner that resumed from its checkpoint lacks the rest

    def resend(self) -> int:
        """Send again (up to ``RESEND_BATCH``) what the learner lacks, when it is due; how many."""
        with self._lock:
            now = self._clock()
            stalled = now - self._progress_at >= self._wait
            alive = bool(self._learner) and now - self._heard_at <= RESEND_AFTER_S  # acking, not learning
            if self._cursor is None and self._learned < self.sent and stalled and alive:
                self._cursor = self._learned
                self._progress_at, self._wait = now, min(2 * self._wait, RESEND_MAX_S)
            if self._cursor is None or not self._kept:
                self._cursor = None
                return 0
            first = self._kept[0].step
            start = max(self._cursor, first)
            end = min(start - first + RESEND_BATCH, len(self._kept))
            batch = [self._kept[i] for i in range(start - first, end)]
            self._cursor = start + len(batch)
            if self._cursor >= self.sent:
                self._cursor = None
            for msg in batch:
                msg.first_kept = first
        for msg in batch:
            self._publish(msg)
        self.resent += len(batch)
        return len(batch)

    def unsaved(self) -> int:
        """Transitions kept because the learner has not saved them yet."""
        with self._lock:
            return len(self._kept)


class Inbox:
    """The learner's side: each stream's transitions in order, once each, for the learner's thread.
    ``marks`` (stream -> transitions learned) is where a checkpoint left each stream."""

    def __init__(self, bus: Bus, marks: dict[str, int], keep: int = 20_000) -> None:
        self.learner = secrets.token_hex(8)
        self.keep = keep
        self.learned = dict(marks)  # the learner thread's: steps learned, per stream
        self.saved = dict(marks)  # what the newest checkpoint holds
        self.received = self.duplicates = self.out_of_order = self.full = self.lost = 0
        self._accepted = dict(marks)  # the callback's: the next step it takes, per stream
        self._seen: set[str] = set()  # streams heard from, learned from or not
        self._items: deque[m.Transition] = deque()
        self._cond = threading.Condition()
        self._acked_at = 0.0
        self._pub_ack = bus.publisher(m.TRANSITION_ACKS)
        bus.subscribe(m.TRANSITIONS, self._on_transition)

    def _on_transition(self, msg: m.Transition) -> None:
        with self._cond:
            self.received += 1
            self._seen.add(msg.stream)
            expected = self._accepted.get(msg.stream, 0)
            if msg.first_kept > expected:  # the actor dropped those before the learner had them
                self.lost += msg.first_kept - expected
                expected = self._accepted[msg.stream] = msg.first_kept
            if msg.step < expected:
                self.duplicates += 1  # sent again, or the publisher's cache to a new subscriber
            elif msg.step > expected:
                self.out_of_order += 1  # one before it is missing: the actor sends again from there
            elif len(self._items) >= self.keep:
                self.full += 1  # not taken: sent again once the learner has caught up
            else:
                self._accepted[msg.stream] = msg.step + 1
                self._items.append(msg)
                self._cond.notify()

    def get(self, timeout: float) -> m.Transition | None:
        with self._cond:
            if not self._cond.wait_for(lambda: bool(self._items), timeout):
                return None
            return self._items.popleft()

    def learned_one(self, msg: m.Transition) -> None:
        self.learned[msg.stream] = msg.step + 1

    def checkpointed(self, marks: dict[str, int]) -> None:
        """A checkpoint now holds ``marks``: the actors may forget what it holds."""
        self.saved = dict(marks)
        self.ack(force=True)

    def ack(self, force: bool = False) -> None:
        """Tell every actor how far its stream was learned and saved (at most every ``ACK_EVERY_S``)."""
        now = time.monotonic()
        if not force and now - self._acked_at < ACK_EVERY_S:
            return
        self._acked_at = now
        with self._cond:
            streams = self._seen | set(self.learned)
        for stream in sorted(streams) or [""]:  # no stream yet: hello, to actors that sent before it came
            learned, saved = self.learned.get(stream, 0), self.saved.get(stream, 0)
            self._pub_ack(m.TransitionAck(stream=stream, learned=learned, saved=saved, learner=self.learner))
