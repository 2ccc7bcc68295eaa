"""Foxglove's well-known messages derived from ours: what its 3D, image, plot and log panels read.

Our channels already decode in Foxglove (protobuf with the schema in the file), but its 3D and image
panels only draw Foxglove's own schemas. This module turns our messages into them, with no Zenoh and no
I/O, so the recorder (``monitor.recording``) and the live server (``monitor.foxglove.live``) emit the same
channels from the same messages:

- ``foxglove/camera``: the annotated JPEG as ``foxglove.CompressedImage`` in the ``camera`` frame;
- ``foxglove/tf``: ``foxglove.FrameTransforms`` base -> ee, base -> target, base -> camera (the
  calibrated extrinsics; ``camera_sim`` too when the sim camera is elsewhere) and base -> each link;
- ``foxglove/scene``: ``foxglove.SceneUpdate`` with the target, the executed end-effector path, the
  current plan's predicted path (``ActionChunk.predicted_ee``; none when a chunk carries none) and the
  rest of the last plan a newer one cut short (where a plan went stale and the retreat cut it);
- ``foxglove/robot``: the arm's link meshes, once (``monitor.foxglove.robot_model``);
- ``foxglove/log``: safety events as ``foxglove.Log`` (the Log panel);
- ``foxglove/distance``, ``foxglove/retreat``: JSON (with a JSON schema) for the plots that need a
  value computed across messages: end effector to target distance, and each segment's closing retreat
  statistic against its threshold.

Channels are ``adaptiveh/<robot>/foxglove/...``: beside the robot's raw ones in Foxglove's topic list.
They never travel on Zenoh; replay skips them (``monitor.recording.replayable``).
"""

from __future__ import annotations

import json
import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from foxglove import messages as fm

from bus import messages as m
from monitor.view_limits import ViewLimits

if TYPE_CHECKING:
    from monitor.foxglove.robot_model import ArmPoser
    from vision.config import VisionConfig

SUB = "foxglove/"
IMAGE, TF, SCENE, ROBOT, LOG = "camera", "tf", "scene", "robot", "log"
DISTANCE, RETREAT = "distance", "retreat"
BASE, EE, TARGET, CAMERA, CAMERA_SIM = "base", "ee", "target", "camera", "camera_sim"
PoseTuple = tuple[tuple[float, ...], tuple[float, ...]]  # position, quaternion (x, y, z, w)

DISTANCE_SCHEMA = {
    "title": "adaptiveh.foxglove.Distance",
    "description": "End effector to the latest valid target, per robot state.",
    "type": "object",
    "properties": {"distance": {"type": "number"}, "target_valid": {"type": "boolean"}},
}
RETREAT_SCHEMA = {
    "title": "adaptiveh.foxglove.RetreatPoint",
    "description": "One closed segment: the retreat statistic at its end and at its peak, and the threshold.",
    "type": "object",
    "properties": {
        "segment": {"type": "integer"},
        "H": {"type": "integer"},
        "reason": {"type": "string"},
        "retreat": {"type": "boolean"},
        "statistic": {"type": "number"},
        "statistic_max": {"type": "number"},
        "threshold": {"type": "number"},
        "global_step": {"type": "integer"},
    },
}


def is_derived(key: str) -> bool:
    """Whether a channel is one of ours derived here (``adaptiveh/<robot>/foxglove/...``)."""
    parts = key.split("/", 2)
    return len(parts) == 3 and parts[0] == m.NAMESPACE and parts[2].startswith(SUB)


@dataclass(frozen=True)
class Derived:
    """One derived message, serialized, with what a writer needs to declare its channel."""

    topic: str
    schema_name: str
    schema_encoding: str  # protobuf | jsonschema
    schema_data: bytes
    message_encoding: str  # protobuf | json
    data: bytes


_SCHEMAS: dict[type, Any] = {}


def _proto(topic: str, msg: Any) -> Derived:
    schema = _SCHEMAS.get(type(msg))
    if schema is None:
        schema = _SCHEMAS[type(msg)] = type(msg).get_schema()
    return Derived(topic, schema.name, schema.encoding, bytes(schema.data), "protobuf", msg.encode())


def _json(topic: str, schema: dict[str, Any], value: dict[str, Any]) -> Derived:
    return Derived(
        topic, schema["title"], "jsonschema", json.dumps(schema).encode(), "json", json.dumps(value).encode()
    )


