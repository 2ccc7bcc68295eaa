"""Whose commands the arm obeys: one learner session at a time, its chunks numbered 0, 1, 2, … .

Before this, robot-io played any chunk whose number was above the last one's: one altered number (a
bit flip, a replayed recording, any peer on the bus) was accepted, and every genuine chunk after it
was "older" and ignored, silently, with the arm frozen. Now a chunk names its session and a number
within it. A session takes over explicitly (robot-io's reset), and only while its liveliness token is
alive, so a replayed or corrupted session id cannot take the arm; a chunk of any other session, one
not newer than the session's last, or one implausibly far ahead is refused with a reason the sender
and the operator both see. A forged number inside the gap can at worst push the genuine learner's
next numbers to "stale" for as many chunks as it jumped: the learner is told and moves past it.
"""

from __future__ import annotations

from typing import Literal

from common.errors import AdaptiveHError

Verdict = Literal["accepted", "held", "bad_plan", "stale", "foreign", "seq_jump", "forged"]
"""What became of a chunk: queued; or refused whole because the arm is held, it breaks the plan rules,
it is not newer than the session's last chunk, it is not from the obeyed session, it jumps ahead, or
(checked by deploy's robot-io node) its signature is not the stack's."""

GATE_REFUSALS: tuple[Verdict, ...] = ("stale", "foreign", "seq_jump")


class TakeoverRefused(AdaptiveHError):
    """A session asked to take over the arm without a live liveliness token (or without an id)."""


class CommandGate:
    """The obeyed session, its last admitted chunk number and the sessions alive now. Not locked: the
    controller calls it under its own lock."""

    def __init__(self, max_seq_gap: int) -> None:
        self.max_seq_gap = max_seq_gap
        self.session = ""  # "" until a session takes over: every chunk is foreign
        self.last_seq = -1
        self.live: set[str] = set()
        self.gone: set[str] = set()  # sessions whose token was seen to go (ids are random: a few a run)

    def alive(self, session: str, alive: bool) -> None:
        """A learner session's liveliness token appeared or disappeared (the subscriber's account)."""
        if alive:
            self.live.add(session)
            self.gone.discard(session)
        else:
            self.live.discard(session)
            self.gone.add(session)

    def confirmed_alive(self, session: str) -> None:
        """The network said ``session``'s token existed a moment ago: alive, unless the subscriber has
        meanwhile seen it go (a late confirmation must not revive a dead session)."""
        if session not in self.gone:
            self.live.add(session)

    def is_alive(self, session: str) -> bool:
        return session in self.live

    def take_over(self, session: str, next_seq: int = 0) -> str | None:
        """Obey ``session`` from now on, its numbering starting at ``next_seq`` (a learner's next chunk);
        returns the session it replaced ("" for none). Raises TakeoverRefused for a session not alive."""
        if not session:
            raise TakeoverRefused("a reset must name its learner session (ResetRequest.session)")
        if session not in self.live:
            raise TakeoverRefused(
                f"session {session[:16]!r} has no liveliness token (alive/learner/<session>): "
                "a replayed or forged request, or a learner that is gone"
            )
        previous = self.session
        if session != previous:
            self.session, self.last_seq = session, max(next_seq, 0) - 1
        return previous

    def check(self, session: str, seq: int) -> Verdict | None:
        """None when chunk ``seq`` of ``session`` may be the obeyed session's next; else why not. A
        session whose token is gone is obeyed no more (its id is on the bus for anyone to copy)."""
        if not self.session or session != self.session or session not in self.live:
            return "foreign"
        if seq <= self.last_seq:
            return "stale"
        if seq > self.last_seq + self.max_seq_gap:
            return "seq_jump"
        return None

    def admitted(self, seq: int) -> None:
        """Chunk ``seq`` was queued, or refused while the arm was held: later ones must be newer. (A chunk
        refused for its content leaves its number free.)"""
        self.last_seq = seq

    def describe(self, verdict: Verdict, session: str, seq: int) -> str:
        """A refusal in words, for the safety event and the log."""
        who = f"chunk {seq} of session {session[:16]!r}"
        if verdict == "foreign":
            obeyed = repr(self.session[:16]) if self.session else "none yet"
            gone = " (its liveliness token is gone)" if session == self.session else ""
            return f"{who}: not the session the arm obeys ({obeyed}){gone}; ignored"
        if verdict == "stale":
            return f"{who}: not newer than its last chunk {self.last_seq}; ignored"
        return (
            f"{who}: {seq - self.last_seq} ahead of its last chunk {self.last_seq}, more than "
            f"robot.max_chunk_seq_gap = {self.max_seq_gap}; ignored"
        )
