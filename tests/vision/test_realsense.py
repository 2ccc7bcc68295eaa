"""The RealSense backend against a fake at pyrealsense2's API boundary (same names, same calls).

The fake records how it is driven (streams enabled, alignment, timeouts, hardware resets) and
serves frames rendered by the sim camera, so the backend's real code path runs end to end.
"""

from __future__ import annotations

import types

import numpy as np
import pytest

from vision.cameras.protocol import CameraError
from vision.cameras.realsense import RealSenseCamera
from vision.cameras.sim import camera_from_config
from vision.config import RealSenseConfig
from vision.pipeline import VisionPipeline

DEPTH_SCALE = 0.001


def make_fake_rs(frames, serials=("123456",)):
    """A module object with pyrealsense2's names; ``frames`` is a list of Frame or Exception."""
    log: list = []
    rs = types.SimpleNamespace(log=log, resets=[])
    rs.stream = types.SimpleNamespace(depth="depth", color="color")
    rs.format = types.SimpleNamespace(z16="z16", rgb8="rgb8", bgr8="bgr8")
    rs.camera_info = types.SimpleNamespace(serial_number="serial_number")
    rs.timestamp_domain = types.SimpleNamespace(
        global_time="global", system_time="system", hardware_clock="hw"
    )
    queue = list(frames)

    class intrinsics:  # noqa: N801 (pyrealsense2's spelling)
        def __init__(self, k):
            self.width, self.height, self.fx, self.fy, self.ppx, self.ppy = (
                k.width,
                k.height,
                k.fx,
                k.fy,
                k.cx,
                k.cy,
            )

    class device:  # noqa: N801
        def __init__(self, serial):
            self.serial = serial

        def get_info(self, what):
            assert what == "serial_number"
            return self.serial

        def hardware_reset(self):
            rs.resets.append(self.serial)

        def first_depth_sensor(self):
            return types.SimpleNamespace(get_depth_scale=lambda: DEPTH_SCALE)

    class context:  # noqa: N801
        def query_devices(self):
            return [device(s) for s in serials]

    class config:  # noqa: N801
        def __init__(self):
            self.streams, self.device = [], None

        def enable_device(self, serial):
            self.device = serial

        def enable_stream(self, stream, width, height, fmt, fps):
            self.streams.append((stream, width, height, fmt, fps))

    class video_frame:  # noqa: N801
        def __init__(self, data, stamp, domain):
            self.data, self.stamp, self.domain = data, stamp, domain

        def __bool__(self):
            return self.data is not None

        def get_data(self):
            return memoryview(self.data)

        def get_timestamp(self):
            return self.stamp

        def get_frame_timestamp_domain(self):
            return self.domain

    class frameset:  # noqa: N801
        def __init__(self, frame, aligned=False):
            self.frame, self.aligned = frame, aligned

        def get_depth_frame(self):
            raw = np.round(self.frame.depth / DEPTH_SCALE).astype(np.uint16)
            return video_frame(raw, self.frame.stamp * 1000, "global")

        def get_color_frame(self):
            return video_frame(self.frame.rgb, self.frame.stamp * 1000, "global")

    class pipeline:  # noqa: N801
        def __init__(self, ctx=None):
            self.running = False

        def start(self, cfg):
            log.append(("start", cfg.device, sorted(cfg.streams)))
            self.running = True
            k = frames_intrinsics[0]
            profile_stream = types.SimpleNamespace(
                as_video_stream_profile=lambda: types.SimpleNamespace(get_intrinsics=lambda: intrinsics(k))
            )
            return types.SimpleNamespace(
                get_device=lambda: device(cfg.device),
                get_stream=lambda s: profile_stream if s == "color" else None,
            )

        def stop(self):
            log.append(("stop",))
            self.running = False

        def wait_for_frames(self, timeout_ms=5000):
            assert self.running
            log.append(("wait", timeout_ms))
            item = queue.pop(0)
            if isinstance(item, Exception):
                raise item
            return frameset(item)

    class align:  # noqa: N801
        def __init__(self, to):
            assert to == "color"
            log.append(("align", to))

        def process(self, fs):
            return frameset(fs.frame, aligned=True)

    frames_intrinsics = [f.intrinsics for f in frames if not isinstance(f, Exception)]
    rs.intrinsics, rs.device, rs.context, rs.config = intrinsics, device, context, config
    rs.pipeline, rs.align = pipeline, align
    return rs


@pytest.fixture
def rendered(scene, config):
    cam = camera_from_config(scene.client_id, config)
    return [cam.capture() for _ in range(3)]


def test_streams_aligned_depth_scale_and_intrinsics_from_device(rendered, config):
    rs = make_fake_rs(rendered)
    cam = RealSenseCamera(RealSenseConfig(width=320, height=240, fps=30, timeout_ms=200), rs=rs)
    assert rs.log[0] == ("start", "123456", [("color", 320, 240, "rgb8", 30), ("depth", 320, 240, "z16", 30)])
    assert ("align", "color") in rs.log and cam.depth_scale == DEPTH_SCALE
    assert cam.intrinsics == config.intrinsics
    frame = cam.capture()
    assert ("wait", 200) in rs.log
    assert frame.rgb.shape == (240, 320, 3) and frame.depth.dtype == np.float32
    assert np.abs(frame.depth - rendered[0].depth).max() <= DEPTH_SCALE / 2 + 1e-6  # z16 quantisation
    assert frame.stamp == pytest.approx(rendered[0].stamp)
    out = VisionPipeline(config).process(frame)
    assert out.error is None and out.estimate.valid  # the same pipeline runs on its frames


def test_timeouts_raise_then_reset_and_restart(rendered):
    timeout = RuntimeError("Frame didn't arrive within 200")
    rs = make_fake_rs([timeout, timeout, rendered[0], timeout, timeout, timeout, rendered[1]])
    slept = []
    cam = RealSenseCamera(
        RealSenseConfig(timeout_ms=200, max_timeouts=3, reconnect_wait_s=2.0), rs=rs, sleep=slept.append
    )
    for _ in range(2):
        with pytest.raises(CameraError, match="no frame within 200 ms"):
            cam.capture()
    cam.capture()  # a frame resets the consecutive-timeout count
    for _ in range(2):
        with pytest.raises(CameraError, match="no frame within"):
            cam.capture()
    with pytest.raises(CameraError, match="device reset and restarted"):
        cam.capture()
    assert rs.resets == ["123456"] and slept == [2.0] and cam.reconnects == 1
    assert [e[0] for e in rs.log].count("start") == 2 and ("stop",) in rs.log
    assert cam.capture().seq == 2


def test_serial_selection_and_missing_device(rendered):
    rs = make_fake_rs(rendered, serials=("111", "222"))
    assert RealSenseCamera(RealSenseConfig(serial="222"), rs=rs).rs.log[0][1] == "222"
    with pytest.raises(CameraError, match="no device with serial '333'"):
        RealSenseCamera(RealSenseConfig(serial="333"), rs=make_fake_rs(rendered, serials=("111",)))
    with pytest.raises(CameraError, match="no device connected"):
        RealSenseCamera(RealSenseConfig(), rs=make_fake_rs(rendered, serials=()))


def test_without_pyrealsense2_the_error_says_how_to_install(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_rs(name, *args, **kwargs):
        if name == "pyrealsense2":
            raise ImportError("No module named 'pyrealsense2'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_rs)
    with pytest.raises(CameraError, match=r"adaptiveh\[realsense\]"):
        RealSenseCamera(RealSenseConfig())
