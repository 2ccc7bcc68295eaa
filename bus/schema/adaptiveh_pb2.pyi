from google.protobuf import descriptor_pb2 as _descriptor_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class SegmentEnd(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SEGMENT_END_UNSPECIFIED: _ClassVar[SegmentEnd]
    RETREAT: _ClassVar[SegmentEnd]
    H_MAX: _ClassVar[SegmentEnd]
    EPISODE_END: _ClassVar[SegmentEnd]
    OPEN: _ClassVar[SegmentEnd]
SEGMENT_END_UNSPECIFIED: SegmentEnd
RETREAT: SegmentEnd
H_MAX: SegmentEnd
EPISODE_END: SegmentEnd
OPEN: SegmentEnd
LENGTH_FIELD_NUMBER: _ClassVar[int]
length: _descriptor.FieldDescriptor
LENGTH_MULTIPLE_FIELD_NUMBER: _ClassVar[int]
length_multiple: _descriptor.FieldDescriptor

class RobotState(_message.Message):
    __slots__ = ("seq", "stamp", "q", "dq", "ee_pos", "ee_vel", "mode", "chunk_seq", "queue_len", "tick", "played_chunk", "played_index", "session", "chunk_stamp", "played_stamp", "mac", "instance", "ee_cmd")
    class Mode(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        MODE_UNSPECIFIED: _ClassVar[RobotState.Mode]
        RUNNING: _ClassVar[RobotState.Mode]
        PAUSED: _ClassVar[RobotState.Mode]
        HELD: _ClassVar[RobotState.Mode]
        ESTOP: _ClassVar[RobotState.Mode]
        FAULT: _ClassVar[RobotState.Mode]
    MODE_UNSPECIFIED: RobotState.Mode
    RUNNING: RobotState.Mode
    PAUSED: RobotState.Mode
    HELD: RobotState.Mode
    ESTOP: RobotState.Mode
    FAULT: RobotState.Mode
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    Q_FIELD_NUMBER: _ClassVar[int]
    DQ_FIELD_NUMBER: _ClassVar[int]
    EE_POS_FIELD_NUMBER: _ClassVar[int]
    EE_VEL_FIELD_NUMBER: _ClassVar[int]
    MODE_FIELD_NUMBER: _ClassVar[int]
    CHUNK_SEQ_FIELD_NUMBER: _ClassVar[int]
    QUEUE_LEN_FIELD_NUMBER: _ClassVar[int]
    TICK_FIELD_NUMBER: _ClassVar[int]
    PLAYED_CHUNK_FIELD_NUMBER: _ClassVar[int]
    PLAYED_INDEX_FIELD_NUMBER: _ClassVar[int]
    SESSION_FIELD_NUMBER: _ClassVar[int]
    CHUNK_STAMP_FIELD_NUMBER: _ClassVar[int]
    PLAYED_STAMP_FIELD_NUMBER: _ClassVar[int]
    MAC_FIELD_NUMBER: _ClassVar[int]
    INSTANCE_FIELD_NUMBER: _ClassVar[int]
    EE_CMD_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    q: _containers.RepeatedScalarFieldContainer[float]
    dq: _containers.RepeatedScalarFieldContainer[float]
    ee_pos: _containers.RepeatedScalarFieldContainer[float]
    ee_vel: _containers.RepeatedScalarFieldContainer[float]
    mode: RobotState.Mode
    chunk_seq: int
    queue_len: int
    tick: int
    played_chunk: int
    played_index: int
    session: str
    chunk_stamp: float
    played_stamp: float
    mac: bytes
    instance: str
    ee_cmd: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., q: _Optional[_Iterable[float]] = ..., dq: _Optional[_Iterable[float]] = ..., ee_pos: _Optional[_Iterable[float]] = ..., ee_vel: _Optional[_Iterable[float]] = ..., mode: _Optional[_Union[RobotState.Mode, str]] = ..., chunk_seq: _Optional[int] = ..., queue_len: _Optional[int] = ..., tick: _Optional[int] = ..., played_chunk: _Optional[int] = ..., played_index: _Optional[int] = ..., session: _Optional[str] = ..., chunk_stamp: _Optional[float] = ..., played_stamp: _Optional[float] = ..., mac: _Optional[bytes] = ..., instance: _Optional[str] = ..., ee_cmd: _Optional[_Iterable[float]] = ...) -> None: ...

class Target(_message.Message):
    __slots__ = ("seq", "stamp", "position", "velocity", "covariance", "valid", "frame_stamp", "status", "mac")
    class Status(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        STATUS_UNSPECIFIED: _ClassVar[Target.Status]
        TRACKING: _ClassVar[Target.Status]
        COASTING: _ClassVar[Target.Status]
        LOST: _ClassVar[Target.Status]
        NONE: _ClassVar[Target.Status]
    STATUS_UNSPECIFIED: Target.Status
    TRACKING: Target.Status
    COASTING: Target.Status
    LOST: Target.Status
    NONE: Target.Status
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    POSITION_FIELD_NUMBER: _ClassVar[int]
    VELOCITY_FIELD_NUMBER: _ClassVar[int]
    COVARIANCE_FIELD_NUMBER: _ClassVar[int]
    VALID_FIELD_NUMBER: _ClassVar[int]
    FRAME_STAMP_FIELD_NUMBER: _ClassVar[int]
    STATUS_FIELD_NUMBER: _ClassVar[int]
    MAC_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    position: _containers.RepeatedScalarFieldContainer[float]
    velocity: _containers.RepeatedScalarFieldContainer[float]
    covariance: _containers.RepeatedScalarFieldContainer[float]
    valid: bool
    frame_stamp: float
    status: Target.Status
    mac: bytes
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., position: _Optional[_Iterable[float]] = ..., velocity: _Optional[_Iterable[float]] = ..., covariance: _Optional[_Iterable[float]] = ..., valid: _Optional[bool] = ..., frame_stamp: _Optional[float] = ..., status: _Optional[_Union[Target.Status, str]] = ..., mac: _Optional[bytes] = ...) -> None: ...

class CameraFrame(_message.Message):
    __slots__ = ("seq", "stamp", "width", "height", "rgb", "depth", "depth_scale", "intrinsics", "frame_stamp")
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    WIDTH_FIELD_NUMBER: _ClassVar[int]
    HEIGHT_FIELD_NUMBER: _ClassVar[int]
    RGB_FIELD_NUMBER: _ClassVar[int]
    DEPTH_FIELD_NUMBER: _ClassVar[int]
    DEPTH_SCALE_FIELD_NUMBER: _ClassVar[int]
    INTRINSICS_FIELD_NUMBER: _ClassVar[int]
    FRAME_STAMP_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    width: int
    height: int
    rgb: bytes
    depth: bytes
    depth_scale: float
    intrinsics: _containers.RepeatedScalarFieldContainer[float]
    frame_stamp: float
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., width: _Optional[int] = ..., height: _Optional[int] = ..., rgb: _Optional[bytes] = ..., depth: _Optional[bytes] = ..., depth_scale: _Optional[float] = ..., intrinsics: _Optional[_Iterable[float]] = ..., frame_stamp: _Optional[float] = ...) -> None: ...

