"""A learner's identity on the bus: the session robot-io obeys (``robot_io.command_gate``).

A session is a random id, a liveliness token ``alive/learner/<id>`` (robot-io lets only a session with a
live token take over, so a replayed or corrupted id cannot), chunks numbered 0, 1, 2, … and stamped
with the id, and a reset that takes the arm over. Acknowledgements are read exactly: a state or a
chunk status counts only when it names this session and the chunk's own number, never "a higher
number than mine" (one forged number used to make a learner take every chunk as played).

With the stack's operator token (every part of ``adaptiveh up`` has it, through its environment) chunks
and resets are signed (``bus.signing``), and robot-io obeys only those that verify: a peer without
the token, or an altered copy of genuine traffic, cannot steer the arm even when it copies the session
id. An exact copy verifies, and is refused by its number (stale) or stamp (a reset).
"""

from __future__ import annotations

import logging
import secrets
import threading

from bus import messages as m
from bus.transport import Bus

log = logging.getLogger(__name__)
SESSIONS = "learner"  # the sessions' tokens live under alive/learner/<id>
REFUSALS = ("stale", "foreign", "seq_jump", "forged")  # ChunkStatus verdicts of a chunk robot-io ignored


class LearnerSession:
    """Declares the token on ``bus`` at once; ``send`` numbers and stamps chunks, ``reset`` takes over."""

    def __init__(self, bus: Bus, session_id: str | None = None) -> None:
        self.bus = bus  # a bus with the stack's key signs the chunks and resets (bus.signing)
        self.id = session_id or secrets.token_hex(8)
        bus.declare_alive(f"{SESSIONS}/{self.id}")
        self._pub = bus.publisher(m.CMD_CHUNK, first_seq=0)

    def send(self, chunk: m.ActionChunk) -> tuple[int, float]:
        """Publish ``chunk`` as this session's next; returns its number and stamp (its exact name)."""
        chunk.session = self.id
        return self._pub(chunk), chunk.stamp

    def reset(self, seed: int, timeout: float, cancel: threading.Event | None = None) -> m.ResetReply:
        """Ask robot-io for a new episode, taking the arm over if another session had it; ``cancel`` set
        gives up waiting for the reply (``bus.transport.QueryCancelled``)."""
        request = m.ResetRequest(seed=seed, session=self.id, next_chunk=self._pub.next_seq)
        return self.bus.query(m.RESET, request, timeout=timeout, cancel=cancel)

    def mine(self, msg: m.RobotState | m.ChunkStatus) -> bool:
        """The state names this session as the one obeyed, or the status is about one of its chunks."""
        return msg.session == self.id
