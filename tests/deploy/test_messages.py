"""The message schema: every type round-trips; bad bytes give errors that name the problem."""

import dataclasses

import msgpack
import numpy as np
import pytest

from deploy import messages as m

SAMPLES = [
    m.RobotState(
        seq=3, q=[0.1] * 7, dq=[0.0] * 7, ee_pos=[0.3, 0.0, 0.5], mode="held", chunk_seq=4, queue_len=2
    ),
    m.Target(position=[0.5, 0.1, 0.2], velocity=[0.01, 0, 0], valid=True, frame_stamp=12.5),
    m.CameraFrame(width=2, height=1, rgb=bytes(6), depth=bytes(4), intrinsics=[600, 600, 1, 0.5]),
    m.AnnotatedImage(jpeg=b"\xff\xd8", detected=True),
    m.ActionChunk(chunk_seq=9, actions=np.full(6, 0.01), segment=2),
    m.ChunkStatus(chunk_seq=9, executed=4, dropped=6, preempted_by=10, done=True),
    m.RetreatEvent(segment=1, H=12, reason="retreat", statistic=[0.5, -0.1], threshold=0.01, global_step=99),
    m.SafetyEvent(kind="watchdog", detail="no command", held=True),
    m.LearnerTelemetry(global_step=10, episode=1, episode_return=-3.5, algo="adaptiveh"),
    m.Control(command="jog", jog=[0.01, 0, 0], token="abc"),
    m.ResetRequest(seed=7),
    m.ResetReply(ok=True, state=m.RobotState(q=[0.0] * 7, dq=[0.0] * 7).encode()),
]


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda x: type(x).__name__)
def test_round_trip(msg):
    back = m.decode(msg.encode(), type(msg))
    assert type(back) is type(msg)
    for f in dataclasses.fields(msg):
        a, b = getattr(msg, f.name), getattr(back, f.name)
        if isinstance(a, np.ndarray):
            np.testing.assert_allclose(a, b)
        else:
            assert a == b, f.name


def test_every_type_is_sampled():
    assert {type(s).__name__ for s in SAMPLES} == set(m.MESSAGE_TYPES)


def test_chunk_array_shape():
    chunk = m.decode(m.ActionChunk(actions=[0.0] * 9).encode(), m.ActionChunk)
    assert chunk.action_array().shape == (3, 3)
    with pytest.raises(m.MessageError, match="multiple of 3"):
        m.ActionChunk(actions=[0.0] * 4).action_array()


def raw(**payload) -> bytes:
    return msgpack.packb(payload, use_bin_type=True)


@pytest.mark.parametrize(
    ("data", "expected", "needle"),
    [
        (b"\xc1\x00garbage", None, "undecodable"),
        (raw(x=1), None, "type tag"),
        (raw(_t="Nope", _v=1), None, "unknown message type"),
        (raw(_t="Target", _v=99), None, "schema version"),
        (m.Target().encode(), m.RobotState, "expected RobotState"),
        (raw(_t="Target", _v=1, position=[0, 0]), None, r"Target.position: expected 3 values"),
        (raw(_t="Target", _v=1, position=[0, float("nan"), 0]), None, "NaN"),
        (raw(_t="Control", _v=1, command=5), None, "Control.command: expected text"),
        (raw(_t="ChunkStatus", _v=1, executed=1.5), None, "ChunkStatus.executed: expected an integer"),
        (raw(_t="SafetyEvent", _v=1, held="yes"), None, "SafetyEvent.held"),
        (raw(_t="ResetRequest", _v=1, seed=1, extra=2), None, "unknown fields"),
    ],
)
def test_bad_bytes_give_clear_errors(data, expected, needle):
    with pytest.raises(m.MessageError, match=needle):
        m.decode(data, expected)


def test_key_expressions():
    assert m.key("panda", m.CMD_CHUNK) == "adaptiveh/panda/cmd/chunk"
