"""The chunk queue: play Cartesian actions in order; a newer chunk preempts what is left of the current one.

Thread-safe because chunks arrive on a transport thread while the control loop pops actions.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ChunkLabel:
    """What the sender says a chunk's plan is (its segment, and why it was made, as the sender's enum
    number): echoed in every report of the chunk and of the one it preempts, never interpreted here."""

    segment: int = 0
    opening: int = 0


UNLABELLED = ChunkLabel()


@dataclass(frozen=True)
class ChunkReport:
    """The account of one chunk: how many actions ran, how many were dropped, and why it ended."""

    chunk_seq: int
    executed: int
    dropped: int
    preempted_by: int = -1
    done: bool = False
    session: str = ""  # the learner session whose chunk it is
    chunk_stamp: float = 0.0  # the chunk's send time: with session and number, names the exact chunk
    label: ChunkLabel = UNLABELLED
    preempted_by_label: ChunkLabel | None = None  # the preempting chunk's label; None: no chunk did


@dataclass(frozen=True)
class Played:
    """An action taken from the queue, with the chunk and index it came from (what the tick reports)."""

    chunk_seq: int
    index: int
    action: np.ndarray
    chunk_stamp: float = 0.0


class ActionQueue:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._actions: deque[np.ndarray] = deque()
        self._seq = -1
        self._stamp = 0.0
        self._label = UNLABELLED
        self._session = ""
        self._executed = 0
        self._reports: list[ChunkReport] = []

    def _report(
        self,
        chunk_seq: int,
        executed: int,
        dropped: int,
        preempted_by: int = -1,
        done: bool = False,
        by: ChunkLabel | None = None,
    ) -> None:
        report = ChunkReport(
            chunk_seq, executed, dropped, preempted_by, done, self._session, self._stamp, self._label, by
        )
        self._reports.append(report)

    def push(
        self, chunk_seq: int, actions: np.ndarray, stamp: float = 0.0, label: ChunkLabel = UNLABELLED
    ) -> bool:
        """Queue a chunk; returns False (and ignores it) when it is not newer than the current one."""
        actions = np.asarray(actions, float).reshape(-1, 3)
        with self._lock:
            if chunk_seq <= self._seq:
                return False
            if self._actions:
                dropped = len(self._actions)
                self._report(self._seq, self._executed, dropped, preempted_by=chunk_seq, done=True, by=label)
            self._actions = deque(actions)
            self._seq, self._stamp, self._label = chunk_seq, stamp, label
            self._executed = 0
            if not self._actions:
                self._report(chunk_seq, 0, 0, done=True)
            return True

    def restart(self, session: str) -> int:
        """A new session's numbering: drop what is queued (reported as dropped, preempted by no chunk)
        and take chunks of ``session`` from number 0 on; returns the number of actions dropped."""
        dropped = self.clear()
        with self._lock:
            self._session, self._seq, self._stamp, self._executed = session, -1, 0.0, 0
            self._label = UNLABELLED
        return dropped

    def take(self) -> Played | None:
        """Next action of the current chunk with its chunk and index, or None when the queue is empty."""
        with self._lock:
            if not self._actions:
                return None
            action = self._actions.popleft()
            played = Played(self._seq, self._executed, action, self._stamp)
            self._executed += 1
            self._report(self._seq, self._executed, 0, done=not self._actions)
            return played

    def pop(self) -> np.ndarray | None:
        """Next action of the current chunk, or None when the queue is empty."""
        played = self.take()
        return None if played is None else played.action

    def clear(self, reason_seq: int = -1) -> int:
        """Drop everything queued (e-stop, holds, reset); returns the number of actions dropped."""
        with self._lock:
            dropped = len(self._actions)
            if dropped:
                self._report(self._seq, self._executed, dropped, preempted_by=reason_seq, done=True)
            self._actions.clear()
            return dropped

    def reports(self) -> list[ChunkReport]:
        """Reports since the last call (oldest first)."""
        with self._lock:
            out, self._reports = self._reports, []
            return out

    @property
    def chunk_seq(self) -> int:
        return self._seq

    @property
    def session(self) -> str:
        return self._session

    @property
    def chunk_stamp(self) -> float:
        return self._stamp

    def __len__(self) -> int:
        with self._lock:
            return len(self._actions)
