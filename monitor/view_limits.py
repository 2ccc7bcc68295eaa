"""What the operator's views (the page, the supervisor's summary, Foxglove) will plot: values in range.

Forged messages never get this far (the bus refuses what the stack did not sign); these checks keep a
genuine but broken message (a learner bug, a corrupted checkpoint's replay) from wrecking a plot's axis
or a summary's counts. Finite numbers and representable stamps are the decoder's (``bus.messages``).
"""

from __future__ import annotations

from dataclasses import dataclass

from bus import messages as m


@dataclass(frozen=True)
class ViewLimits:
    """``longest_segment``: no segment of this stack's learner is longer (None: not known, not checked)."""

    longest_segment: int | None = None

    def problem(self, msg: m.Message) -> str | None:
        """Why ``msg`` must not be shown, or None."""
        if isinstance(msg, m.RetreatEvent):
            return self._segment_problem(msg)
        return None

    def _segment_problem(self, e: m.RetreatEvent) -> str | None:
        if e.H < 1:
            return f"segment {e.segment}: H = {e.H} < 1"
        if self.longest_segment is not None and e.H > self.longest_segment:
            return f"segment {e.segment}: H = {e.H} > {self.longest_segment}, the learner's longest"
        if len(e.statistic) > e.H:
            return f"segment {e.segment}: {len(e.statistic)} statistic values for H = {e.H}"
        return None
