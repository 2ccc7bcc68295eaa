"""Intel RealSense backend (pyrealsense2): colour + depth aligned to colour, read from the device.

Intrinsics come from the colour stream's profile and the depth scale from the depth sensor, so the
pipeline deprojects with what the device reports. The colour stream's lens distortion is not modelled
(D4xx colour streams report zero coefficients).

``capture()`` returns only a new, complete pair of colour and depth; anything else raises
``CameraError`` (the caller reports it and carries on) and nothing is returned:

- no frameset within ``timeout_ms`` (a timeout, or the device gone);
- a frozen stream: the colour frame, or the depth frame, is the one last returned (same frame number
  and timestamp);
- depth that is not colour's partner: librealsense's pipeline fills a stream that stopped with its
  last frame, so when depth stalls it keeps delivering fresh colour with old depth. A pair counts when
  the timestamps are less than half a frame period apart, at the slower stream's rate (the SDK
  syncer's own matching rule);
- a frameset without depth or colour.

After ``max_timeouts`` such captures in a row the device is hardware-reset and the pipeline restarted;
until a device is back every capture raises ``CameraError``. Every SDK error becomes ``CameraError``.

``rs`` may be injected (tests pass a fake with pyrealsense2's names); by default the real module is
imported, lazily, so machines without the package can still import this file. ``devices`` (tests, a
rig of ``rs.software_device``) replaces the SDK's device enumeration with a function returning the
devices connected now; the pipeline is then bound to the chosen device with ``pipeline.set_device``
(librealsense >= 2.56), since contexts do not enumerate software devices.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import Any

import numpy as np

from vision.camera_model import Intrinsics
from vision.cameras.protocol import CameraError, Frame
from vision.cameras.realsense_config import RealSenseConfig


def _import_pyrealsense2() -> ModuleType:
    try:
        import pyrealsense2 as rs
    except ImportError as exc:
        raise CameraError(
            f"realsense camera needs pyrealsense2 ({exc}); "
            "install the extra: pip install 'adaptiveh[realsense]'"
        ) from None
    return rs


class RealSenseCamera:
    """A RealSense opened on construction; ``capture()`` returns aligned frames."""

    def __init__(
        self,
        config: RealSenseConfig,
        rs: Any = None,
        sleep: Callable[[float], None] = time.sleep,
        devices: Callable[[], Sequence[Any]] | None = None,
    ) -> None:
        self.config = config
        self.rs = rs if rs is not None else _import_pyrealsense2()
        self._sleep = sleep
        self._devices = devices
        self._pipeline: Any = None
        self._serial = config.serial or "?"
        self._timeouts = 0  # consecutive captures without a new usable frameset
        self._last_color: tuple[int, float] | None = None  # (frame number, timestamp) last returned
        self._last_depth: tuple[int, float] | None = None
        self._seq = 0
        self.reconnects = 0
        self.depth_scale = 0.0
        self._intrinsics: Intrinsics | None = None
        self._start()

    # -- device ------------------------------------------------------------------------------------
    def _find_device(self) -> Any:
        rs = self.rs
        try:
            devices = list(self._devices() if self._devices else rs.context().query_devices())
        except RuntimeError as exc:
            raise CameraError(f"realsense: could not list devices: {exc}") from None
        if not devices:
            raise CameraError("realsense: no device connected")
        if not self.config.serial:
            return devices[0]
        for dev in devices:
            if dev.get_info(rs.camera_info.serial_number) == self.config.serial:
                return dev
        serials = [d.get_info(rs.camera_info.serial_number) for d in devices]
        raise CameraError(f"realsense: no device with serial {self.config.serial!r} (found {serials})")

    def _start(self) -> None:
        rs, c = self.rs, self.config
        device = self._find_device()
        try:
            self._serial = device.get_info(rs.camera_info.serial_number)
            pipeline = rs.pipeline()
            if self._devices is not None:
                pipeline.set_device(device)
            rs_config = rs.config()
            rs_config.enable_device(self._serial)
            rs_config.enable_stream(rs.stream.depth, c.width, c.height, rs.format.z16, c.fps)
            rs_config.enable_stream(rs.stream.color, c.width, c.height, rs.format.rgb8, c.fps)
            profile = pipeline.start(rs_config)
        except RuntimeError as exc:
            raise CameraError(f"realsense {self._serial}: could not start streaming: {exc}") from None
        try:
            depth_scale = float(profile.get_device().first_depth_sensor().get_depth_scale())
            intr = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        except RuntimeError as exc:
            try:
                pipeline.stop()
            except RuntimeError:
                pass
            raise CameraError(f"realsense {self._serial}: could not read the stream profile: {exc}") from None
        self._pipeline = pipeline
        self._align = rs.align(rs.stream.color)
        self.depth_scale = depth_scale
        self._intrinsics = Intrinsics(intr.width, intr.height, intr.fx, intr.fy, intr.ppx, intr.ppy)

    def _stop(self) -> None:
        if self._pipeline is not None:
            try:
                self._pipeline.stop()
            except RuntimeError:
                pass  # already stopped or the device is gone; either way it is not streaming
            self._pipeline = None

    def reconnect(self) -> None:
        """Stop, hardware-reset the device, wait for it to come back, start again."""
        self._stop()
        try:
            self._find_device().hardware_reset()
        except (RuntimeError, CameraError):
            pass  # not enumerated right now (or cannot be reset): waiting and restarting is all we can do
        self._sleep(self.config.reconnect_wait_s)
        self.reconnects += 1
        self._timeouts = 0
        self._start()

    def _unusable(self, detail: str) -> CameraError:
        """Count a capture without a new usable frameset; reset the device after ``max_timeouts``."""
        self._timeouts += 1
        detail = f"realsense {self._serial}: {detail}"
        if self._timeouts >= self.config.max_timeouts:
            try:
                self.reconnect()
            except CameraError as again:
                self._pipeline = None  # try again on the next capture
                return CameraError(f"{detail}; reconnect failed: {again}")
            return CameraError(f"{detail}; device reset and restarted")
        return CameraError(detail)

    # -- Camera protocol ---------------------------------------------------------------------------
    @property
    def intrinsics(self) -> Intrinsics:
        assert self._intrinsics is not None
        return self._intrinsics

    def capture(self) -> Frame:
        if self._pipeline is None:
            self.reconnect()
        try:
            frames = self._pipeline.wait_for_frames(self.config.timeout_ms)
        except RuntimeError as exc:
            raise self._unusable(f"no frame within {self.config.timeout_ms} ms ({exc})") from None
        try:
            return self._frame(frames)
        except CameraError:
            raise
        except RuntimeError as exc:  # an SDK error on a frame: never let it out as anything else
            raise self._unusable(f"unusable frameset: {exc}") from None

    def _frame(self, frames: Any) -> Frame:
        rs = self.rs
        depth_frame, color_frame = frames.get_depth_frame(), frames.get_color_frame()
        if not depth_frame or not color_frame:
            raise self._unusable("incomplete frameset (depth or colour missing)")
        color = (color_frame.get_frame_number(), color_frame.get_timestamp())
        depth = (depth_frame.get_frame_number(), depth_frame.get_timestamp())
        if color == self._last_color:
            raise self._unusable(f"frozen: colour frame {color[0]} (t={color[1]:.1f} ms) delivered again")
        if depth == self._last_depth:
            raise self._unusable(
                f"depth stalled: depth frame {depth[0]} (t={depth[1]:.1f} ms) delivered again"
                " with newer colour"
            )
        domain = color_frame.get_frame_timestamp_domain()
        if depth_frame.get_frame_timestamp_domain() == domain:
            half_period_ms = 500.0 / min(self._fps(depth_frame), self._fps(color_frame))
            if abs(color[1] - depth[1]) >= half_period_ms:
                name, (number, t) = ("depth", depth) if depth[1] < color[1] else ("colour", color)
                raise self._unusable(
                    f"{name} stalled: {name} frame {number} (t={t:.1f} ms) is not the other stream's"
                    f" partner (a pair is within {half_period_ms:.1f} ms)"
                )
        aligned = self._align.process(frames)
        depth_frame, color_frame = aligned.get_depth_frame(), aligned.get_color_frame()
        if not depth_frame or not color_frame:
            raise self._unusable("alignment gave no depth or colour")
        if domain in (rs.timestamp_domain.global_time, rs.timestamp_domain.system_time):
            stamp = color[1] / 1000.0  # host clock, ms since the epoch
        else:
            stamp = time.time()  # hardware clock only: arrival time is the best host-side stamp
        # Copies: a view would hold the SDK's frame (and its pool slot) for as long as the Frame lives.
        rgb = np.array(color_frame.get_data(), dtype=np.uint8, order="C")
        depth_m = np.asanyarray(depth_frame.get_data()).astype(np.float32) * self.depth_scale
        self._timeouts = 0
        self._last_color, self._last_depth = color, depth  # kept across restarts: a repeat stays one
        self._seq += 1
        return Frame(rgb=rgb, depth=depth_m, intrinsics=self.intrinsics, stamp=stamp, seq=self._seq)

    def _fps(self, frame: Any) -> float:
        """The frame rate the SDK's syncer pairs ``frame`` by: measured (metadata) if known, else nominal."""
        actual = self.rs.frame_metadata_value.actual_fps
        if frame.supports_frame_metadata(actual) and frame.get_frame_metadata(actual) > 0:
            return frame.get_frame_metadata(actual) / 1000.0
        return float(frame.get_profile().fps() or self.config.fps)

    def close(self) -> None:
        self._stop()
