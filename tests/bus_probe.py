"""The test's own peer on a robot's bus: what the parts publish, collected as it arrives.

One helper for the Zenoh tests (the vision, robot-io and learner tests each had a copy). Each topic
asked for fills a list (a deque where only the newest are kept) under one lock; ``wait`` polls a
condition over them. Lists, not unbounded deques: a test may iterate one while Zenoh's thread
appends. Arrival times are wall clock (``time.time()``): tests compare them with the messages' own
stamps. Imported by name (tests/ is not a package).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, MutableSequence
from typing import Any, TypeVar

import numpy as np
from polling import wait_until

from bus import messages as m
from bus.messages import Message, Topic
from bus.transport import Bus

M = TypeVar("M", bound=Message)


class BusProbe:
    """Collects the messages of the topics asked for on ``bus``; ``lock`` guards every collection."""

    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        self.lock = threading.RLock()  # re-entrant: conditions in wait() may call helpers that lock

    def collect(
        self, topic: Topic[M], arrival: bool = True, maxlen: int | None = None
    ) -> MutableSequence[Any]:
        """Every message on ``topic`` from now on, as ``(arrival time, message)`` or, with
        ``arrival=False``, the message alone; ``maxlen`` keeps only the newest."""
        got: MutableSequence[Any] = [] if maxlen is None else deque(maxlen=maxlen)

        def on(msg: M) -> None:
            with self.lock:
                got.append((time.time(), msg) if arrival else msg)

        self.bus.subscribe(topic, on)  # the probe's one tie to decoding; bad bytes: the Bus counts them
        return got

    def wait_heard_by(self, sender: Bus, topic: Topic[Any], timeout: float = 10.0) -> None:
        """Wait until what ``sender`` puts on ``topic`` reaches this probe's subscription (Zenoh declares a
        subscription to a peer a moment after it connects; a put before that is lost)."""
        publisher = sender.session.declare_publisher(sender.key(topic))
        try:
            self.wait(lambda: publisher.matching_status.matching, timeout, f"{topic} to match a subscriber")
        finally:
            publisher.undeclare()

    def wait(self, pred: Callable[[], Any], timeout: float = 10.0, what: str = "the condition") -> Any:
        """``pred()``'s first truthy value (evaluated under the lock); AssertionError after ``timeout`` s."""

        def locked() -> Any:
            with self.lock:
                return pred()

        return wait_until(locked, timeout, what)


# A ChunkStatus must say why its chunk and its preemptor were made (every enum is set on the wire).
LABELS = {"opened_by": m.ActionChunk.FIRST, "preempted_by_opening": m.ActionChunk.NONE}


def send_chunk(bus: Bus, seq: int, actions: Any, session: str, predicted_ee: Any = ()) -> None:
    """Put an ActionChunk of ``session`` with an explicit ``seq`` straight on the wire (what a learner,
    or a stranger copying its session id, sends), bypassing the publisher's own numbering."""
    msg = m.ActionChunk(
        seq=seq,
        actions=np.asarray(actions, float).ravel(),
        session=session,
        predicted_ee=np.asarray(predicted_ee, float).ravel(),
        opened_by=m.ActionChunk.FIRST,
    )
    bus.session.put(bus.key(m.CMD_CHUNK), msg.SerializeToString())


def control(bus: Bus, command: str) -> None:
    """An operator request without a token (the robot obeys an e-stop regardless)."""
    msg = m.Control(command=m.enum(m.Control, "command", command), jog=[0.0, 0.0, 0.0])
    bus.session.put(bus.key(m.CONTROL), msg.SerializeToString())