# -- pure conversions -----------------------------------------------------------------------------------
def timestamp(stamp: float) -> fm.Timestamp:
    return fm.Timestamp.from_epoch_secs(max(stamp, 0.0))


def _vec(p: Any) -> fm.Vector3:
    return fm.Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _quat(q: Any) -> fm.Quaternion:
    return fm.Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))


def _point(p: Any) -> fm.Point3:
    return fm.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _color(r: float, g: float, b: float, a: float = 1.0) -> fm.Color:
    return fm.Color(r=r, g=g, b=b, a=a)


IDENTITY = (0.0, 0.0, 0.0, 1.0)
TARGET_COLORS = {"tracking": _color(0.9, 0.1, 0.1), "coasting": _color(1.0, 0.6, 0.0)}


def transform(parent: str, child: str, position: Any, quaternion: Any, stamp: float) -> fm.FrameTransform:
    """The pose of ``child`` in ``parent`` (Foxglove's transform from parent to child)."""
    return fm.FrameTransform(
        timestamp=timestamp(stamp),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=_vec(position),
        rotation=_quat(quaternion),
    )


def compressed_image(a: m.AnnotatedImage) -> fm.CompressedImage:
    """The operator's annotated JPEG, in the camera frame (OpenCV axes, as Foxglove's camera model)."""
    return fm.CompressedImage(
        timestamp=timestamp(a.stamp), frame_id=CAMERA, data=bytes(a.jpeg), format="jpeg"
    )


def target_transforms(t: m.Target) -> fm.FrameTransforms | None:
    """base -> target while the target is valid; None when it is lost (never guessed)."""
    if not t.valid:
        return None
    return fm.FrameTransforms(transforms=[transform(BASE, TARGET, t.position, IDENTITY, t.stamp)])


def safety_log(e: m.SafetyEvent) -> fm.Log:
    """A safety event as a log line: an error for an e-stop or a failing device, a warning when held."""
    kind = m.label(e, "kind")
    level = fm.LogLevel.Info
    if kind in ("estop", "driver_error", "camera_error"):
        level = fm.LogLevel.Error
    elif e.held:
        level = fm.LogLevel.Warning
    text = f"{kind}: {e.detail}" + (" (arm held)" if e.held else "")
    return fm.Log(timestamp=timestamp(e.stamp), level=level, message=text, name="safety")


def retreat_point(e: m.RetreatEvent) -> dict[str, Any]:
    reason = m.label(e, "reason")
    stats = list(e.statistic)
    return {
        "segment": e.segment,
        "H": e.H,
        "reason": reason,
        "retreat": reason == "retreat",
        "statistic": stats[-1] if stats else 0.0,
        "statistic_max": max(stats) if stats else 0.0,
        "threshold": e.threshold,
        "global_step": e.global_step,
    }


def _line(points: list[Any], color: fm.Color, thickness: float) -> fm.LinePrimitive:
    return fm.LinePrimitive(
        type=fm.LinePrimitiveLineType.LineStrip,
        thickness=thickness,
        scale_invariant=True,  # pixels: readable at any zoom
        points=[_point(p) for p in points],
        color=color,
    )


def scene_update(
    stamp: float,
    target: m.Target | None,
    target_size: float,
    executed: list[Any],
    plan: list[Any],
    abandoned: list[Any],
) -> fm.SceneUpdate:
    """The whole scene at ``stamp``: it replaces the previous one (delete all, then these entities)."""
    ts = timestamp(stamp)
    entities = []
    if target is not None and target.valid:
        color = TARGET_COLORS.get(m.label(target, "status"), _color(0.5, 0.5, 0.5))
        size = _vec([2 * target_size] * 3)
        pose = fm.Pose(position=_vec(target.position), orientation=_quat(IDENTITY))
        entities.append(
            fm.SceneEntity(
                timestamp=ts,
                frame_id=BASE,
                id="target",
                cubes=[fm.CubePrimitive(pose=pose, size=size, color=color)],
            )
        )
    for name, points, color, width in (
        ("executed", executed, _color(0.2, 0.5, 1.0), 3.0),
        ("plan", plan, _color(0.1, 0.8, 0.2), 4.0),
        ("abandoned", abandoned, _color(1.0, 0.1, 0.1), 4.0),
    ):
        if len(points) >= 2:
            entities.append(
                fm.SceneEntity(timestamp=ts, frame_id=BASE, id=name, lines=[_line(points, color, width)])
            )
    return fm.SceneUpdate(
        deletions=[fm.SceneEntityDeletion(timestamp=ts, type=fm.SceneEntityDeletionType.All)],
        entities=entities,
    )


