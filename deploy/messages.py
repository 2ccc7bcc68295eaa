"""The message schema: every message that crosses Zenoh, typed and versioned, in one place.

Messages are frozen dataclasses encoded with msgpack as ``{"_t": type, "_v": version, ...fields}``.
Vectors travel as lists of floats, images as bytes. ``decode`` validates the type tag, the version,
every field's type, vector lengths and finiteness, and raises ``MessageError`` with a message that
names the offending field, so a node can log it and keep running.
"""

from __future__ import annotations

import dataclasses
import math
import time
import typing
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

import msgpack
import numpy as np

SCHEMA_VERSION = 1
NAMESPACE = "adaptiveh"


class MessageError(ValueError):
    """Bytes that are not a valid message of the expected type."""


def key(robot: str, topic: str) -> str:
    """Zenoh key expression for ``topic`` of ``robot`` (``adaptiveh/<robot>/<topic>``)."""
    return f"{NAMESPACE}/{robot}/{topic}"


# Topic names of DESIGN section 6.
STATE = "state"
TARGET = "target"
CAMERA = "camera/frame"
# Simulation only: the target's ground-truth pose, for the sim camera, tests and benchmarks (never the
# learner's observation unless a test asks for it with ``learner.target_topic``).
TARGET_TRUTH = "sim/target_truth"
CAMERA_ANNOTATED = "camera/annotated"
CMD_CHUNK = "cmd/chunk"
CHUNK_STATUS = "cmd/status"
EVENTS_RETREAT = "events/retreat"
EVENTS_SAFETY = "events/safety"
TELEMETRY_LEARNER = "telemetry/learner"
CONTROL = "control"
RESET = "reset"
LIVELINESS = "alive"


def _now() -> float:
    return time.time()


@dataclass(frozen=True)
class Message:
    """Base: a sequence number and a wall-clock timestamp (seconds since the epoch)."""

    seq: int = 0
    stamp: float = field(default_factory=_now)
    # Vector fields and their required lengths (None: any length); filled by subclasses.
    VECTORS: ClassVar[dict[str, int | None]] = {}

    def encode(self) -> bytes:
        return encode(self)


@dataclass(frozen=True)
class RobotState(Message):
    """What the robot interface publishes at its state rate."""

    q: list[float] = field(default_factory=list)
    dq: list[float] = field(default_factory=list)
    ee_pos: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    ee_vel: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    mode: str = "running"  # running | paused | held | estop
    chunk_seq: int = -1
    queue_len: int = 0
    VECTORS: ClassVar[dict[str, int | None]] = {"q": None, "dq": None, "ee_pos": 3, "ee_vel": 3}


@dataclass(frozen=True)
class Target(Message):
    """The tracked 3D target in the robot base frame; ``valid`` is False when it is lost."""

    position: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    velocity: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    covariance: list[float] = field(default_factory=lambda: [0.0] * 9)
    valid: bool = False
    frame_stamp: float = 0.0
    # tracking: a detection was fused at frame_stamp | coasting: predicted, no fresh fix | lost | none
    status: str = "tracking"
    VECTORS: ClassVar[dict[str, int | None]] = {"position": 3, "velocity": 3, "covariance": 9}


@dataclass(frozen=True)
class CameraFrame(Message):
    """An RGB-D frame: rgb as raw uint8 HxWx3, depth as raw uint16 HxW in units of ``depth_scale`` m."""

    width: int = 0
    height: int = 0
    rgb: bytes = b""
    depth: bytes = b""
    depth_scale: float = 0.001
    intrinsics: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])  # fx, fy, cx, cy
    frame_stamp: float = 0.0
    VECTORS: ClassVar[dict[str, int | None]] = {"intrinsics": 4}

    def images(self) -> tuple[np.ndarray, np.ndarray]:
        """(rgb uint8 HxWx3, depth float32 HxW metres); raises MessageError on a size mismatch."""
        n = self.width * self.height
        if len(self.rgb) != 3 * n or len(self.depth) != 2 * n:
            raise MessageError(
                f"CameraFrame: {self.width}x{self.height} needs {3 * n} rgb and {2 * n} depth bytes, "
                f"got {len(self.rgb)} and {len(self.depth)}"
            )
        rgb = np.frombuffer(self.rgb, np.uint8).reshape(self.height, self.width, 3)
        depth = np.frombuffer(self.depth, np.uint16).reshape(self.height, self.width)
        return rgb, depth.astype(np.float32) * self.depth_scale


@dataclass(frozen=True)
class AnnotatedImage(Message):
    """A downscaled JPEG of the camera image with the detection drawn, for the monitor."""

    jpeg: bytes = b""
    detected: bool = False


@dataclass(frozen=True)
class ActionChunk(Message):
    """Cartesian end-effector displacements (N x 3, metres per control period) to play in order.

    A chunk with a higher ``chunk_seq`` preempts whatever is left of the current one.
    """

    chunk_seq: int = 0
    actions: list[float] = field(default_factory=list)  # flattened N x 3
    segment: int = 0
    VECTORS: ClassVar[dict[str, int | None]] = {"actions": None}

    def action_array(self) -> np.ndarray:
        if len(self.actions) % 3:
            raise MessageError(f"ActionChunk.actions: length {len(self.actions)} is not a multiple of 3")
        return np.asarray(self.actions, dtype=float).reshape(-1, 3)


@dataclass(frozen=True)
class ChunkStatus(Message):
    """The robot's account of a chunk: executed and dropped counts; ``preempted_by`` or -1."""

    chunk_seq: int = 0
    executed: int = 0
    dropped: int = 0
    preempted_by: int = -1
    done: bool = False