class AnnotatedImage(_message.Message):
    __slots__ = ("seq", "stamp", "jpeg", "detected")
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    JPEG_FIELD_NUMBER: _ClassVar[int]
    DETECTED_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    jpeg: bytes
    detected: bool
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., jpeg: _Optional[bytes] = ..., detected: _Optional[bool] = ...) -> None: ...

class ActionChunk(_message.Message):
    __slots__ = ("seq", "stamp", "actions", "segment", "predicted_ee", "session", "mac", "opened_by")
    class Opening(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        OPENING_UNSPECIFIED: _ClassVar[ActionChunk.Opening]
        NONE: _ClassVar[ActionChunk.Opening]
        FIRST: _ClassVar[ActionChunk.Opening]
        RETREAT: _ClassVar[ActionChunk.Opening]
        H_MAX: _ClassVar[ActionChunk.Opening]
        TARGET_LOST: _ClassVar[ActionChunk.Opening]
        CONTINUE: _ClassVar[ActionChunk.Opening]
    OPENING_UNSPECIFIED: ActionChunk.Opening
    NONE: ActionChunk.Opening
    FIRST: ActionChunk.Opening
    RETREAT: ActionChunk.Opening
    H_MAX: ActionChunk.Opening
    TARGET_LOST: ActionChunk.Opening
    CONTINUE: ActionChunk.Opening
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    ACTIONS_FIELD_NUMBER: _ClassVar[int]
    SEGMENT_FIELD_NUMBER: _ClassVar[int]
    PREDICTED_EE_FIELD_NUMBER: _ClassVar[int]
    SESSION_FIELD_NUMBER: _ClassVar[int]
    MAC_FIELD_NUMBER: _ClassVar[int]
    OPENED_BY_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    actions: _containers.RepeatedScalarFieldContainer[float]
    segment: int
    predicted_ee: _containers.RepeatedScalarFieldContainer[float]
    session: str
    mac: bytes
    opened_by: ActionChunk.Opening
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., actions: _Optional[_Iterable[float]] = ..., segment: _Optional[int] = ..., predicted_ee: _Optional[_Iterable[float]] = ..., session: _Optional[str] = ..., mac: _Optional[bytes] = ..., opened_by: _Optional[_Union[ActionChunk.Opening, str]] = ...) -> None: ...

