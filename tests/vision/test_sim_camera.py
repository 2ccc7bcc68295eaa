"""The sim camera obeys the pinhole model it claims: pixels, depth in metres, noise."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from sim.panda_scene import TARGET_HALF
from vision.camera_model import Intrinsics
from vision.cameras.sim import SimRGBDCamera, buffer_to_metres, camera_from_config
from vision.cameras.sim_config import DepthNoise, SimCameraConfig
from vision.deprojection import project
from vision.extrinsics import apply, invert, look_at, pose_to_matrix

NO_NOISE = SimCameraConfig(noise=DepthNoise(enabled=False))
RENDERERS = ("mujoco", "tiny")  # the camera's renderer and its fallback obey the same model


def no_noise(renderer: str) -> SimCameraConfig:
    return NO_NOISE.model_copy(update={"renderer": renderer})


@pytest.fixture
def client():
    cid = pb.connect(pb.DIRECT)
    yield cid
    pb.disconnect(cid)


def _sphere(cid: int, radius: float = 0.02) -> int:
    vis = pb.createVisualShape(pb.GEOM_SPHERE, radius=radius, rgbaColor=[1, 0, 0, 1], physicsClientId=cid)
    return pb.createMultiBody(0, -1, vis, [0, 0, 0], physicsClientId=cid)


@pytest.mark.parametrize("renderer", RENDERERS)
@pytest.mark.parametrize("size", [(160, 120), (320, 240)])
def test_sphere_centre_lands_on_projected_pixel(client, size, renderer):
    """Off-centre principal point, non-square pixels: the blob centroid is where K says.

    Each position within 0.35 px (pixel quantisation of a small blob), no systematic bias (< 0.12 px).
    """
    w, h = size
    k = Intrinsics(w, h, 0.9 * w, 0.85 * w, w / 2 + 7.3, h / 2 - 3.1)
    pose = look_at([1.0, 0.2, 0.3], [0.0, 0.0, 0.0])
    cam = SimRGBDCamera(client, k, pose, no_noise(renderer))
    body = _sphere(client, 0.04)
    cam_from_base = invert(pose_to_matrix(pose))
    offsets = []
    for p in np.random.default_rng(0).uniform([-0.1, -0.2, -0.12], [0.1, 0.2, 0.12], size=(8, 3)):
        pb.resetBasePositionAndOrientation(body, p.tolist(), [0, 0, 0, 1], physicsClientId=client)
        frame = cam.capture()
        red = (frame.rgb[..., 0] > 100) & (frame.rgb[..., 1] < 60)
        ys, xs = np.nonzero(red)
        u, v = project(k, apply(cam_from_base, p))
        offsets.append((xs.mean() - u, ys.mean() - v))
    offsets = np.array(offsets)
    assert np.abs(offsets).max() < 0.35, offsets
    assert np.all(np.abs(offsets.mean(axis=0)) < 0.12), offsets.mean(axis=0)


@pytest.mark.parametrize("renderer", RENDERERS)
def test_depth_is_metric_z(client, renderer):
    """A wall facing the camera at 1.5 m reads 1.5 m (z-depth) everywhere, within 2 mm; sky reads 0."""
    k = Intrinsics(160, 120, 140.0, 140.0, 79.5, 59.5)
    vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[0.01, 0.4, 0.3], physicsClientId=client)
    pb.createMultiBody(0, -1, vis, [0.01, 0, 0], physicsClientId=client)  # front face at x = 0.02
    cam = SimRGBDCamera(client, k, look_at([1.52, 0, 0], [0, 0, 0]), no_noise(renderer))
    frame = cam.capture()
    centre = frame.depth[45:75, 50:110]
    assert np.all(np.abs(centre - 1.5) < 0.002), (centre.min(), centre.max())
    assert frame.depth[0, 0] == 0.0  # nothing there: no depth, as a real sensor reports
    assert frame.depth.dtype == np.float32 and frame.rgb.shape == (120, 160, 3)


@pytest.mark.parametrize("distance", [0.5, 1.0, 1.5])
def test_depth_at_the_target_matches_the_scene(scene, distance):
    """The camera's real resolution (640x480, the configured intrinsics, MuJoCo's renderer): the depth
    at the scene's target, seen from 0.5-1.5 m at an angle, is the target's face within 2 mm."""
    k = Intrinsics(640, 480, 615.0, 615.0, 321.7, 238.2)
    target, _ = scene.target_pose()
    direction = np.array([0.8, -0.3, 0.5]) / np.linalg.norm([0.8, -0.3, 0.5])
    pose = look_at(target + distance * direction, target)
    cam = SimRGBDCamera(scene.client_id, k, pose, NO_NOISE)
    assert cam.renderer_name == "mujoco"
    frame = cam.capture()
    assert frame.rgb.shape == (480, 640, 3) and frame.depth.shape == (480, 640)
    assert frame.intrinsics == k
    cam_to_base = pose_to_matrix(pose)
    u, v = project(k, apply(invert(cam_to_base), target))
    for du, dv in ((0, 0), (-3, 2), (4, -3)):  # pixels on the target's image near its centre
        px, py = round(u) + du, round(v) + dv
        ray = cam_to_base[:3, :3] @ np.array([(px - k.cx) / k.fx, (py - k.cy) / k.fy, 1.0])
        t = _ray_hits_cube(cam_to_base[:3, 3], ray, target, TARGET_HALF)  # ray's z component is 1
        assert abs(frame.depth[py, px] - t) < 0.002, (distance, px, py, frame.depth[py, px], t)


def _ray_hits_cube(origin: np.ndarray, ray: np.ndarray, centre: np.ndarray, half: float) -> float:
    """Where ``origin + t ray`` first meets an axis-aligned cube (slab method); t is then the z-depth
    because the ray's camera-frame z is 1."""
    with np.errstate(divide="ignore"):
        t1, t2 = (centre - half - origin) / ray, (centre + half - origin) / ray
    near, far = np.minimum(t1, t2).max(), np.maximum(t1, t2).min()
    assert near <= far, "the ray misses the target"
    return float(near)


