"""Which messages come from the stack: an HMAC keyed by the operator token, in a message's ``mac`` field.

Every part of ``adaptiveh up`` gets the operator token through its environment. Messages that steer the
arm or that the learner trusts as the arm's account (``ActionChunk``, ``ResetRequest``, ``Control``,
``RobotState``, ``ChunkStatus``) carry ``mac``: HMAC-SHA256 of the message serialized with ``mac``
empty. A peer without the token, or an altered copy of genuine traffic, does not verify; an exact copy
does, so receivers also refuse what is not new (chunk numbers, control and reset stamps).

The key is derived from the token, never the token itself, and the token is never on the bus: a
``Control`` proves it knows the token by its ``mac`` (a token in clear, as before, let any peer that saw
one operator request sign anything).
"""

from __future__ import annotations

import hashlib
import hmac

from bus.messages import Message, MessageError

KEY_CONTEXT = b"adaptiveh message mac v1"


class ForgedMessage(MessageError):
    """A message that decoded but is not signed with the stack's key; ``msg`` is what it claimed."""

    def __init__(self, what: str, msg: Message) -> None:
        super().__init__(what)
        self.msg = msg


def mac_key(token: str) -> bytes | None:
    """The signing key of a stack with operator token ``token``; None (nothing signed) without one."""
    return hmac.new(token.encode(), KEY_CONTEXT, hashlib.sha256).digest() if token else None


def signed(cls: type[Message]) -> bool:
    """Messages of ``cls`` carry a ``mac``."""
    return "mac" in cls.DESCRIPTOR.fields_by_name


def _mac(msg: Message, key: bytes) -> bytes:
    mac, msg.mac = msg.mac, b""
    try:
        return hmac.new(key, msg.SerializeToString(deterministic=True), hashlib.sha256).digest()
    finally:
        msg.mac = mac


def sign(msg: Message, key: bytes) -> None:
    """Set ``msg.mac`` for its current contents (after ``seq`` and ``stamp`` are set)."""
    msg.mac = _mac(msg, key)


def authentic(msg: Message, key: bytes) -> bool:
    """``msg.mac`` is ``key``'s for these exact contents."""
    return hmac.compare_digest(msg.mac, _mac(msg, key))


class Fresh:
    """Accepts each stamp once and only newer ones: an exact copy of a signed request (a recorded
    "release" replayed after the next e-stop) verifies, and must still not be obeyed."""

    def __init__(self) -> None:
        self.last = 0.0

    def __call__(self, stamp: float) -> bool:
        if stamp <= self.last:
            return False
        self.last = stamp
        return True
