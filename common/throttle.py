"""Rate-limited reporting of bad input: a flood of it must not fill a disk or the operator's screen."""

from __future__ import annotations

import time
from collections.abc import Callable

REPORT_EVERY_S = 60.0  # a flood on one key for one reason: one line a minute (30 s of fuzz: one per kind)


class ReportThrottle:
    """Per (key, reason): the first report in full, then at most one per ``every_s`` saying how many
    were held back meanwhile (with the newest example). ``total`` counts everything."""

    def __init__(self, every_s: float = REPORT_EVERY_S, clock: Callable[[], float] = time.monotonic) -> None:
        self.every_s = every_s
        self.clock = clock
        self.total: dict[tuple[str, str], int] = {}
        self._last: dict[tuple[str, str], float] = {}
        self._held: dict[tuple[str, str], int] = {}

    def report(self, key: str, reason: str, text: str) -> str | None:
        """The line to report for this complaint now, or None to hold it back."""
        group = (key, reason)
        self.total[group] = self.total.get(group, 0) + 1
        now = self.clock()
        if now - self._last.get(group, -float("inf")) < self.every_s:
            self._held[group] = self._held.get(group, 0) + 1
            return None
        held = self._held.pop(group, 0)
        self._last[group] = now
        if held:
            return f"{text} (and {held} more like it on {key} in the last {self.every_s:g} s)"
        return text
