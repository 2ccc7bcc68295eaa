"""Rate-limited reporting of bad input: a flood of it must not fill a disk, the recording or the operator's
screen. Every part that reports repeated complaints (the bus's log, robot-io's and the actor's safety
events, vision's, the monitor's API) reports through one :class:`Throttle`."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Hashable

REPORT_EVERY_S = 60.0  # a flood on one key for one reason in a log: one line a minute
EVENT_EVERY_S = 1.0  # a flood as safety events: one a second


class Throttle:
    """Per group (any label: a key and a reason, a kind of event): the first report in full, then at most
    one per ``every_s`` saying how many (``what``) were held back meanwhile. ``overdue`` gives the counts
    held back whose window has passed with nothing let through, so a burst is reported even when nothing
    follows it. ``total`` counts everything. Thread-safe: bad input arrives on the bus's threads."""

    def __init__(
        self, what: str, every_s: float = REPORT_EVERY_S, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.what = what
        self.every_s = every_s
        self.clock = clock
        self.total: dict[Hashable, int] = {}
        self._last: dict[Hashable, float] = {}
        self._held: dict[Hashable, int] = {}
        self._lock = threading.Lock()

    def report(self, text: str, group: Hashable = "", now: float | None = None) -> str | None:
        """The line to report for this complaint at ``now`` (default: the clock's), or None to hold it."""
        with self._lock:
            self.total[group] = self.total.get(group, 0) + 1
            now = self.clock() if now is None else now
            if now - self._last.get(group, -float("inf")) < self.every_s:
                self._held[group] = self._held.get(group, 0) + 1
                return None
            held = self._held.pop(group, 0)
            self._last[group] = now
        return f"{text} (and {self._more(held)})" if held else text

    def overdue(self, now: float | None = None) -> list[str]:
        """One line per group whose held-back count's window has passed at ``now``."""
        out = []
        with self._lock:
            now = self.clock() if now is None else now
            for group, held in list(self._held.items()):
                if now - self._last[group] >= self.every_s:
                    out.append(self._more(held))
                    del self._held[group]
                    self._last[group] = now
        return out

    def _more(self, held: int) -> str:
        return " ".join(filter(None, (f"{held} more", self.what, "since the last report")))