class ChunkStatus(_message.Message):
    __slots__ = ("seq", "stamp", "chunk_seq", "executed", "dropped", "preempted_by", "done", "session", "verdict", "chunk_stamp", "mac", "segment", "opened_by", "preempted_by_opening")
    class Verdict(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        VERDICT_UNSPECIFIED: _ClassVar[ChunkStatus.Verdict]
        ACCEPTED: _ClassVar[ChunkStatus.Verdict]
        HELD: _ClassVar[ChunkStatus.Verdict]
        BAD_PLAN: _ClassVar[ChunkStatus.Verdict]
        STALE: _ClassVar[ChunkStatus.Verdict]
        FOREIGN: _ClassVar[ChunkStatus.Verdict]
        SEQ_JUMP: _ClassVar[ChunkStatus.Verdict]
        FORGED: _ClassVar[ChunkStatus.Verdict]
    VERDICT_UNSPECIFIED: ChunkStatus.Verdict
    ACCEPTED: ChunkStatus.Verdict
    HELD: ChunkStatus.Verdict
    BAD_PLAN: ChunkStatus.Verdict
    STALE: ChunkStatus.Verdict
    FOREIGN: ChunkStatus.Verdict
    SEQ_JUMP: ChunkStatus.Verdict
    FORGED: ChunkStatus.Verdict
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    CHUNK_SEQ_FIELD_NUMBER: _ClassVar[int]
    EXECUTED_FIELD_NUMBER: _ClassVar[int]
    DROPPED_FIELD_NUMBER: _ClassVar[int]
    PREEMPTED_BY_FIELD_NUMBER: _ClassVar[int]
    DONE_FIELD_NUMBER: _ClassVar[int]
    SESSION_FIELD_NUMBER: _ClassVar[int]
    VERDICT_FIELD_NUMBER: _ClassVar[int]
    CHUNK_STAMP_FIELD_NUMBER: _ClassVar[int]
    MAC_FIELD_NUMBER: _ClassVar[int]
    SEGMENT_FIELD_NUMBER: _ClassVar[int]
    OPENED_BY_FIELD_NUMBER: _ClassVar[int]
    PREEMPTED_BY_OPENING_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    chunk_seq: int
    executed: int
    dropped: int
    preempted_by: int
    done: bool
    session: str
    verdict: ChunkStatus.Verdict
    chunk_stamp: float
    mac: bytes
    segment: int
    opened_by: ActionChunk.Opening
    preempted_by_opening: ActionChunk.Opening
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., chunk_seq: _Optional[int] = ..., executed: _Optional[int] = ..., dropped: _Optional[int] = ..., preempted_by: _Optional[int] = ..., done: _Optional[bool] = ..., session: _Optional[str] = ..., verdict: _Optional[_Union[ChunkStatus.Verdict, str]] = ..., chunk_stamp: _Optional[float] = ..., mac: _Optional[bytes] = ..., segment: _Optional[int] = ..., opened_by: _Optional[_Union[ActionChunk.Opening, str]] = ..., preempted_by_opening: _Optional[_Union[ActionChunk.Opening, str]] = ...) -> None: ...

