"""What a reader believes: signed with the stack's key and new (bus.signing), and the lenient e-stop."""

from __future__ import annotations

import pytest

from bus import messages as m
from bus.signing import ForgedMessage, ReplayGuard, Verifier, mac_key, sign

KEY = mac_key("operator")


def _event(segment: int, stamp: float) -> m.RetreatEvent:
    e = m.RetreatEvent(segment=segment, H=3, reason=m.SegmentEnd.RETREAT, stamp=stamp)
    sign(e, KEY)
    return e


def test_a_verifier_believes_a_signed_event_once():
    verify = Verifier(KEY)
    e = _event(1, 10.0)
    verify.check("events/retreat", e)
    with pytest.raises(ForgedMessage, match="replay") as exc:
        verify.check("events/retreat", e)
    assert exc.value.reason == "replayed"


@pytest.mark.parametrize("key", [None, mac_key("another stack")])
def test_a_verifier_refuses_unsigned_and_foreign_events(key):
    e = m.RetreatEvent(segment=1, H=3, reason=m.SegmentEnd.RETREAT, stamp=10.0)
    if key is not None:
        sign(e, key)
    with pytest.raises(ForgedMessage, match="events/retreat: not signed") as exc:
        Verifier(KEY).check("events/retreat", e)
    assert exc.value.reason == "forged"


def test_an_altered_copy_is_refused():
    e = _event(1, 10.0)
    e.H = 49
    with pytest.raises(ForgedMessage, match="not signed"):
        Verifier(KEY).check("events/retreat", e)


def test_the_replay_guard_forgets_the_oldest_and_refuses_what_it_can_no_longer_judge():
    new = ReplayGuard(size=3)
    assert all(new(bytes([i]), float(i)) for i in range(1, 5))  # the 4th pushes the 1st out
    assert new.floor == 1.0
    assert not new(b"\x00", 0.5)  # older than anything remembered: cannot tell, refused
    assert not new(bytes([3]), 3.0)  # remembered: a copy
    assert new(b"\x09", 1.0)  # as old as the floor, never seen: believed


@pytest.mark.parametrize(
    "data, stops",
    [
        (m.Control(command=m.Control.ESTOP).SerializeToString(), True),  # no jog, no mac, no stamp
        (m.Control(command=m.Control.ESTOP, jog=[float("nan")] * 5, mac=b"x").SerializeToString(), True),
        (m.Control(command=m.Control.ESTOP, stamp=-1e300).SerializeToString(), True),
        (m.Control(command=m.Control.PAUSE).SerializeToString(), False),
        (b"\x18\x03\xff", False),  # an e-stop's bytes, then garbage: not a message at all
        (b"", False),
    ],
)
def test_says_estop_reads_a_stop_request_whatever_else_is_wrong(data, stops):
    assert m.says_estop(data) is stops


def test_a_stamp_foxglove_cannot_show_is_refused_on_decode():
    for stamp in (-1.0, 2.0**32, 1e76):
        data = m.RetreatEvent(H=1, reason=m.SegmentEnd.RETREAT, stamp=stamp).SerializeToString()
        with pytest.raises(m.MessageError, match="RetreatEvent.stamp"):
            m.decode(data, m.RetreatEvent)


def test_a_mac_is_valid_for_its_own_type_only():
    """A signed SafetyEvent's bytes parse as a Control (a RELEASE): the type is inside the mac."""
    event = m.SafetyEvent(kind=m.SafetyEvent.WATCHDOG, detail="x" * 24, stamp=10.0)
    sign(event, KEY)
    as_control = m.Control.FromString(event.SerializeToString())
    assert as_control.command == m.Control.RELEASE and as_control.mac == event.mac
    with pytest.raises(ForgedMessage, match="not signed"):
        Verifier(KEY).check("control", as_control)
