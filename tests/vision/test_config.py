"""Config validation: bad values fail at load time with a message naming the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.config import ConfigError, parse
from deploy.config import load_stack_config
from vision.camera_model import Intrinsics, Pose
from vision.config import VisionConfig


@pytest.mark.parametrize(
    "section, match",
    [
        ({"camera": "kinect"}, "camera: Input should be 'sim', 'frames' or 'realsense'"),
        ({"intrinsics": {"fx": -1}}, "intrinsics.fx: Input should be greater than 0"),
        ({"intrinsics": {"width": 320, "cx": 400}}, "principal point"),
        ({"extrinsics": {"quaternion": [0, 0, 0, 2]}}, "unit norm"),
        ({"extrinsics": {"position": [1, 2]}}, "extrinsics.position: Tuple should have at least 3 items"),
        ({"detection": {"hsv_ranges": [[10, 0, 0, 5, 255, 255]]}}, "lower bound above upper"),
        ({"detection": {"target_shape": "cone"}}, "detection.target_shape: Input should be 'box'"),
        ({"tracking": {"lost_after_s": 0}}, "tracking.lost_after_s: Input should be greater than 0"),
        ({"realsense": {"fps": 25}}, "realsense.fps: Input should be 6, 15, 30, 60 or 90"),
        ({"sim": {"near": 2, "far": 1}}, "near < far"),
        ({"sim": {"noise": {"dropout": 1.5}}}, "dropout"),
        ({"colour": "red"}, "unknown key"),
    ],
)
def test_bad_values_are_named(section, match):
    with pytest.raises(ConfigError, match=match):
        parse(VisionConfig, section, "vision")


@pytest.mark.parametrize("path", ["configs/sim.yaml", "configs/franka_realsense.yaml"])
def test_shipped_configs_load(path):
    vision = load_stack_config(Path(__file__).parents[2] / path).vision
    assert vision.sim_pose() == vision.extrinsics or vision.sim.pose is not None


def test_scaled_intrinsics_keep_pixel_centres():
    k = Intrinsics(320, 240, 307.5, 307.5, 159.5, 119.5).scaled(640, 480)
    assert (k.fx, k.cx, k.cy) == (615.0, 319.5, 239.5)
    assert Pose((0, 0, 0), (0, 0, 0, 1.0004)).quaternion[3] == pytest.approx(1.0)