class RetreatEvent(_message.Message):
    __slots__ = ("seq", "stamp", "segment", "H", "reason", "statistic", "threshold", "global_step", "mac", "arm")
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    SEGMENT_FIELD_NUMBER: _ClassVar[int]
    H_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    STATISTIC_FIELD_NUMBER: _ClassVar[int]
    THRESHOLD_FIELD_NUMBER: _ClassVar[int]
    GLOBAL_STEP_FIELD_NUMBER: _ClassVar[int]
    MAC_FIELD_NUMBER: _ClassVar[int]
    ARM_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    segment: int
    H: int
    reason: SegmentEnd
    statistic: _containers.RepeatedScalarFieldContainer[float]
    threshold: float
    global_step: int
    mac: bytes
    arm: str
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., segment: _Optional[int] = ..., H: _Optional[int] = ..., reason: _Optional[_Union[SegmentEnd, str]] = ..., statistic: _Optional[_Iterable[float]] = ..., threshold: _Optional[float] = ..., global_step: _Optional[int] = ..., mac: _Optional[bytes] = ..., arm: _Optional[str] = ...) -> None: ...

class SafetyEvent(_message.Message):
    __slots__ = ("seq", "stamp", "kind", "detail", "held", "mac")
    class Kind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        KIND_UNSPECIFIED: _ClassVar[SafetyEvent.Kind]
        WORKSPACE: _ClassVar[SafetyEvent.Kind]
        JOINT_LIMIT: _ClassVar[SafetyEvent.Kind]
        VELOCITY_LIMIT: _ClassVar[SafetyEvent.Kind]
        WATCHDOG: _ClassVar[SafetyEvent.Kind]
        ESTOP: _ClassVar[SafetyEvent.Kind]
        PAUSE: _ClassVar[SafetyEvent.Kind]
        RELEASE: _ClassVar[SafetyEvent.Kind]
        LIVELINESS: _ClassVar[SafetyEvent.Kind]
        IK_UNREACHABLE: _ClassVar[SafetyEvent.Kind]
        BAD_MESSAGE: _ClassVar[SafetyEvent.Kind]
        DRIVER_ERROR: _ClassVar[SafetyEvent.Kind]
        BAD_FRAME: _ClassVar[SafetyEvent.Kind]
        CAMERA_ERROR: _ClassVar[SafetyEvent.Kind]
        BAD_PLAN: _ClassVar[SafetyEvent.Kind]
        FOREIGN_COMMAND: _ClassVar[SafetyEvent.Kind]
        TAKEOVER: _ClassVar[SafetyEvent.Kind]
    KIND_UNSPECIFIED: SafetyEvent.Kind
    WORKSPACE: SafetyEvent.Kind
    JOINT_LIMIT: SafetyEvent.Kind
    VELOCITY_LIMIT: SafetyEvent.Kind
    WATCHDOG: SafetyEvent.Kind
    ESTOP: SafetyEvent.Kind
    PAUSE: SafetyEvent.Kind
    RELEASE: SafetyEvent.Kind
    LIVELINESS: SafetyEvent.Kind
    IK_UNREACHABLE: SafetyEvent.Kind
    BAD_MESSAGE: SafetyEvent.Kind
    DRIVER_ERROR: SafetyEvent.Kind
    BAD_FRAME: SafetyEvent.Kind
    CAMERA_ERROR: SafetyEvent.Kind
    BAD_PLAN: SafetyEvent.Kind
    FOREIGN_COMMAND: SafetyEvent.Kind
    TAKEOVER: SafetyEvent.Kind
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    DETAIL_FIELD_NUMBER: _ClassVar[int]
    HELD_FIELD_NUMBER: _ClassVar[int]
    MAC_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    kind: SafetyEvent.Kind
    detail: str
    held: bool
    mac: bytes
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., kind: _Optional[_Union[SafetyEvent.Kind, str]] = ..., detail: _Optional[str] = ..., held: _Optional[bool] = ..., mac: _Optional[bytes] = ...) -> None: ...

class LearnerTelemetry(_message.Message):
    __slots__ = ("seq", "stamp", "global_step", "episode", "episode_return", "success", "paused", "algo", "mac", "started_from")
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    GLOBAL_STEP_FIELD_NUMBER: _ClassVar[int]
    EPISODE_FIELD_NUMBER: _ClassVar[int]
    EPISODE_RETURN_FIELD_NUMBER: _ClassVar[int]
    SUCCESS_FIELD_NUMBER: _ClassVar[int]
    PAUSED_FIELD_NUMBER: _ClassVar[int]
    ALGO_FIELD_NUMBER: _ClassVar[int]
    MAC_FIELD_NUMBER: _ClassVar[int]
    STARTED_FROM_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    global_step: int
    episode: int
    episode_return: float
    success: bool
    paused: bool
    algo: str
    mac: bytes
    started_from: str
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., global_step: _Optional[int] = ..., episode: _Optional[int] = ..., episode_return: _Optional[float] = ..., success: _Optional[bool] = ..., paused: _Optional[bool] = ..., algo: _Optional[str] = ..., mac: _Optional[bytes] = ..., started_from: _Optional[str] = ...) -> None: ...

