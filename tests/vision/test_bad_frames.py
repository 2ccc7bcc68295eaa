"""Bad frames give a clear error in the output, never an exception, and the track degrades to lost."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vision.cameras.protocol import Frame
from vision.cameras.sim import camera_from_config
from vision.pipeline import VisionPipeline, annotate


@pytest.fixture
def good(scene, config) -> Frame:
    return camera_from_config(scene.client_id, config).capture()


def _bad_frames(good: Frame) -> dict[str, Frame]:
    nan = good.depth.copy()
    nan[10:20, 10:20] = np.nan
    return {
        "all-zero depth": dataclasses.replace(good, depth=np.zeros_like(good.depth)),
        "NaN depth": dataclasses.replace(good, depth=nan),
        "wrong rgb shape": dataclasses.replace(good, rgb=good.rgb[:, :-1]),
        "wrong depth shape": dataclasses.replace(good, depth=good.depth.T.copy()),
        "integer depth": dataclasses.replace(good, depth=(good.depth * 1000).astype(np.uint16)),
        "float rgb": dataclasses.replace(good, rgb=good.rgb.astype(np.float32)),
        "negative depth": dataclasses.replace(good, depth=-good.depth),
    }


EXPECTED = {
    "all-zero depth": "all zero",
    "NaN depth": "NaN",
    "wrong rgb shape": "rgb shape",
    "wrong depth shape": "depth shape",
    "integer depth": "dtype",
    "float rgb": "dtype",
    "negative depth": "negative",
}


def test_each_bad_frame_is_named(config, good):
    pipeline = VisionPipeline(config)
    for name, frame in _bad_frames(good).items():
        out = pipeline.process(frame)
        assert out.error is not None and EXPECTED[name] in out.error, (name, out.error)
        assert out.detection is None and out.measurement is None
        assert annotate(frame, out)[:2] == b"\xff\xd8"  # the monitor still gets a (JPEG) picture
    ok = pipeline.process(good)
    assert ok.error is None and ok.estimate.valid and ok.detection is not None


def test_a_run_of_bad_frames_ends_in_lost(config, good):
    pipeline = VisionPipeline(config)
    t0 = 100.0
    assert pipeline.process(dataclasses.replace(good, stamp=t0)).estimate.valid
    zero = dataclasses.replace(good, depth=np.zeros_like(good.depth))
    statuses = [
        pipeline.process(dataclasses.replace(zero, stamp=t0 + i / 30)).estimate.status for i in range(1, 16)
    ]
    lost_after = config.tracking.lost_after_s
    expected = ["coasting" if i / 30 <= lost_after else "lost" for i in range(1, 16)]
    assert statuses == expected
    back = pipeline.process(dataclasses.replace(good, stamp=t0 + 1.0))
    assert back.estimate.valid and back.estimate.status == "tracking"
