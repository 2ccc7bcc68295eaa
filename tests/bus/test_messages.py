"""The message schema: every type round-trips; bad bytes give errors that name the field."""

import math

import numpy as np
import pytest

from bus import messages as m

SAMPLES = [
    m.RobotState(
        seq=3,
        q=[0.1] * 7,
        dq=[0.0] * 7,
        ee_pos=[0.3, 0.0, 0.5],
        ee_vel=[0.0, 0.01, 0.0],
        ee_cmd=[0.3, 0.0, 0.5],
        mode=m.RobotState.HELD,
        chunk_seq=4,
        queue_len=2,
    ),
    m.Target(
        position=[0.5, 0.1, 0.2],
        velocity=[0.01, 0, 0],
        covariance=[1e-6] * 9,
        valid=True,
        frame_stamp=12.5,
        status=m.Target.COASTING,
    ),
    m.CameraFrame(width=2, height=1, rgb=bytes(6), depth=bytes(4), intrinsics=[600, 600, 1, 0.5]),
    m.AnnotatedImage(jpeg=b"\xff\xd8", detected=True),
    m.ActionChunk(seq=9, actions=np.full(6, 0.01), segment=2, opened_by=m.ActionChunk.RETREAT),
    m.ChunkStatus(
        chunk_seq=9,
        executed=4,
        dropped=6,
        preempted_by=10,
        done=True,
        session="ab",
        verdict=1,
        segment=2,
        opened_by=m.ActionChunk.FIRST,
        preempted_by_opening=m.ActionChunk.RETREAT,
    ),
    m.RetreatEvent(
        segment=1, H=12, reason=m.SegmentEnd.RETREAT, statistic=[0.5, -0.1], threshold=0.01, global_step=99
    ),
    m.SafetyEvent(kind=m.SafetyEvent.WATCHDOG, detail="no command", held=True),
    m.LearnerTelemetry(global_step=10, episode=1, episode_return=-3.5, algo="adaptiveh"),
    m.Control(command=m.Control.JOG, jog=[0.01, 0, 0], mac=b"\x01" * 32),
    m.ResetRequest(seed=7),
    m.ResetReply(
        ok=True,
        state=m.RobotState(
            q=[0.0] * 7,
            dq=[0.0] * 7,
            ee_pos=[0.3, 0, 0.5],
            ee_vel=[0, 0, 0],
            ee_cmd=[0.3, 0, 0.5],
            mode=m.RobotState.RUNNING,
        ),
    ),
    m.Rejected(key="adaptiveh/panda/cmd/chunk", error="bad", data=b"\x00\x01"),
    m.PolicySnapshot(
        version=40,
        state_dim=2,
        action_dim=1,
        policy_centers=[0.1, 0.2],
        policy_weights=[0.3],
        field_centers=[],
        field_weights=[],
        sigma=[0.2],
    ),
    m.Transition(
        step=5,
        episode=1,
        segment=2,
        obs=[0.1, 0.2],
        raw_action=[0.3],
        noise=[0.01],
        reward=-0.5,
        next_obs=[0.2, 0.2],
        predicted=[0.21, 0.2],
        end=m.SegmentEnd.RETREAT,
        policy_version=40,
        statistic=0.2,
        target_age=0.12,
        stream="a1b2c3d4",
        first_kept=3,
    ),
    m.TransitionAck(stream="a1b2c3d4", learned=6, saved=4, learner="e5f6"),
]


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda x: type(x).__name__)
def test_round_trip(msg):
    back = m.decode(msg.SerializeToString(), type(msg))
    assert type(back) is type(msg)
    assert back == msg
    assert back.SerializeToString() == msg.SerializeToString()


def test_every_type_is_sampled():
    assert {type(s) for s in SAMPLES} == set(m.MESSAGE_TYPES)


def test_every_topic_binds_one_schema_type():
    assert {t.type for t in m.TOPICS.values()} <= set(m.MESSAGE_TYPES)
    assert m.topic_of_key("adaptiveh/panda/cmd/chunk") is m.CMD_CHUNK
    assert m.topic_of_key("adaptiveh/panda/nope") is None
    assert m.topic_of_key("other/panda/state") is None


