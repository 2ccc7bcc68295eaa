"""The mirror sim camera renders what the physics owner's scene looks like, from its published world."""

from __future__ import annotations

import time

import numpy as np
import pytest

from sim.panda_scene import PandaScene
from tasks.sim_world import replica_scene
from vision.camera_model import Intrinsics
from vision.cameras.protocol import CameraError
from vision.cameras.sim import camera_from_config
from vision.cameras.sim_config import DepthNoise, SimCameraConfig
from vision.cameras.sim_mirror import MirrorSimCamera
from vision.config import VisionConfig
from vision.extrinsics import look_at

POSE = look_at((1.3, -0.6, 0.9), (0.5, 0.0, 0.28))
CONFIG = VisionConfig(
    rate_hz=50.0,
    intrinsics=Intrinsics(160, 120, 154.0, 154.0, 79.5, 59.5),
    extrinsics=POSE,
    sim=SimCameraConfig(noise=DepthNoise(enabled=False)),
)


def test_replica_renders_the_same_picture_as_the_physics_scene():
    """Posed from joint positions and the target's position only, the replica's frame equals a render
    of the stepped physics scene (arm moved away from home, target moved)."""
    with PandaScene(motion="fast", seed=3) as scene:
        scene.command_positions(np.array([0.4, -0.3, 0.2, -2.0, 0.1, 1.9, 0.5]))
        scene.step(240)
        truth = camera_from_config(scene.client_id, CONFIG).capture()
        q, _ = scene.joint_state()
        target = scene.target_pose()[0]
    mirror = MirrorSimCamera(CONFIG, replica_scene())
    try:
        stamp = time.time()
        mirror.set_joints(q)
        mirror.set_target(target, stamp)
        frame = mirror.capture()
    finally:
        mirror.close()
    assert stamp <= frame.stamp <= stamp + mirror.max_extrapolation_s  # the instant the picture shows
    differing = np.any(frame.rgb != truth.rgb, axis=2).mean()
    assert differing < 0.002  # the fingers are not mirrored (held open in both): same picture
    both = (frame.depth > 0) & (truth.depth > 0)
    assert np.abs(frame.depth[both] - truth.depth[both]).max() < 1e-3
    red = (truth.rgb[:, :, 0] > 150) & (truth.rgb[:, :, 1] < 60)
    assert red.sum() > 5 and np.array_equal(red, (frame.rgb[:, :, 0] > 150) & (frame.rgb[:, :, 1] < 60))


def test_the_frame_shows_the_world_moved_on_to_its_stamp():
    """A target observed moving is drawn where it is at the frame's instant (its published velocity
    times the time since it was observed), and no further than ``max_extrapolation_s`` past it: the
    same picture as a still target placed there."""
    q = np.array([0.0, -0.4, 0.0, -2.2, 0.0, 1.8, 0.8])
    p0, v = np.array([0.5, -0.1, 0.3]), np.array([0.0, 0.8, 0.0])
    mirror = MirrorSimCamera(CONFIG, replica_scene(), max_extrapolation_s=0.1)
    try:
        mirror.set_joints(q)
        observed = time.time() - 0.03
        mirror.set_target(p0, observed, velocity=v)
        moving = mirror.capture()
        shown = moving.stamp - observed
        assert 0.03 <= shown <= 0.1
        mirror.set_target(p0 + v * shown, time.time())
        still = mirror.capture()
        assert not np.array_equal(moving.rgb, _render_at(mirror, q, p0))  # it did move
        assert np.any(moving.rgb != still.rgb, axis=2).mean() < 0.002
        mirror.set_target(p0, time.time() - 0.4, velocity=v)  # observed long ago: moved on 0.1 s only
        far = mirror.capture()
        assert far.stamp == pytest.approx(time.time() - 0.3, abs=0.05)
        assert np.any(far.rgb != _render_at(mirror, q, p0 + v * 0.1), axis=2).mean() < 0.002
    finally:
        mirror.close()


def _render_at(mirror: MirrorSimCamera, q: np.ndarray, target: np.ndarray) -> np.ndarray:
    mirror.set_joints(q)
    mirror.set_target(target, time.time())
    return mirror.capture().rgb


def test_no_world_or_a_stale_world_is_a_camera_error_not_an_old_picture():
    mirror = MirrorSimCamera(CONFIG, replica_scene(), stale_after_s=0.2)
    try:
        with pytest.raises(CameraError, match="no joint state or target pose"):
            mirror.capture()
        mirror.set_joints(np.zeros(7))
        with pytest.raises(CameraError, match="no target pose"):
            mirror.capture()
        mirror.set_target([0.5, 0.0, 0.3], time.time())
        assert mirror.capture().rgb.shape == (120, 160, 3)
        time.sleep(0.3)
        with pytest.raises(CameraError, match="physics owner gone"):
            mirror.capture()
        with pytest.raises(ValueError, match="7 finite"):
            mirror.set_joints([0.0] * 6 + [float("nan")])
        with pytest.raises(ValueError, match="3 finite"):
            mirror.set_target([0.5, 0.0], time.time())
    finally:
        mirror.close()


def test_capture_keeps_the_configured_rate():
    mirror = MirrorSimCamera(CONFIG.model_copy(update={"rate_hz": 10.0}), replica_scene())
    try:
        mirror.set_joints(np.zeros(7))
        t0 = time.monotonic()
        for _ in range(4):
            mirror.set_target([0.5, 0.0, 0.3], time.time())
            mirror.capture()
        assert time.monotonic() - t0 >= 0.29  # 4 frames at 10 Hz: 3 full periods at least
    finally:
        mirror.close()
