"""The chunk queue: play Cartesian actions in order; a newer chunk preempts what is left of the current one.

Thread-safe because chunks arrive on a transport thread while the control loop pops actions.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ChunkReport:
    """The account of one chunk: how many actions ran, how many were dropped, and why it ended."""

    chunk_seq: int
    executed: int
    dropped: int
    preempted_by: int = -1
    done: bool = False


@dataclass(frozen=True)
class Played:
    """An action taken from the queue, with the chunk and index it came from (what the tick reports)."""

    chunk_seq: int
    index: int
    action: np.ndarray


class ActionQueue:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._actions: deque[np.ndarray] = deque()
        self._seq = -1
        self._executed = 0
        self._reports: list[ChunkReport] = []

    def push(self, chunk_seq: int, actions: np.ndarray) -> bool:
        """Queue a chunk; returns False (and ignores it) when it is not newer than the current one."""
        actions = np.asarray(actions, float).reshape(-1, 3)
        with self._lock:
            if chunk_seq <= self._seq:
                return False
            if self._actions:
                self._reports.append(
                    ChunkReport(
                        self._seq, self._executed, len(self._actions), preempted_by=chunk_seq, done=True
                    )
                )
            self._actions = deque(actions)
            self._seq = chunk_seq
            self._executed = 0
            if not self._actions:
                self._reports.append(ChunkReport(chunk_seq, 0, 0, done=True))
            return True

    def take(self) -> Played | None:
        """Next action of the current chunk with its chunk and index, or None when the queue is empty."""
        with self._lock:
            if not self._actions:
                return None
            action = self._actions.popleft()
            played = Played(self._seq, self._executed, action)
            self._executed += 1
            self._reports.append(ChunkReport(self._seq, self._executed, 0, done=not self._actions))
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
                self._reports.append(
                    ChunkReport(self._seq, self._executed, dropped, preempted_by=reason_seq, done=True)
                )
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

    def __len__(self) -> int:
        with self._lock:
            return len(self._actions)
