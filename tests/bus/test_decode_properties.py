"""Property tests of every message decoder: whatever bytes arrive, ``decode`` returns a valid message of
the asked type or raises ``MessageError`` naming the type (never another exception, never a message
with NaN, an unset enum or a wrong vector length). 10⁴ cases per strategy; each case is tried against
every type, so every decoder sees all of them."""

from __future__ import annotations

import math

import pytest
from google.protobuf.descriptor import FieldDescriptor
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_messages import SAMPLES

from bus import messages as m

CASES = settings(
    max_examples=10_000, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True
)
GENUINE = [s.SerializeToString() for s in SAMPLES]  # one real message of every type


def _decode_everywhere(data: bytes) -> None:
    for cls in m.MESSAGE_TYPES:
        try:
            msg = m.decode(data, cls)
        except m.MessageError as exc:
            assert str(exc).startswith(cls.__name__), exc  # the error names the type (and field)
            continue
        m.validate(msg)  # what came back obeys every rule
        assert msg.SerializeToString() is not None


@CASES
@given(st.binary(max_size=300))
def test_random_bytes(data: bytes) -> None:
    _decode_everywhere(data)


@CASES
@given(
    st.sampled_from(GENUINE),
    st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=6),
    st.integers(0, 400),
)
def test_mutated_genuine_messages(sample: bytes, flips: list[tuple[int, int]], cut: int) -> None:
    """Byte flips and truncation of real traffic: the fuzzing a bit error or a forger does."""
    data = bytearray(sample)
    for pos, value in flips:
        if data:
            data[pos % len(data)] = value
    _decode_everywhere(bytes(data[: max(cut, 0)] if cut < len(data) else data))


def _field_values(fd: FieldDescriptor) -> st.SearchStrategy:
    if fd.type in (FieldDescriptor.TYPE_DOUBLE, FieldDescriptor.TYPE_FLOAT):
        one = st.floats(allow_nan=True, allow_infinity=True)
    elif fd.type == FieldDescriptor.TYPE_ENUM:
        one = st.integers(-3, 20)
    elif fd.type == FieldDescriptor.TYPE_BOOL:
        one = st.booleans()
    elif fd.type in (FieldDescriptor.TYPE_STRING,):
        one = st.text(max_size=20)
    elif fd.type == FieldDescriptor.TYPE_BYTES:
        one = st.binary(max_size=20)
    elif fd.type == FieldDescriptor.TYPE_MESSAGE:
        return st.none()
    elif fd.type in (FieldDescriptor.TYPE_UINT32, FieldDescriptor.TYPE_UINT64):
        one = st.integers(0, 2**32 - 1)
    else:
        one = st.integers(-(2**31), 2**31 - 1)
    return st.lists(one, max_size=12) if fd.is_repeated else one


@st.composite
def any_message(draw: st.DrawFn) -> m.Message:
    cls = draw(st.sampled_from(m.MESSAGE_TYPES))
    msg = cls()
    for fd in cls.DESCRIPTOR.fields:
        value = draw(_field_values(fd))
        if value is None:
            continue
        if fd.is_repeated:
            getattr(msg, fd.name).extend(value)
        else:
            setattr(msg, fd.name, value)
    return msg


def _breaks_a_rule(msg: m.Message) -> bool:
    for fd in msg.DESCRIPTOR.fields:
        values = list(getattr(msg, fd.name)) if fd.is_repeated else [getattr(msg, fd.name)]
        if fd.type == FieldDescriptor.TYPE_DOUBLE and not all(math.isfinite(v) for v in values):
            return True
        is_stamp = fd.name == "stamp" or fd.name.endswith("_stamp")
        if is_stamp and fd.type == FieldDescriptor.TYPE_DOUBLE and not 0 <= values[0] < 2**32:
            return True  # a time Foxglove cannot show (its seconds are a uint32)
        known = fd.enum_type.values_by_number if fd.enum_type else {}
        if fd.type == FieldDescriptor.TYPE_ENUM and any(v not in known or v == 0 for v in values):
            return True
        opts = fd.GetOptions()
        if fd.is_repeated and opts.HasExtension(m.pb.length) and len(values) != opts.Extensions[m.pb.length]:
            return True
        if fd.is_repeated and opts.HasExtension(m.pb.length_multiple):
            if len(values) % opts.Extensions[m.pb.length_multiple]:
                return True
    return False


@CASES
@given(any_message())
def test_well_formed_bytes_with_any_values(msg: m.Message) -> None:
    """Any field values: decode refuses exactly the messages that break a rule, and returns the others."""
    data = msg.SerializeToString()
    if _breaks_a_rule(msg):
        with pytest.raises(m.MessageError, match=type(msg).__name__):
            m.decode(data, type(msg))
    else:
        assert m.decode(data, type(msg)) == msg