def robot_scene(arm: ArmPoser, stamp: float) -> fm.SceneUpdate:
    """The arm's link meshes, each locked to its link frame (moved by the base -> link transforms)."""
    ts = timestamp(stamp)
    grey = _color(0.85, 0.85, 0.88)
    return fm.SceneUpdate(
        entities=[
            fm.SceneEntity(
                timestamp=ts,
                frame_id=mesh.link,
                id=f"robot/{mesh.link}",
                frame_locked=True,
                models=[
                    fm.ModelPrimitive(
                        pose=fm.Pose(position=_vec(mesh.position), orientation=_quat(mesh.quaternion)),
                        scale=fm.Vector3(x=1.0, y=1.0, z=1.0),
                        color=grey,
                        override_color=True,
                        media_type="model/stl",
                        data=mesh.stl,
                    )
                ],
            )
            for mesh in arm.meshes
        ]
    )


# -- configuration and the stateful glue --------------------------------------------------------------
@dataclass(frozen=True)
class SceneSetup:
    """What the scene needs beyond the messages: the camera's pose, the target's size, the arm."""

    camera: PoseTuple | None = None  # camera-to-base (the calibrated extrinsics the pipeline uses)
    camera_sim: PoseTuple | None = None  # where the sim camera really is, when that differs
    target_size: float = 0.025  # half extent, m
    arm: ArmPoser | None = None

    @classmethod
    def from_vision(cls, vision: VisionConfig | None, arm: bool = True) -> SceneSetup:
        """From the stack's vision section (None: no camera): its extrinsics and sim pose, its target
        size; and the Panda's links."""
        from monitor.foxglove.robot_model import ArmPoser

        camera = camera_sim = None
        size = 0.025
        if vision is not None:
            camera = (tuple(vision.extrinsics.position), tuple(vision.extrinsics.quaternion))
            sim = vision.sim_pose()
            if (tuple(sim.position), tuple(sim.quaternion)) != camera:
                camera_sim = (tuple(sim.position), tuple(sim.quaternion))
            size = vision.detection.target_size
        return cls(camera=camera, camera_sim=camera_sim, target_size=size, arm=ArmPoser() if arm else None)


