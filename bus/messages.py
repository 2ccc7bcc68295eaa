"""The message schema's Python face: typed topics, strict decoding, and small numpy helpers.

The messages themselves are defined once, in ``bus/schema/adaptiveh.proto`` (protobuf: the same
schema serves the wire, the MCAP recordings and Foxglove); this module re-exports the generated
classes. Each topic binds a key to its type once (``STATE = Topic("state", RobotState)``), so a
publisher cannot put the wrong type on a key and a subscriber never names the type again.

Protobuf's parser is lenient (unknown fields are kept, NaN is a valid double, any integer is a valid
enum), so :func:`decode` adds the checks a robot needs: no unknown fields, every double finite, every
enum set to a known value, vector lengths as the schema's ``length`` options declare, every stamp a time
Foxglove can show. Its
``MessageError`` names the field, so a node logs it and keeps running.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np
from google.protobuf import descriptor_pb2, unknown_fields
from google.protobuf.descriptor import FieldDescriptor, FileDescriptor
from google.protobuf.message import DecodeError
from google.protobuf.message import Message as Message

from bus.schema import adaptiveh_pb2 as pb
from bus.schema.adaptiveh_pb2 import (
    ActionChunk,
    AnnotatedImage,
    CameraFrame,
    ChunkStatus,
    Control,
    LearnerTelemetry,
    PolicySnapshot,
    ResetReply,
    ResetRequest,
    RetreatEvent,
    RobotState,
    SafetyEvent,
    Target,
    Transition,
    TransitionAck,
)
from common.errors import AdaptiveHError

SegmentEnd = pb.SegmentEnd  # how a segment stands (Transition.end, RetreatEvent.reason): one vocabulary
Rejected = pb.Rejected  # recordings only: bytes that did not decode as their key's type
NAMESPACE = "adaptiveh"
LIVELINESS = "alive"
M = TypeVar("M", bound=Message)
R = TypeVar("R", bound=Message)


class MessageError(AdaptiveHError, ValueError):
    """Bytes that are not a valid message of the expected type; the text names the field. ``reason``
    groups errors for rate-limited reporting: undecodable, invalid, forged, replayed."""

    def __init__(self, text: str, reason: str = "invalid") -> None:
        super().__init__(text)
        self.reason = reason


def key(robot: str, topic: str) -> str:
    """Zenoh key expression for ``topic`` of ``robot`` (``adaptiveh/<robot>/<topic>``)."""
    return f"{NAMESPACE}/{robot}/{topic}"


@dataclass(frozen=True)
class Topic(Generic[M]):
    """A key suffix bound to the one message type that travels on it, and how urgently it travels:
    ``urgent`` topics (the operator's commands, safety events) go at Zenoh's real-time priority, ahead of
    the state and camera traffic that congests a busy link; ``never_drop`` ones make the publisher wait
    for queue space rather than lose the message (only for rare messages put outside the control loop).
    ``kept``: the publisher keeps its newest this many messages, so a subscriber that missed some (a
    recorder stopped for seconds) asks for them back (Zenoh's advanced publisher: cache, heartbeat);
    0 for the camera's images, too big to keep and replaced by the next one anyway. ``fleet``: the topic
    is the fleet's (``adaptiveh/<name>/…``: the learner's, one for all arms), not an arm's
    (``adaptiveh/<name>/<arm>/…`` in a fleet; the same key when the stack has one arm).
    """

    name: str
    type: type[M]
    urgent: bool = False
    never_drop: bool = False
    kept: int = 0
    fleet: bool = False

    def key(self, robot: str) -> str:
        return key(robot, self.name)

    def decode(self, data: bytes | bytearray | memoryview) -> M:
        return decode(data, self.type)


@dataclass(frozen=True)
class Service(Generic[M, R]):
    """A queryable: a key bound to its request and reply types."""

    name: str
    request: type[M]
    reply: type[R]

    def key(self, robot: str) -> str:
        return key(robot, self.name)


# The topics of DESIGN section 6, each bound to its type once.
KEPT = 1024  # ~20 s of states at 50 Hz: a recorder stopped that long still gets every one back
STATE = Topic("state", RobotState, kept=KEPT)
TARGET = Topic("target", Target, kept=KEPT)
CAMERA = Topic("camera/frame", CameraFrame)
CAMERA_ANNOTATED = Topic("camera/annotated", AnnotatedImage)
CMD_CHUNK = Topic("cmd/chunk", ActionChunk, kept=KEPT)
CHUNK_STATUS = Topic("cmd/status", ChunkStatus, kept=KEPT)
EVENTS_RETREAT = Topic("events/retreat", RetreatEvent, kept=KEPT, fleet=True)
EVENTS_SAFETY = Topic("events/safety", SafetyEvent, urgent=True, kept=KEPT)
TELEMETRY_LEARNER = Topic("telemetry/learner", LearnerTelemetry, kept=KEPT, fleet=True)
CONTROL = Topic("control", Control, urgent=True, never_drop=True, kept=KEPT)
# The operator's commands to every arm at once (E-STOP all) and to the learner (pause, resume); with one
# arm the same key as CONTROL.
FLEET_CONTROL = Topic("control", Control, urgent=True, never_drop=True, kept=KEPT, fleet=True)
# Simulation only: the target's ground truth, for the sim camera, tests and benchmarks (the learner's
# observation only when a test asks for it with ``learner.target_topic``).
TARGET_TRUTH = Topic("sim/target_truth", Target, kept=KEPT)
# The actor beside the arm and the learner anywhere (deploy.actor_node): the policy one way, every executed
# tick the other. Snapshots are rare and must not be lost; the stream is kept so a stalled reader catches up.
POLICY = Topic("policy/snapshot", PolicySnapshot, never_drop=True, kept=8, fleet=True)
TRANSITIONS = Topic("stream/transition", Transition, kept=KEPT, fleet=True)
# The learner's account of each actor's stream: what it learned and checkpointed (deploy.transition_stream).
TRANSITION_ACKS = Topic("stream/ack", TransitionAck, fleet=True)
RESET = Service("reset", ResetRequest, ResetReply)

TOPICS: dict[str, Topic[Any]] = {}
for _t in [t for t in list(globals().values()) if isinstance(t, Topic)]:
    TOPICS.setdefault(_t.name, _t)  # by name: CONTROL and FLEET_CONTROL are one message on two keys
MESSAGE_TYPES = tuple(getattr(pb, name) for name in pb.DESCRIPTOR.message_types_by_name)


def topic_of_key(k: str) -> Topic[Any] | None:
    """The topic of ``adaptiveh/<robot>/<topic>`` or of an arm's ``adaptiveh/<robot>/<arm>/<topic>``
    (an arm is never named like a topic's first part: ``deploy.config.ArmConfig``), or None for a key
    outside the schema."""
    parts = k.split("/", 3)
    if len(parts) < 3 or parts[0] != NAMESPACE:
        return None
    found = TOPICS.get("/".join(parts[2:]))
    return found if found is not None or len(parts) < 4 else TOPICS.get(parts[3])


TOPIC_ROOTS = frozenset(t.name.split("/")[0] for t in TOPICS.values()) | {LIVELINESS, "reset"}
"""First key parts of the schema's topics: an arm's name must be none of them."""


# -- strict decoding ----------------------------------------------------------------------------------
_FLOATS = (FieldDescriptor.TYPE_DOUBLE, FieldDescriptor.TYPE_FLOAT)
STAMP_MAX_S = 2.0**32  # Foxglove's Timestamp holds seconds in a uint32: a later stamp cannot be shown


def _is_stamp(fd: FieldDescriptor) -> bool:
    return fd.type in _FLOATS and not fd.is_repeated and (fd.name == "stamp" or fd.name.endswith("_stamp"))


def _check_length(fd: FieldDescriptor, values: Sequence[Any], where: str) -> None:
    opts = fd.GetOptions()
    if opts.HasExtension(pb.length) and len(values) != opts.Extensions[pb.length]:
        raise MessageError(f"{where}: expected {opts.Extensions[pb.length]} values, got {len(values)}")
    multiple = opts.Extensions[pb.length_multiple] if opts.HasExtension(pb.length_multiple) else 0
    if multiple and len(values) % multiple:
        raise MessageError(f"{where}: {len(values)} values is not a multiple of {multiple}")


def _check_enum(fd: FieldDescriptor, values: Sequence[int], where: str) -> None:
    known = fd.enum_type.values_by_number
    for v in values:
        if v == 0 or v not in known:
            allowed = [e.name.lower() for e in fd.enum_type.values if e.number != 0]
            raise MessageError(
                f"{where}: {'not set' if v == 0 else f'unknown value {v}'}; allowed: {allowed}"
            )


def validate(msg: Message, where: str | None = None) -> None:
    """Raise MessageError if ``msg`` breaks a rule protobuf itself does not enforce (see module doc)."""
    where = where or type(msg).__name__
    unknown = unknown_fields.UnknownFieldSet(msg)
    if len(unknown):
        raise MessageError(f"{where}: unknown field number(s) {sorted({f.field_number for f in unknown})}")
    for fd in msg.DESCRIPTOR.fields:
        value = getattr(msg, fd.name)
        path = f"{where}.{fd.name}"
        values = list(value) if fd.is_repeated else [value]
        if fd.is_repeated:
            _check_length(fd, values, path)
        if fd.type in _FLOATS and not all(math.isfinite(x) for x in values):
            raise MessageError(f"{path}: contains NaN or inf")
        if _is_stamp(fd) and not 0.0 <= value < STAMP_MAX_S:
            raise MessageError(f"{path}: {value!r} s is not a time in [0, 2^32) s")
        if fd.type == FieldDescriptor.TYPE_ENUM:
            _check_enum(fd, values, path)
        if fd.type == FieldDescriptor.TYPE_MESSAGE:
            present = values if fd.is_repeated else ([value] if msg.HasField(fd.name) else [])
            for i, sub in enumerate(present):
                validate(sub, f"{path}[{i}]" if fd.is_repeated else path)


def says_estop(data: bytes | bytearray | memoryview) -> bool:
    """``data`` parses as a ``Control`` whose command is an e-stop, whatever else is wrong with it (fields
    of the wrong length, NaNs, unknown fields, no or a wrong mac): a stop request is never refused."""
    msg = Control()
    try:
        msg.ParseFromString(bytes(data))
    except DecodeError:
        return False
    return msg.command == Control.ESTOP


def decode(data: bytes | bytearray | memoryview, cls: type[M]) -> M:
    """Parse and validate ``data`` as ``cls``; every failure is a MessageError naming the field."""
    msg = cls()
    try:
        msg.ParseFromString(bytes(data))
    except DecodeError as exc:
        raise MessageError(f"{cls.__name__}: undecodable ({len(data)} bytes): {exc}", "undecodable") from None
    validate(msg)
    return msg


# -- enums as the libraries' lower-case names ---------------------------------------------------------
def label(msg: Message, field: str) -> str:
    """The lower-case name of an enum field's value (``RobotState.mode`` → ``"running"``)."""
    fd = msg.DESCRIPTOR.fields_by_name[field]
    value = fd.enum_type.values_by_number.get(getattr(msg, field))
    return value.name.lower() if value is not None else "unknown"


def enum(cls: type[Message], field: str, name: str) -> int:
    """The number of ``name`` (any case) in an enum field of ``cls``; MessageError if it is not one."""
    fd = cls.DESCRIPTOR.fields_by_name[field]
    value = fd.enum_type.values_by_name.get(name.upper())
    if value is None or value.number == 0:
        allowed = [e.name.lower() for e in fd.enum_type.values if e.number != 0]
        raise MessageError(f"{cls.__name__}.{field}: unknown value {name!r}; allowed: {allowed}")
    return value.number


def file_descriptor_set(msg_type: type[Message]) -> bytes:
    """The serialized ``FileDescriptorSet`` of ``msg_type``'s file and everything it imports."""
    fds = descriptor_pb2.FileDescriptorSet()
    seen: set[str] = set()

    def add(fd: FileDescriptor) -> None:
        if fd.name in seen:
            return
        for dep in fd.dependencies:
            add(dep)
        seen.add(fd.name)
        fd.CopyToProto(fds.file.add())

    add(msg_type.DESCRIPTOR.file)
    return fds.SerializeToString()


# -- numpy views ---------------------------------------------------------------------------------------
def action_array(chunk: ActionChunk) -> np.ndarray:
    """The chunk's actions as an N x 3 array (metres per control period); decoding checked the length."""
    return np.asarray(chunk.actions, dtype=float).reshape(-1, 3)


def frame_images(frame: CameraFrame) -> tuple[np.ndarray, np.ndarray]:
    """(rgb uint8 HxWx3, depth float32 HxW metres); MessageError when the sizes do not match."""
    n = frame.width * frame.height
    if len(frame.rgb) != 3 * n or len(frame.depth) != 2 * n:
        raise MessageError(
            f"CameraFrame: {frame.width}x{frame.height} needs {3 * n} rgb and {2 * n} depth bytes, "
            f"got {len(frame.rgb)} and {len(frame.depth)}"
        )
    rgb = np.frombuffer(frame.rgb, np.uint8).reshape(frame.height, frame.width, 3)
    depth = np.frombuffer(frame.depth, np.uint16).reshape(frame.height, frame.width)
    return rgb, depth.astype(np.float32) * frame.depth_scale