class Control(_message.Message):
    __slots__ = ("seq", "stamp", "command", "jog", "mac", "arm")
    class Command(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        COMMAND_UNSPECIFIED: _ClassVar[Control.Command]
        PAUSE: _ClassVar[Control.Command]
        RESUME: _ClassVar[Control.Command]
        ESTOP: _ClassVar[Control.Command]
        RELEASE: _ClassVar[Control.Command]
        JOG: _ClassVar[Control.Command]
    COMMAND_UNSPECIFIED: Control.Command
    PAUSE: Control.Command
    RESUME: Control.Command
    ESTOP: Control.Command
    RELEASE: Control.Command
    JOG: Control.Command
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    COMMAND_FIELD_NUMBER: _ClassVar[int]
    JOG_FIELD_NUMBER: _ClassVar[int]
    MAC_FIELD_NUMBER: _ClassVar[int]
    ARM_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    command: Control.Command
    jog: _containers.RepeatedScalarFieldContainer[float]
    mac: bytes
    arm: str
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., command: _Optional[_Union[Control.Command, str]] = ..., jog: _Optional[_Iterable[float]] = ..., mac: _Optional[bytes] = ..., arm: _Optional[str] = ...) -> None: ...

class ResetRequest(_message.Message):
    __slots__ = ("seq", "stamp", "seed", "session", "mac", "next_chunk")
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    SESSION_FIELD_NUMBER: _ClassVar[int]
    MAC_FIELD_NUMBER: _ClassVar[int]
    NEXT_CHUNK_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    seed: int
    session: str
    mac: bytes
    next_chunk: int
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., seed: _Optional[int] = ..., session: _Optional[str] = ..., mac: _Optional[bytes] = ..., next_chunk: _Optional[int] = ...) -> None: ...

class ResetReply(_message.Message):
    __slots__ = ("seq", "stamp", "ok", "detail", "state")
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    OK_FIELD_NUMBER: _ClassVar[int]
    DETAIL_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    ok: bool
    detail: str
    state: RobotState
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., ok: _Optional[bool] = ..., detail: _Optional[str] = ..., state: _Optional[_Union[RobotState, _Mapping]] = ...) -> None: ...

class PolicySnapshot(_message.Message):
    __slots__ = ("seq", "stamp", "version", "state_dim", "action_dim", "policy_centers", "policy_weights", "field_centers", "field_weights", "sigma", "mac")
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    VERSION_FIELD_NUMBER: _ClassVar[int]
    STATE_DIM_FIELD_NUMBER: _ClassVar[int]
    ACTION_DIM_FIELD_NUMBER: _ClassVar[int]
    POLICY_CENTERS_FIELD_NUMBER: _ClassVar[int]
    POLICY_WEIGHTS_FIELD_NUMBER: _ClassVar[int]
    FIELD_CENTERS_FIELD_NUMBER: _ClassVar[int]
    FIELD_WEIGHTS_FIELD_NUMBER: _ClassVar[int]
    SIGMA_FIELD_NUMBER: _ClassVar[int]
    MAC_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    version: int
    state_dim: int
    action_dim: int
    policy_centers: _containers.RepeatedScalarFieldContainer[float]
    policy_weights: _containers.RepeatedScalarFieldContainer[float]
    field_centers: _containers.RepeatedScalarFieldContainer[float]
    field_weights: _containers.RepeatedScalarFieldContainer[float]
    sigma: _containers.RepeatedScalarFieldContainer[float]
    mac: bytes
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., version: _Optional[int] = ..., state_dim: _Optional[int] = ..., action_dim: _Optional[int] = ..., policy_centers: _Optional[_Iterable[float]] = ..., policy_weights: _Optional[_Iterable[float]] = ..., field_centers: _Optional[_Iterable[float]] = ..., field_weights: _Optional[_Iterable[float]] = ..., sigma: _Optional[_Iterable[float]] = ..., mac: _Optional[bytes] = ...) -> None: ...