class Deriver:
    """Feeds on our messages in arrival order and returns the derived ones (keeps paths and plans).

    ``scene_every``: a scene update every this many states (and at each new or cut plan): at 20 Hz state,
    4 gives 5 Hz, enough for a path and ~4x cheaper on disk than every tick. ``links_every``: the arm's
    link and the camera transforms every this many states (the ee's at every state): they are most of
    the transform bytes (~1.4 kB a set). ``path_len``: executed end-effector points kept, one every
    other state (100 = 10 s at 20 Hz). ``limits``: a message out of the views' range derives nothing.
    Not thread-safe: callers serialize ``feed``.
    """

    PLANS_KEPT = 4

    def __init__(
        self,
        robot: str,
        setup: SceneSetup | None = None,
        limits: ViewLimits | None = None,
        scene_every: int = 4,
        links_every: int = 2,
        path_len: int = 100,
    ):
        self.robot = robot
        self.setup = setup or SceneSetup()
        self.limits = limits or ViewLimits()
        self.scene_every, self.links_every = scene_every, links_every
        self.executed: deque[list[float]] = deque(maxlen=path_len)
        self.target: m.Target | None = None
        self.ee: list[float] = []
        # (session, seq) -> (starts at the ee, points), the newest PLANS_KEPT in arrival order
        self.plans: dict[tuple[str, int], tuple[bool, list[list[float]]]] = {}
        self.session = ""  # the learner session the arm obeys (its chunks are the ones drawn)
        self.plan: list[list[float]] = []
        self.abandoned: list[list[float]] = []
        self._states = 0
        self.robot_sent = False

    def topic(self, name: str) -> str:
        return f"{m.NAMESPACE}/{self.robot}/{SUB}{name}"

    def feed(self, topic: m.Topic[Any], msg: m.Message) -> list[Derived]:
        """The derived messages ``msg``, received on ``topic``, gives (often none).

        By topic, not by type: the sim's ground-truth target is a ``Target`` too, and is not the target
        the robot chases (it would double the transforms for nothing the operator acts on).
        """
        if self.limits.problem(msg) is not None:
            return []
        if topic == m.STATE:
            return self._state(msg)
        if topic == m.TARGET:
            return self._target(msg)
        if topic == m.CAMERA_ANNOTATED:
            return [_proto(self.topic(IMAGE), compressed_image(msg))]
        if topic == m.CMD_CHUNK:
            return self._chunk(msg)
        if topic == m.CHUNK_STATUS:
            return self._status(msg)
        if topic == m.EVENTS_SAFETY:
            return [_proto(self.topic(LOG), safety_log(msg))]
        if topic == m.EVENTS_RETREAT:
            return [_json(self.topic(RETREAT), RETREAT_SCHEMA, retreat_point(msg))]
        return []

    def robot_model(self, stamp: float) -> Derived | None:
        """The arm's meshes (sent with the first state; the live server resends them to new viewers)."""
        if self.setup.arm is None:
            return None
        return _proto(self.topic(ROBOT), robot_scene(self.setup.arm, stamp))

    def scene(self, stamp: float) -> Derived:
        update = scene_update(
            stamp, self.target, self.setup.target_size, list(self.executed), self.plan, self.abandoned
        )
        return _proto(self.topic(SCENE), update)

    def _state(self, s: m.RobotState) -> list[Derived]:
        out = []
        if not self.robot_sent:
            self.robot_sent = True
            model = self.robot_model(s.stamp)
            out += [model] if model is not None else []
        self.ee = list(s.ee_pos)
        self.session = s.session
        if self._states % 2 == 0:
            self.executed.append(self.ee)
        tfs = [transform(BASE, EE, s.ee_pos, IDENTITY, s.stamp)]
        slow = self._states % self.links_every == 0
        for child, pose in ((CAMERA, self.setup.camera), (CAMERA_SIM, self.setup.camera_sim)):
            if pose is not None and slow:
                tfs.append(transform(BASE, child, pose[0], pose[1], s.stamp))
        arm = self.setup.arm
        if arm is not None and len(s.q) == len(arm.kin.description.arm_joints):
            for link, position, quat in arm.poses(s.q):
                if slow:
                    tfs.append(transform(BASE, link, position, quat, s.stamp))
                if link == arm.kin.description.ee_frame:  # the ee frame turns with the tool centre point
                    tfs[0] = transform(BASE, EE, s.ee_pos, quat, s.stamp)
        out.append(_proto(self.topic(TF), fm.FrameTransforms(transforms=tfs)))
        valid = self.target is not None and self.target.valid
        dist = math.dist(self.ee, self.target.position) if valid else 0.0
        out.append(_json(self.topic(DISTANCE), DISTANCE_SCHEMA, {"distance": dist, "target_valid": valid}))
        self._states += 1
        if self._states % self.scene_every == 0:
            out.append(self.scene(s.stamp))
        return out

    def _target(self, t: m.Target) -> list[Derived]:
        self.target = t
        tf = target_transforms(t)
        return [_proto(self.topic(TF), tf)] if tf is not None else []

    def _chunk(self, c: m.ActionChunk) -> list[Derived]:
        if self.session and c.session != self.session:
            return []  # refused by robot-io (not the obeyed session): nothing the arm will do
        if not c.predicted_ee:
            self.plan = []  # a chunk without a prediction: no plan path to draw
            return []
        points = np.asarray(c.predicted_ee, float).reshape(-1, 3).tolist()
        self.plan = ([self.ee] if self.ee else []) + points
        self.plans[(c.session, c.seq)] = (bool(self.ee), self.plan)
        while len(self.plans) > self.PLANS_KEPT:
            del self.plans[next(iter(self.plans))]
        return [self.scene(c.stamp)]

    def _status(self, s: m.ChunkStatus) -> list[Derived]:
        """A plan cut short by a newer one: keep the rest it did not play, from where the arm stopped."""
        entry = self.plans.get((s.session, s.chunk_seq))
        if entry is None or not s.dropped or s.preempted_by < 0:
            return []
        has_start, points = entry  # points[0] is the arm at arrival when has_start; then one per action
        self.abandoned = points[s.executed if has_start else max(s.executed - 1, 0) :]
        return [self.scene(s.stamp)]
