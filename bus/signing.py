"""Which messages come from the stack: an HMAC keyed by the operator token, in a message's ``mac`` field.

Every part of ``adaptiveh up`` gets the operator token through its environment. Messages that steer the
arm or that the learner trusts as the arm's account (``ActionChunk``, ``ResetRequest``, ``Control``,
``RobotState``, ``ChunkStatus``, and what the operator's views show: ``Target``, ``LearnerTelemetry``,
``RetreatEvent``, ``SafetyEvent``) carry ``mac``: HMAC-SHA256 of the message's type name and the message
serialized with ``mac`` empty. A peer without the token, or an altered copy of genuine traffic, does not
verify; an exact copy does, so receivers also refuse what is not new (chunk numbers, control and reset
stamps; every other signed message through ``Verifier``'s replay guard).

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

    def __init__(self, what: str, msg: Message, reason: str = "forged") -> None:
        super().__init__(what, reason)
        self.msg = msg


def mac_key(token: str) -> bytes | None:
    """The signing key of a stack with operator token ``token``; None (nothing signed) without one."""
    return hmac.new(token.encode(), KEY_CONTEXT, hashlib.sha256).digest() if token else None


def signed(cls: type[Message]) -> bool:
    """Messages of ``cls`` carry a ``mac``."""
    return "mac" in cls.DESCRIPTOR.fields_by_name


def _mac(msg: Message, key: bytes) -> bytes:
    """HMAC of the message's type name, then its bytes: the bytes of one type can parse as another (a
    signed SafetyEvent read as a Control parsed as a RELEASE), so a mac is only ever valid for its type."""
    mac, msg.mac = msg.mac, b""
    try:
        signer = hmac.new(key, msg.DESCRIPTOR.full_name.encode() + b"\0", hashlib.sha256)
        signer.update(msg.SerializeToString(deterministic=True))
        return signer.digest()
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


class ReplayGuard:
    """Refuses an exact copy of a signed message it let through (a stranger replaying genuine retreat or
    safety events would inflate the operator's counts): remembers the newest ``size`` macs, and refuses a
    stamp older than any it has forgotten (it could no longer tell a copy from an original). Each put has
    its own seq and stamp, so genuine traffic never repeats a mac."""

    def __init__(self, size: int = 4096) -> None:
        self.size = size
        self.floor = 0.0
        self._seen: dict[bytes, float] = {}

    def __call__(self, mac: bytes, stamp: float) -> bool:
        if stamp < self.floor or mac in self._seen:
            return False
        self._seen[mac] = stamp
        if len(self._seen) > self.size:
            oldest = next(iter(self._seen))
            self.floor = max(self.floor, self._seen.pop(oldest))
        return True


class Verifier:
    """What a reader of signed messages believes: signed with the stack's ``key`` and not a copy of one
    already believed. One per subscription (each sees every message once)."""

    def __init__(self, key: bytes) -> None:
        self.key = key
        self._new = ReplayGuard()

    def check(self, where: str, msg: Message) -> None:
        """Raise ForgedMessage (naming ``where``) unless ``msg`` is authentic and new."""
        if not authentic(msg, self.key):
            raise ForgedMessage(f"{where}: not signed with the stack's key", msg)
        if not self._new(msg.mac, getattr(msg, "stamp", 0.0)):
            raise ForgedMessage(f"{where}: a copy of a message already seen (a replay)", msg, "replayed")


class KeyedVerifiers:
    """A ``Verifier`` per key expression, for a reader of every key (the recorder, the live view): with
    no stack key, or for a type without a mac, everything passes."""

    def __init__(self, key: bytes | None) -> None:
        self.key = key
        self._by_key: dict[str, Verifier] = {}

    def check(self, where: str, msg: Message) -> None:
        """Raise ForgedMessage unless ``msg`` (seen on ``where``) is the stack's and new, or has no mac."""
        if self.key is None or not signed(type(msg)):
            return
        verifier = self._by_key.get(where)
        if verifier is None:
            verifier = self._by_key[where] = Verifier(self.key)
        verifier.check(where, msg)
