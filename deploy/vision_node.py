"""The vision process: camera frames in, ``target`` out, over Zenoh.

The camera is chosen by ``vision.camera``: ``sim`` renders a replica of the simulated world in this
process (``vision.cameras.sim_mirror``, posed from robot-io's ``state`` and ``sim/target_truth``, so
rendering never stalls the control loop), ``realsense`` reads the device, and ``frames`` takes frames
from the ``camera/frame`` topic (published by another process, e.g. ``SimFramePublisher`` below in the
vision benchmark). All feed the same ``vision.pipeline.VisionPipeline``. Every frame gives one
``Target`` (``valid`` False when lost); a downscaled annotated JPEG goes to ``camera/annotated`` at a
low rate. Bad frames, bad messages and camera errors become ``events/safety`` messages (kinds
``bad_frame``, ``bad_message``, ``camera_error``; ``held`` False: vision never holds the arm itself),
rate-limited, and the process keeps running. Only the newest frame is processed: if processing falls
behind, older frames are dropped (counted), so latency stays bounded.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import numpy as np

from bus import messages as m
from bus.node import Node
from bus.transport import Bus
from common.throttle import EVENT_EVERY_S, Throttle
from deploy.config import ConfigError, StackConfig
from vision.camera_model import Intrinsics
from vision.cameras.protocol import Camera, CameraError, Frame
from vision.config import VisionConfig
from vision.pipeline import PipelineOutput, VisionPipeline, annotate

log = logging.getLogger(__name__)


# -- frames <-> messages -----------------------------------------------------------------------------
def frame_message(frame: Frame, depth_scale: float = 0.001) -> m.CameraFrame:
    """A ``CameraFrame`` of ``frame``: depth quantised to uint16 in units of ``depth_scale`` metres."""
    k = frame.intrinsics
    depth = np.clip(np.round(frame.depth / depth_scale), 0, 65535).astype(np.uint16)
    return m.CameraFrame(
        width=k.width,
        height=k.height,
        rgb=np.ascontiguousarray(frame.rgb, np.uint8).tobytes(),
        depth=depth.tobytes(),
        depth_scale=depth_scale,
        intrinsics=[k.fx, k.fy, k.cx, k.cy],
        frame_stamp=frame.stamp,
    )


def frame_from_message(msg: m.CameraFrame) -> Frame:
    """The ``Frame`` in a ``CameraFrame``; raises ``MessageError`` when sizes or intrinsics are wrong."""
    rgb, depth = m.frame_images(msg)
    fx, fy, cx, cy = msg.intrinsics
    try:
        k = Intrinsics(msg.width, msg.height, fx, fy, cx, cy)
    except ValueError as exc:
        raise m.MessageError(f"CameraFrame.intrinsics: {exc}") from None
    return Frame(rgb=rgb, depth=depth, intrinsics=k, stamp=msg.frame_stamp, seq=msg.seq)


def target_message(out: PipelineOutput) -> m.Target:
    est = out.estimate
    return m.Target(
        position=[float(x) for x in est.position],
        velocity=[float(x) for x in est.velocity],
        covariance=[float(x) for x in np.asarray(est.covariance).ravel()],
        valid=bool(est.valid),
        frame_stamp=out.frame_stamp,
        status=m.enum(m.Target, "status", est.status),
    )


class SimFramePublisher:
    """For the physics owner: render the scene's client and publish ``camera/frame``.

    Call it at the frame rate from the thread that owns the PyBullet client (PyBullet is single-owner;
    the vision benchmark and tests do). It never raises: a render failure is logged.
    """

    def __init__(self, bus: Bus, client_id: int, config: VisionConfig) -> None:
        from vision.cameras.sim import camera_from_config

        self.camera = camera_from_config(client_id, config)
        self._publish = bus.publisher(m.CAMERA)
        self.seq = 0  # the last frame published
        self.render_s = 0.0

    def __call__(self) -> None:
        t0 = time.perf_counter()
        try:
            frame = self.camera.capture()
        except CameraError as exc:
            log.warning("sim camera: %s", exc)
            return
        self.seq = self._publish(frame_message(frame))
        self.render_s = time.perf_counter() - t0


# -- the node ----------------------------------------------------------------------------------------
class VisionNode(Node):
    """Run with ``start()``/``stop()``. ``camera`` overrides the RealSense (tests, other devices)."""

    alive_as = "vision"

    def __init__(self, settings: StackConfig, camera: Camera | None = None, token: str = "") -> None:
        """``token``: the stack's operator token: the targets are signed with its key, and the robot
        states its simulated camera poses the arm from must be (``bus.signing``)."""
        if settings.vision is None:
            raise ConfigError(f"robot {settings.name}: the config has no vision section")
        self.settings = settings
        self.config = settings.vision
        self.pipeline = VisionPipeline(self.config)
        super().__init__(settings.bus_key, settings.zenoh, token=token, fleet=settings.name)
        self._pub_target = self.bus.publisher(m.TARGET)
        self._pub_image = self.bus.publisher(m.CAMERA_ANNOTATED, express=False)
        self._pub_event = self.bus.publisher(m.EVENTS_SAFETY)
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._pending: Frame | m.CameraFrame | None = None
        self._events = Throttle("", EVENT_EVERY_S)  # one event per problem a second, with a count
        self._last_image = 0.0
        self._last_frame_wall = time.time()
        self.frames = 0
        self.dropped = 0
        self.camera = camera
        if camera is None:
            self.camera = self._open_camera()
        self.declare_alive()

    def _open_camera(self) -> Camera | None:
        """The configured camera (None for ``frames``: they arrive on ``camera/frame``)."""
        if self.config.camera == "frames":
            self.bus.subscribe(m.CAMERA, self._offer, on_bad=self._on_bad)
            return None
        if self.config.camera == "sim":
            from tasks.sim_world import replica_scene
            from vision.cameras.sim_mirror import MirrorSimCamera

            mirror = MirrorSimCamera(self.config, replica_scene())
            self.bus.subscribe(m.STATE, lambda s: mirror.set_joints(s.q, s.dq, s.stamp), on_bad=self._on_bad)
            self.bus.subscribe(
                m.TARGET_TRUTH,
                lambda t: mirror.set_target(t.position, t.frame_stamp, t.velocity),
                on_bad=self._on_bad,
            )
            return mirror
        from vision.cameras.realsense import RealSenseCamera

        return RealSenseCamera(self.config.realsense)

    # -- inputs ------------------------------------------------------------------------------------
    def _offer(self, item: Frame | m.CameraFrame) -> None:
        with self._wake:
            if self._pending is not None:
                self.dropped += 1
            self._pending = item
            self._wake.notify()

    def _on_bad(self, topic: str, exc: Exception, data: bytes = b"") -> None:
        self.event("bad_message", f"{topic}: {exc}", key=topic, logged=False)

    def _capture_loop(self) -> None:
        assert self.camera is not None
        while not self.stopping:
            try:
                frame = self.camera.capture()
            except CameraError as exc:
                self.event("camera_error", str(exc))
                self.wait(0.05)
                continue
            self._offer(frame)

    # -- outputs -----------------------------------------------------------------------------------
    def event(self, kind: str, detail: str, key: str | None = None, logged: bool = True) -> None:
        """Publish ``events/safety`` (kind, ``vision: detail``), at most once a second per ``key``.

        ``key`` (default: the detail) groups repeats of one problem, so a camera stuck on bad frames
        sends one event a second with a count, while a different problem is reported at once.
        ``logged``: also a log line (not for bad messages: the bus logs those, rate-limited per minute).
        """
        shown = self._events.report(detail, (kind, key if key is not None else detail))
        if shown is None:
            return
        if logged:
            log.warning("vision %s: %s", kind, shown)
        kind_value = m.enum(m.SafetyEvent, "kind", kind)
        self._pub_event(m.SafetyEvent(kind=kind_value, detail=f"vision: {shown}", held=False))

    def _handle(self, item: Frame | m.CameraFrame) -> None:
        if isinstance(item, m.CameraFrame):
            try:
                frame = frame_from_message(item)
            except m.MessageError as exc:
                self.event("bad_frame", str(exc))
                self._publish_target(self.pipeline.idle(time.time(), str(exc)))
                return
        else:
            frame = item
        out = self.pipeline.process(frame)
        self.frames += 1
        if out.error is not None:
            self.event("bad_frame", f"frame {frame.seq}: {out.error}", key=out.error)
        self._publish_target(out)
        rate = self.config.annotated.rate_hz
        now = time.monotonic()
        if rate > 0 and now - self._last_image >= 1.0 / rate:
            self._last_image = now
            a = self.config.annotated
            jpeg = annotate(frame, out, a.width, a.jpeg_quality)
            self._pub_image(m.AnnotatedImage(jpeg=jpeg, detected=out.detection is not None))

    def _publish_target(self, out: PipelineOutput) -> None:
        self._pub_target(target_message(out))

    def _process_loop(self) -> None:
        lost_after = self.config.tracking.lost_after_s
        while not self.stopping:
            with self._wake:
                if self._pending is None:
                    self._wake.wait(timeout=lost_after / 2)
                item, self._pending = self._pending, None
            if item is None:
                # No frames at all (camera or renderer gone): still say the target is lost, on time.
                if time.time() - self._last_frame_wall > lost_after:
                    self._publish_target(self.pipeline.idle(time.time()))
                continue
            self._last_frame_wall = time.time()
            try:
                self._handle(item)
            except Exception as exc:  # a pipeline bug must not end the process
                log.exception("vision pipeline failed")
                self.event("bad_frame", f"pipeline error: {type(exc).__name__}: {exc}")

    # -- lifecycle ---------------------------------------------------------------------------------
    def workers(self) -> dict[str, Callable[[], None]]:
        loops = {"vision-process": self._process_loop}
        if self.camera is not None:
            loops["vision-capture"] = self._capture_loop
        return loops

    def wake(self) -> None:
        with self._wake:
            self._wake.notify_all()

    def close(self) -> None:
        if self.camera is not None:
            self.camera.close()
        super().close()
