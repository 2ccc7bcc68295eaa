"""Shared fixtures: the real PyBullet Panda scene and a 320x240 sim camera looking at its workspace.

Tests render at 320x240 (half the configured 640x480) to stay fast on two cores; the accuracy bounds
of the issue hold at that size (the 640x480 numbers are better, see bench/vision_bench.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from sim.panda_scene import PandaScene
from vision.camera_model import Intrinsics
from vision.config import VisionConfig
from vision.extrinsics import look_at

# Where the camera stands in the tests and in configs/sim.yaml: in front of the robot, to its right,
# looking down at the target's workspace.
CAMERA_EYE = (1.3, -0.6, 0.9)
CAMERA_AT = (0.5, 0.0, 0.28)
TEST_INTRINSICS = Intrinsics(320, 240, 307.5, 307.5, 159.5, 119.5)


def make_config(**overrides: object) -> VisionConfig:
    kwargs: dict[str, object] = {"intrinsics": TEST_INTRINSICS, "extrinsics": look_at(CAMERA_EYE, CAMERA_AT)}
    kwargs.update(overrides)
    return VisionConfig(**kwargs)  # type: ignore[arg-type]


@pytest.fixture
def scene():
    s = PandaScene(motion="static", seed=3)
    yield s
    s.close()


@pytest.fixture
def config() -> VisionConfig:
    return make_config()


@pytest.fixture
def workspace(scene: PandaScene) -> tuple[np.ndarray, np.ndarray]:
    """The box the scene's target moves in (lo, hi)."""
    lo, hi = scene.motion.box
    return np.asarray(lo, float), np.asarray(hi, float)


@pytest.fixture
def vision_config():
    """Factory: the test config with some fields overridden."""
    return make_config