def test_fallback_renderer_warns(client, monkeypatch, caplog):
    """No OpenGL context (here: MUJOCO_GL names a platform this process cannot use): the camera says so
    and renders with TinyRenderer."""
    monkeypatch.setenv("MUJOCO_GL", "glx")
    with caplog.at_level("WARNING", logger="vision.cameras.sim"):
        cam = SimRGBDCamera(client, Intrinsics(80, 60, 70.0, 70.0, 39.5, 29.5), look_at([1, 0, 0], [0, 0, 0]))
    assert cam.renderer_name == "tiny"
    assert "TinyRenderer" in caplog.text and "MUJOCO_GL=glx" in caplog.text
    assert cam.capture().rgb.shape == (60, 80, 3)


def test_buffer_conversion_round_trip():
    near, far = 0.05, 4.0
    z = np.array([0.1, 0.5, 1.0, 3.9])
    d = (far / (far - near)) * (1 - near / z)  # the OpenGL depth buffer value of z-depth z
    assert np.allclose(buffer_to_metres(d, near, far), z, atol=1e-5)


def test_noise_grows_with_distance_and_drops_pixels(client):
    vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[0.01, 2, 2], physicsClientId=client)
    pb.createMultiBody(0, -1, vis, [-0.01, 0, 0], physicsClientId=client)
    k = Intrinsics(120, 90, 100.0, 100.0, 59.5, 44.5)
    noise = SimCameraConfig(noise=DepthNoise(base_sigma=0.0005, sigma_per_m2=0.002, dropout=0.05), seed=1)
    stds = []
    for dist in (0.8, 2.5):
        cam = SimRGBDCamera(client, k, look_at([dist, 0, 0], [0, 0, 0]), noise)
        depth = cam.capture().depth
        valid = depth[depth > 0]
        assert 0.03 < 1 - valid.size / depth.size < 0.07  # about 5 % dropped
        stds.append(valid.std())
        assert abs(valid.mean() - dist) < 0.003
    expected = [0.0005 + 0.002 * d**2 for d in (0.8, 2.5)]
    assert np.allclose(stds, expected, rtol=0.15), (stds, expected)


def test_renders_the_panda_scene_target(scene, config):
    cam = camera_from_config(scene.client_id, config)
    frame = cam.capture()
    red = (frame.rgb[..., 0] > 100) & (frame.rgb[..., 1] < 60)
    assert red.sum() > 50  # the scene's red target is in view
    assert frame.seq == 1 and cam.capture().seq == 2


def test_disconnected_client_is_a_camera_error(config):
    from vision.cameras.protocol import CameraError

    cid = pb.connect(pb.DIRECT)
    cam = camera_from_config(cid, config)
    pb.disconnect(cid)
    with pytest.raises(CameraError, match="not connected"):
        cam.capture()