def test_chunk_array_shape():
    chunk = m.CMD_CHUNK.decode(
        m.ActionChunk(actions=[0.0] * 9, opened_by=m.ActionChunk.FIRST).SerializeToString()
    )
    assert m.action_array(chunk).shape == (3, 3)
    four = m.ActionChunk(actions=[0.0] * 4, opened_by=m.ActionChunk.FIRST).SerializeToString()
    with pytest.raises(m.MessageError, match="ActionChunk.actions: 4 values is not a multiple of 3"):
        m.CMD_CHUNK.decode(four)


def test_frame_images_check_sizes():
    frame = m.CameraFrame(width=2, height=1, rgb=bytes(6), depth=bytes(4), intrinsics=[1, 1, 1, 1])
    rgb, depth = m.frame_images(frame)
    assert rgb.shape == (1, 2, 3) and depth.shape == (1, 2)
    frame.depth = bytes(3)
    with pytest.raises(m.MessageError, match="needs 6 rgb and 4 depth bytes"):
        m.frame_images(frame)


def test_enum_names_match_the_libraries_strings():
    state = m.RobotState(mode=m.enum(m.RobotState, "mode", "estop"))
    assert m.label(state, "mode") == "estop"
    assert m.enum(m.SafetyEvent, "kind", "camera_error") == m.SafetyEvent.CAMERA_ERROR
    with pytest.raises(
        m.MessageError, match=r"SafetyEvent.kind: unknown value 'melted'; allowed: \['workspace'"
    ):
        m.enum(m.SafetyEvent, "kind", "melted")
    with pytest.raises(m.MessageError, match="unknown value"):
        m.enum(m.RobotState, "mode", "mode_unspecified")  # the zero value means "not set"


GOOD_STATE = SAMPLES[0]


def _state(**change) -> bytes:
    msg = m.RobotState()
    msg.CopyFrom(GOOD_STATE)
    for name, value in change.items():
        if isinstance(value, list):
            msg.ClearField(name)
            getattr(msg, name).extend(value)
        else:
            setattr(msg, name, value)
    return msg.SerializeToString()


@pytest.mark.parametrize(
    ("data", "cls", "needle"),
    [
        (b"\xff\xff\xff", m.RobotState, "RobotState: undecodable"),
        (_state(ee_pos=[0.0, 0.0]), m.RobotState, r"RobotState.ee_pos: expected 3 values, got 2"),
        (_state(ee_vel=[0.0, math.nan, 0.0]), m.RobotState, r"RobotState.ee_vel: contains NaN or inf"),
        (_state(q=[0.0] * 6 + [math.inf]), m.RobotState, r"RobotState.q: contains NaN or inf"),
        (_state(mode=0), m.RobotState, r"RobotState.mode: not set; allowed: \['running'"),
        (_state(mode=42), m.RobotState, r"RobotState.mode: unknown value 42"),
        (m.ActionChunk(actions=[0.0] * 4).SerializeToString(), m.ActionChunk, "not a multiple of 3"),
        (m.Control(command=m.Control.JOG, jog=[0, 0]).SerializeToString(), m.Control, "Control.jog"),
        (m.Control(jog=[0, 0, 0]).SerializeToString(), m.Control, "Control.command: not set"),
        # A RobotState's fields 6-9 do not exist in a ResetRequest: refused, not silently ignored.
        (GOOD_STATE.SerializeToString(), m.ResetRequest, r"ResetRequest: unknown field number\(s\)"),
        (
            m.ResetReply(ok=True, state=m.RobotState(ee_pos=[1.0])).SerializeToString(),
            m.ResetReply,
            r"ResetReply.state.ee_pos: expected 3 values",
        ),
    ],
)
def test_bad_bytes_give_errors_that_name_the_field(data, cls, needle):
    with pytest.raises(m.MessageError, match=needle):
        m.decode(data, cls)


def test_key_expressions():
    assert m.CMD_CHUNK.key("panda") == "adaptiveh/panda/cmd/chunk"
    assert m.RESET.key("arm2") == "adaptiveh/arm2/reset"
    assert m.key("panda", "alive/learner") == "adaptiveh/panda/alive/learner"