class Transition(_message.Message):
    __slots__ = ("seq", "stamp", "step", "episode", "segment", "obs", "raw_action", "reward", "next_obs", "terminated", "truncated", "success", "distance", "predicted", "end", "policy_version", "statistic", "target_age", "mac", "noise", "stream", "first_kept", "arm")
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    STEP_FIELD_NUMBER: _ClassVar[int]
    EPISODE_FIELD_NUMBER: _ClassVar[int]
    SEGMENT_FIELD_NUMBER: _ClassVar[int]
    OBS_FIELD_NUMBER: _ClassVar[int]
    RAW_ACTION_FIELD_NUMBER: _ClassVar[int]
    REWARD_FIELD_NUMBER: _ClassVar[int]
    NEXT_OBS_FIELD_NUMBER: _ClassVar[int]
    TERMINATED_FIELD_NUMBER: _ClassVar[int]
    TRUNCATED_FIELD_NUMBER: _ClassVar[int]
    SUCCESS_FIELD_NUMBER: _ClassVar[int]
    DISTANCE_FIELD_NUMBER: _ClassVar[int]
    PREDICTED_FIELD_NUMBER: _ClassVar[int]
    END_FIELD_NUMBER: _ClassVar[int]
    POLICY_VERSION_FIELD_NUMBER: _ClassVar[int]
    STATISTIC_FIELD_NUMBER: _ClassVar[int]
    TARGET_AGE_FIELD_NUMBER: _ClassVar[int]
    MAC_FIELD_NUMBER: _ClassVar[int]
    NOISE_FIELD_NUMBER: _ClassVar[int]
    STREAM_FIELD_NUMBER: _ClassVar[int]
    FIRST_KEPT_FIELD_NUMBER: _ClassVar[int]
    ARM_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    step: int
    episode: int
    segment: int
    obs: _containers.RepeatedScalarFieldContainer[float]
    raw_action: _containers.RepeatedScalarFieldContainer[float]
    reward: float
    next_obs: _containers.RepeatedScalarFieldContainer[float]
    terminated: bool
    truncated: bool
    success: bool
    distance: float
    predicted: _containers.RepeatedScalarFieldContainer[float]
    end: SegmentEnd
    policy_version: int
    statistic: float
    target_age: float
    mac: bytes
    noise: _containers.RepeatedScalarFieldContainer[float]
    stream: str
    first_kept: int
    arm: str
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., step: _Optional[int] = ..., episode: _Optional[int] = ..., segment: _Optional[int] = ..., obs: _Optional[_Iterable[float]] = ..., raw_action: _Optional[_Iterable[float]] = ..., reward: _Optional[float] = ..., next_obs: _Optional[_Iterable[float]] = ..., terminated: _Optional[bool] = ..., truncated: _Optional[bool] = ..., success: _Optional[bool] = ..., distance: _Optional[float] = ..., predicted: _Optional[_Iterable[float]] = ..., end: _Optional[_Union[SegmentEnd, str]] = ..., policy_version: _Optional[int] = ..., statistic: _Optional[float] = ..., target_age: _Optional[float] = ..., mac: _Optional[bytes] = ..., noise: _Optional[_Iterable[float]] = ..., stream: _Optional[str] = ..., first_kept: _Optional[int] = ..., arm: _Optional[str] = ...) -> None: ...

class TransitionAck(_message.Message):
    __slots__ = ("seq", "stamp", "stream", "learned", "saved", "learner", "mac")
    SEQ_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    STREAM_FIELD_NUMBER: _ClassVar[int]
    LEARNED_FIELD_NUMBER: _ClassVar[int]
    SAVED_FIELD_NUMBER: _ClassVar[int]
    LEARNER_FIELD_NUMBER: _ClassVar[int]
    MAC_FIELD_NUMBER: _ClassVar[int]
    seq: int
    stamp: float
    stream: str
    learned: int
    saved: int
    learner: str
    mac: bytes
    def __init__(self, seq: _Optional[int] = ..., stamp: _Optional[float] = ..., stream: _Optional[str] = ..., learned: _Optional[int] = ..., saved: _Optional[int] = ..., learner: _Optional[str] = ..., mac: _Optional[bytes] = ...) -> None: ...

class Rejected(_message.Message):
    __slots__ = ("key", "error", "data")
    KEY_FIELD_NUMBER: _ClassVar[int]
    ERROR_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    key: str
    error: str
    data: bytes
    def __init__(self, key: _Optional[str] = ..., error: _Optional[str] = ..., data: _Optional[bytes] = ...) -> None: ...
