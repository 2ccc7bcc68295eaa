"""Always-on safety: hold reasons, the command watchdog, the workspace box and the e-stop.

The arm moves only when no hold reason is active. Each reason has its own way out, so one cannot clear
another: a fresh command clears the watchdog, the peer's liveliness token coming back clears a liveliness
hold, ``resume`` clears a pause, and only ``release`` clears an e-stop. Every change is an event.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robot_io.config import WorkspaceBox

RUNNING, PAUSED, HELD, ESTOP, FAULT = "running", "paused", "held", "estop", "fault"


@dataclass(frozen=True)
class SafetyRecord:
    """A safety intervention, as robot_io reports it (deploy turns it into a message)."""

    kind: str
    detail: str
    held: bool


class Safety:
    def __init__(self, workspace: WorkspaceBox, watchdog_timeout_s: float) -> None:
        self.lo = np.asarray(workspace.lo, float)
        self.hi = np.asarray(workspace.hi, float)
        self.watchdog_timeout_s = watchdog_timeout_s
        self.reasons: set[str] = set()
        self.last_command = None  # time of the last fresh command; None before the first
        self._clipping = False
        self.events: list[SafetyRecord] = []

    # -- state ---------------------------------------------------------------------------------------
    @property
    def mode(self) -> str:
        if "estop" in self.reasons:
            return ESTOP
        if "driver_error" in self.reasons:
            return FAULT  # the driver stopped the arm: these ticks are no steps to learn from
        if "pause" in self.reasons:
            return PAUSED
        return HELD if self.reasons else RUNNING

    @property
    def may_move(self) -> bool:
        return not self.reasons

    def report(self, kind: str, detail: str) -> None:
        self.events.append(SafetyRecord(kind, detail, held=not self.may_move))

    def drain(self) -> list[SafetyRecord]:
        out, self.events = self.events, []
        return out

    def hold(self, reason: str, detail: str) -> bool:
        """Add a hold reason; True when it is new (the caller then brakes the arm)."""
        if reason in self.reasons:
            return False
        self.reasons.add(reason)
        self.report(reason, detail)
        return True

    def clear(self, reason: str, detail: str) -> bool:
        if reason not in self.reasons:
            return False
        self.reasons.discard(reason)
        if not self.reasons:
            self.last_command = None  # the watchdog restarts with the next command, not at once
        self.report("release", f"{reason} cleared: {detail}")
        return True

    # -- operator ------------------------------------------------------------------------------------
    def estop(self, detail: str = "operator e-stop") -> bool:
        return self.hold("estop", detail)

    def pause(self, detail: str = "operator pause") -> bool:
        return self.hold("pause", detail)

    def resume(self) -> bool:
        return self.clear("pause", "operator resume")

    def release(self) -> bool:
        """Operator release: clears the e-stop, a pause and a watchdog hold (not a missing peer, and not a
        driver fault: only a successful recovery clears that, see ``robot_io.recovery``)."""
        changed = False
        for reason in ("estop", "pause", "watchdog", "ik_unreachable"):
            changed |= self.clear(reason, "operator release")
        return changed

    # -- watchdog ------------------------------------------------------------------------------------
    def accepts_commands(self) -> bool:
        """New chunks are taken when running or held only by the watchdog (which they clear)."""
        return not self.reasons - {"watchdog"}

    def command_received(self, now: float) -> None:
        self.clear("watchdog", "fresh command")
        self.last_command = now

    def check_watchdog(self, now: float, queue_empty: bool) -> bool:
        """Hold when the queue has run dry and no fresh command came within the timeout."""
        if not queue_empty or self.last_command is None or self.reasons - {"watchdog"}:
            return False  # nothing to watch, or already held for another reason
        idle = now - self.last_command
        if idle > self.watchdog_timeout_s:
            return self.hold("watchdog", f"no command for {idle:.3f} s (timeout {self.watchdog_timeout_s} s)")
        return False

    # -- workspace -----------------------------------------------------------------------------------
    def clip_goal(self, goal: np.ndarray) -> np.ndarray:
        """Clip an end-effector goal into the box; an event when clipping starts."""
        clipped = np.clip(goal, self.lo, self.hi)
        outside = bool(np.any(np.abs(clipped - goal) > 1e-9))
        if outside and not self._clipping:
            self.report("workspace", f"goal {np.round(goal, 3).tolist()} clipped to the workspace box")
        self._clipping = outside
        return clipped
