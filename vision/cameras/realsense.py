"""Intel RealSense backend (pyrealsense2): colour + depth aligned to colour, read from the device.

Intrinsics come from the colour stream's profile and the depth scale from the depth sensor, so the
pipeline deprojects with what the device reports. A frame timeout raises ``CameraError`` (the caller
reports it and carries on); after ``max_timeouts`` in a row the device is hardware-reset and the
pipeline restarted. The colour stream's lens distortion is not modelled (D4xx colour streams report
zero coefficients).

``rs`` may be injected (tests pass a fake with pyrealsense2's names); by default the real module is
imported, lazily, so machines without the package can still import this file.
"""

from __future__ import annotations

import time
from types import ModuleType
from typing import Any

import numpy as np

from vision.cameras.protocol import CameraError, Frame
from vision.config import Intrinsics, RealSenseConfig


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

    def __init__(self, config: RealSenseConfig, rs: Any = None, sleep=time.sleep) -> None:
        self.config = config
        self.rs = rs if rs is not None else _import_pyrealsense2()
        self._sleep = sleep
        self._pipeline: Any = None
        self._timeouts = 0
        self._seq = 0
        self.reconnects = 0
        self.depth_scale = 0.0
        self._intrinsics: Intrinsics | None = None
        self._start()

    # -- device ------------------------------------------------------------------------------------
    def _find_device(self) -> Any:
        rs = self.rs
        devices = list(rs.context().query_devices())
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
        self._serial = device.get_info(rs.camera_info.serial_number)
        pipeline = rs.pipeline()
        rs_config = rs.config()
        rs_config.enable_device(self._serial)
        rs_config.enable_stream(rs.stream.depth, c.width, c.height, rs.format.z16, c.fps)
        rs_config.enable_stream(rs.stream.color, c.width, c.height, rs.format.rgb8, c.fps)
        try:
            profile = pipeline.start(rs_config)
        except RuntimeError as exc:
            raise CameraError(f"realsense {self._serial}: could not start streaming: {exc}") from None
        self._pipeline = pipeline
        self._align = rs.align(rs.stream.color)
        self.depth_scale = float(profile.get_device().first_depth_sensor().get_depth_scale())
        intr = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
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
            pass  # not enumerated right now: waiting and restarting is all we can do
        self._sleep(self.config.reconnect_wait_s)
        self.reconnects += 1
        self._timeouts = 0
        self._start()

    # -- Camera protocol ---------------------------------------------------------------------------
    @property
    def intrinsics(self) -> Intrinsics:
        assert self._intrinsics is not None
        return self._intrinsics

    def capture(self) -> Frame:
        rs = self.rs
        if self._pipeline is None:
            self.reconnect()
        try:
            frames = self._pipeline.wait_for_frames(self.config.timeout_ms)
        except RuntimeError as exc:
            self._timeouts += 1
            detail = f"realsense {self._serial}: no frame within {self.config.timeout_ms} ms ({exc})"
            if self._timeouts >= self.config.max_timeouts:
                try:
                    self.reconnect()
                except CameraError as again:
                    self._pipeline = None  # try again on the next capture
                    raise CameraError(f"{detail}; reconnect failed: {again}") from None
                raise CameraError(f"{detail}; device reset and restarted") from None
            raise CameraError(detail) from None
        self._timeouts = 0
        aligned = self._align.process(frames)
        depth_frame, color_frame = aligned.get_depth_frame(), aligned.get_color_frame()
        if not depth_frame or not color_frame:
            raise CameraError(f"realsense {self._serial}: incomplete frameset (depth or colour missing)")
        domain = color_frame.get_frame_timestamp_domain()
        if domain in (rs.timestamp_domain.global_time, rs.timestamp_domain.system_time):
            stamp = color_frame.get_timestamp() / 1000.0  # host clock, ms since the epoch
        else:
            stamp = time.time()  # hardware clock only: arrival time is the best host-side stamp
        rgb = np.asanyarray(color_frame.get_data())
        depth = np.asanyarray(depth_frame.get_data()).astype(np.float32) * self.depth_scale
        self._seq += 1
        return Frame(
            rgb=np.ascontiguousarray(rgb), depth=depth, intrinsics=self.intrinsics, stamp=stamp, seq=self._seq
        )

    def close(self) -> None:
        self._stop()
