"""When to try clearing a driver fault: on the operator's release, or automatically for a few kinds.

A fault (a reflex, a lost connection) holds the arm with a ``driver_error`` safety event. Only a
successful ``backend.recover()`` clears that hold, so a release can no longer resume an arm whose
driver still reports the error (the next tick would hold again). Some reflexes are transient and
safe to clear without a person, e.g. ``communication_constraints_violation`` after a network hiccup;
``robot.franka.auto_recover`` names them and ``auto_recover_limit`` bounds how often that happens
before an operator must look (the count restarts at each operator release). Everything else waits
for the operator.
"""

from __future__ import annotations

from robot_io.backends.protocol import Fault


class RecoveryPolicy:
    """Decides, once per control pass, whether to attempt recovery and says why (for the event)."""

    def __init__(self, auto_kinds: tuple[str, ...], auto_limit: int) -> None:
        self.auto_kinds = frozenset(auto_kinds)
        self.auto_limit = auto_limit
        self.auto_used = 0

    def reason(self, fault: Fault | None, new_fault: bool, released: bool, held: bool) -> str | None:
        """Why to call ``recover()`` now, or None. ``new_fault``: this pass first saw ``fault``;
        ``released``: the operator released in this pass; ``held``: a driver_error hold is active."""
        if released and (held or fault is not None):
            self.auto_used = 0
            return "operator release: recovered"
        if fault is None or not new_fault:
            return None
        matched = sorted(self.auto_kinds.intersection(fault.kinds))
        if not matched:
            return None
        if self.auto_used >= self.auto_limit:
            return None
        self.auto_used += 1
        return f"automatic recovery {self.auto_used}/{self.auto_limit} of {', '.join(matched)}"