@dataclass(frozen=True)
class RetreatEvent(Message):
    """One learner segment: its length H, why it ended, and the retreat statistic trace."""

    segment: int = 0
    H: int = 0
    reason: str = "retreat"  # retreat | h_max | episode_end
    statistic: list[float] = field(default_factory=list)
    threshold: float = 0.0
    global_step: int = 0
    VECTORS: ClassVar[dict[str, int | None]] = {"statistic": None}


@dataclass(frozen=True)
class SafetyEvent(Message):
    """A safety intervention: ``kind`` names the rule, ``held`` says whether the arm is now held."""

    kind: str = ""  # workspace | joint_limit | velocity_limit | watchdog | estop | pause | release
    #                 | liveliness | ik_unreachable | bad_message | driver_error
    detail: str = ""
    held: bool = False


@dataclass(frozen=True)
class LearnerTelemetry(Message):
    """Learner progress for the monitor and recording."""

    global_step: int = 0
    episode: int = 0
    episode_return: float = 0.0
    success: bool = False
    paused: bool = False
    algo: str = ""


@dataclass(frozen=True)
class Control(Message):
    """An operator request; ``token`` must match the one the monitor printed."""

    command: str = ""  # pause | resume | estop | release | jog
    jog: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    token: str = ""
    VECTORS: ClassVar[dict[str, int | None]] = {"jog": 3}

    COMMANDS: ClassVar[frozenset[str]] = frozenset({"pause", "resume", "estop", "release", "jog"})


@dataclass(frozen=True)
class ResetRequest(Message):
    """Ask the robot interface for a new episode: home pose, new target motion from ``seed``."""

    seed: int = 0


@dataclass(frozen=True)
class ResetReply(Message):
    ok: bool = True
    detail: str = ""
    state: bytes = b""  # an encoded RobotState after the reset


MESSAGE_TYPES: dict[str, type[Message]] = {
    cls.__name__: cls
    for cls in (
        RobotState,
        Target,
        CameraFrame,
        AnnotatedImage,
        ActionChunk,
        ChunkStatus,
        RetreatEvent,
        SafetyEvent,
        LearnerTelemetry,
        Control,
        ResetRequest,
        ResetReply,
    )
}

M = TypeVar("M", bound=Message)


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return [float(x) for x in value.ravel()]
    if isinstance(value, (list, tuple)):
        return [float(x) for x in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def encode(msg: Message) -> bytes:
    """Serialize a message (numpy arrays become float lists)."""
    payload = {"_t": type(msg).__name__, "_v": SCHEMA_VERSION}
    for f in dataclasses.fields(msg):
        payload[f.name] = _plain(getattr(msg, f.name))
    return msgpack.packb(payload, use_bin_type=True)


def _check_field(cls: type[Message], name: str, hint: Any, value: Any) -> Any:
    where = f"{cls.__name__}.{name}"
    origin = typing.get_origin(hint)
    if origin is list:
        if not isinstance(value, list) or not all(isinstance(x, (int, float)) for x in value):
            raise MessageError(f"{where}: expected a list of numbers, got {type(value).__name__}")
        want = cls.VECTORS.get(name)
        if want is not None and len(value) != want:
            raise MessageError(f"{where}: expected {want} values, got {len(value)}")
        if not all(math.isfinite(x) for x in value):
            raise MessageError(f"{where}: contains NaN or inf")
        return [float(x) for x in value]
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise MessageError(f"{where}: expected a number, got {type(value).__name__}")
        if not math.isfinite(value):
            raise MessageError(f"{where}: is NaN or inf")
        return float(value)
    if hint is int and (isinstance(value, bool) or not isinstance(value, int)):
        raise MessageError(f"{where}: expected an integer, got {type(value).__name__}")
    if hint is bool and not isinstance(value, bool):
        raise MessageError(f"{where}: expected true/false, got {type(value).__name__}")
    if hint is str and not isinstance(value, str):
        raise MessageError(f"{where}: expected text, got {type(value).__name__}")
    if hint is bytes and not isinstance(value, (bytes, bytearray)):
        raise MessageError(f"{where}: expected bytes, got {type(value).__name__}")
    return value


def decode(data: bytes | bytearray | memoryview, expected: type[M] | None = None) -> M:
    """Parse and validate bytes; ``expected`` restricts the message type."""
    try:
        payload = msgpack.unpackb(bytes(data), raw=False)
    except Exception as exc:  # msgpack raises several unrelated exception types
        raise MessageError(f"undecodable bytes ({len(data)} bytes): {exc}") from None
    if not isinstance(payload, dict) or "_t" not in payload:
        raise MessageError("not a message: missing type tag '_t'")
    name = payload.pop("_t")
    version = payload.pop("_v", None)
    cls = MESSAGE_TYPES.get(name)
    if cls is None:
        raise MessageError(f"unknown message type {name!r}")
    if expected is not None and cls is not expected:
        raise MessageError(f"expected {expected.__name__}, got {name}")
    if version != SCHEMA_VERSION:
        raise MessageError(f"{name}: schema version {version!r}, this build speaks {SCHEMA_VERSION}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(payload) - names
    if unknown:
        raise MessageError(f"{name}: unknown fields {sorted(unknown)}")
    values = {k: _check_field(cls, k, hints[k], v) for k, v in payload.items()}
    return cls(**values)  # type: ignore[return-value]
