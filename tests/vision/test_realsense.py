"""What the SDK test (test_realsense_sdk.py, librealsense's software_device) cannot show, on a fake.

Streams, alignment, intrinsics, depth scale, timeouts, frozen and depth-less framesets and a vanished
device run through the real SDK there. Left for a fake at pyrealsense2's names: the hardware path's
enumeration (``rs.context().query_devices()``, the pipeline not bound with ``set_device``) and the
hardware reset after repeated timeouts (a software device refuses it: "hardware_reset is not
implemented for this device!"); and the message when pyrealsense2 is not installed.
"""

from __future__ import annotations

import types

import pytest

from vision.cameras.protocol import CameraError
from vision.cameras.realsense import RealSenseCamera
from vision.cameras.realsense_config import RealSenseConfig


def make_fake_rs(serials: tuple[str, ...]):
    """pyrealsense2's names for enumeration, reset and a pipeline whose frames never arrive."""
    rs = types.SimpleNamespace(log=[], resets=[])
    rs.stream = types.SimpleNamespace(depth="depth", color="color")
    rs.format = types.SimpleNamespace(z16="z16", rgb8="rgb8")
    rs.camera_info = types.SimpleNamespace(serial_number="serial_number")

    class device:  # noqa: N801 (pyrealsense2's spelling)
        def __init__(self, serial):
            self.serial = serial

        def get_info(self, what):
            assert what == "serial_number"
            return self.serial

        def hardware_reset(self):
            rs.resets.append(self.serial)

        def first_depth_sensor(self):
            return types.SimpleNamespace(get_depth_scale=lambda: 0.001)

    class context:  # noqa: N801
        def query_devices(self):
            rs.log.append(("query",))
            return [device(s) for s in serials]

    class config:  # noqa: N801
        def __init__(self):
            self.device = None

        def enable_device(self, serial):
            self.device = serial

        def enable_stream(self, *args):
            pass

    intrinsics = types.SimpleNamespace(width=640, height=480, fx=615.0, fy=615.0, ppx=319.5, ppy=239.5)
    color_profile = types.SimpleNamespace(
        as_video_stream_profile=lambda: types.SimpleNamespace(get_intrinsics=lambda: intrinsics)
    )

    class pipeline:  # noqa: N801 (no set_device: the hardware path must not need it)
        def start(self, cfg):
            rs.log.append(("start", cfg.device))
            dev = device(cfg.device)
            return types.SimpleNamespace(get_device=lambda: dev, get_stream=lambda s: color_profile)

        def stop(self):
            rs.log.append(("stop",))

        def wait_for_frames(self, timeout_ms):
            raise RuntimeError(f"Frame didn't arrive within {timeout_ms}")

    rs.context, rs.config, rs.pipeline = context, config, pipeline
    rs.align = lambda to: None
    return rs


def test_hardware_path_enumerates_and_resets_the_chosen_device_after_timeouts():
    rs = make_fake_rs(("111", "222"))
    slept: list[float] = []
    settings = RealSenseConfig(serial="222", timeout_ms=200, max_timeouts=3, reconnect_wait_s=2.0)
    cam = RealSenseCamera(settings, rs=rs, sleep=slept.append)
    assert rs.log == [("query",), ("start", "222")]
    for _ in range(2):
        with pytest.raises(CameraError, match=r"^realsense 222: no frame within 200 ms"):
            cam.capture()
    with pytest.raises(CameraError, match="device reset and restarted"):
        cam.capture()
    assert rs.resets == ["222"] and slept == [2.0] and cam.reconnects == 1
    assert rs.log[2:] == [("stop",), ("query",), ("query",), ("start", "222")]
    with pytest.raises(CameraError, match=r"no device with serial '333' \(found \['111'\]\)"):
        RealSenseCamera(RealSenseConfig(serial="333"), rs=make_fake_rs(("111",)))


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
