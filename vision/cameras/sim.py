"""Simulated RGB-D camera: renders the PyBullet scene of a given client with a pinhole model.

The picture comes from MuJoCo's renderer (``vision.cameras.mujoco_render``) by default; PyBullet's
TinyRenderer is the fallback when no OpenGL context can be opened, and what this module's matrices are for.
The physics owner (the robot interface's mock) calls ``SimRGBDCamera(client_id, ...).capture()`` on
its own client and publishes the frame; the vision pipeline never touches PyBullet. The projection
matrix is built from the intrinsics (including an off-centre principal point) and the view matrix from
the camera-to-base pose, so the render obeys the same model the pipeline deprojects with. Depth comes
out of PyBullet as a non-linear OpenGL buffer in [0, 1]; it is converted to metric z-depth.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import pybullet as pb

from vision.camera_model import Intrinsics, Pose
from vision.cameras.mujoco_render import MujocoRenderer, RendererUnavailable
from vision.cameras.protocol import CameraError, Frame
from vision.cameras.sim_config import DepthNoise, SimCameraConfig
from vision.config import VisionConfig
from vision.extrinsics import pose_to_matrix

log = logging.getLogger(__name__)

# OpenCV camera axes (x right, y down, z forward) to OpenGL camera axes (x right, y up, z backward).
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


# Where TinyRenderer samples pixel (u, v), as offsets (ax, ay) in x_ndc = 2 (u + ax) / W - 1 and
# y_ndc = 1 - 2 (v + ay) / H. OpenGL samples pixel centres (0.5, 0.5); PyBullet's TinyRenderer was
# measured (tests/vision/test_sim_camera.py) to sample at (0, 1): its rows are flipped after rasterising.
TINY_PIXEL_OFFSET = (0.0, 1.0)


def projection_matrix(
    k: Intrinsics, near: float, far: float, offset: tuple[float, float] = (0.0, 1.0)
) -> list[float]:
    """OpenGL projection (column-major, 16 floats) that renders pixel (u, v) where OpenCV's model puts it.

    ``offset`` is the renderer's pixel sampling offset (see ``TINY_PIXEL_OFFSET``).
    """
    w, h = k.width, k.height
    ax, ay = offset
    P = np.array(
        [
            [2 * k.fx / w, 0.0, 1 - 2 * (k.cx + ax) / w, 0.0],
            [0.0, 2 * k.fy / h, 2 * (k.cy + ay) / h - 1, 0.0],
            [0.0, 0.0, -(far + near) / (far - near), -2 * far * near / (far - near)],
            [0.0, 0.0, -1.0, 0.0],
        ]
    )
    return P.T.ravel().tolist()


def view_matrix(camera_to_base: np.ndarray) -> list[float]:
    """OpenGL view matrix (column-major) of a camera whose OpenCV-frame pose in the world is given."""
    gl_to_world = camera_to_base @ _CV_TO_GL
    R, t = gl_to_world[:3, :3], gl_to_world[:3, 3]
    V = np.eye(4)
    V[:3, :3] = R.T
    V[:3, 3] = -R.T @ t
    return V.T.ravel().tolist()


def buffer_to_metres(buffer: np.ndarray, near: float, far: float) -> np.ndarray:
    """OpenGL depth buffer value d in [0, 1] to z-depth in metres (0 where nothing was hit)."""
    d = np.asarray(buffer, np.float64)
    z = far * near / (far - (far - near) * d)
    z[d >= 1.0] = 0.0  # the far plane: no surface, as a real depth camera reports it
    return z.astype(np.float32)


def add_depth_noise(depth: np.ndarray, noise: DepthNoise, rng: np.random.Generator) -> np.ndarray:
    """Gaussian noise with sigma growing with z^2, and randomly dropped pixels (0)."""
    if not noise.enabled:
        return depth
    valid = depth > 0
    sigma = noise.base_sigma + noise.sigma_per_m2 * depth.astype(np.float64) ** 2
    noisy = depth + (rng.standard_normal(depth.shape) * sigma).astype(np.float32)
    noisy = np.where(valid, np.maximum(noisy, 0.0), 0.0)
    if noise.dropout > 0:
        noisy[rng.random(depth.shape) < noise.dropout] = 0.0
    return noisy.astype(np.float32)


class SimRGBDCamera:
    """Renders registered RGB-D frames of PyBullet client ``client_id`` (headless).

    ``pose`` is the camera-to-base transform the camera is rendered from (the ground truth). With the
    MuJoCo renderer the bodies in the client when the camera is made are the ones drawn.
    """

    def __init__(
        self,
        client_id: int,
        intrinsics: Intrinsics,
        pose: Pose,
        config: SimCameraConfig | None = None,
    ) -> None:
        self.client_id = int(client_id)
        self._intrinsics = intrinsics
        self.config = config or SimCameraConfig()
        self._rng = np.random.default_rng(self.config.seed)
        self._seq = 0
        self._mujoco = self._open_mujoco() if self.config.renderer == "mujoco" else None
        self.set_pose(pose)

    def _open_mujoco(self) -> MujocoRenderer | None:
        try:
            return MujocoRenderer(self.client_id, self._intrinsics, self.config.near, self.config.far)
        except RendererUnavailable as exc:
            log.warning(
                "sim camera: %s; rendering with PyBullet's TinyRenderer instead (several times slower: "
                "install Debian's libegl1 and libegl-mesa0, or set MUJOCO_GL=osmesa with libosmesa6)",
                exc,
            )
            return None

    @property
    def renderer_name(self) -> str:
        """Which renderer draws the frames: ``mujoco`` or ``tiny``."""
        return "mujoco" if self._mujoco is not None else "tiny"

    @property
    def intrinsics(self) -> Intrinsics:
        return self._intrinsics

    def set_pose(self, pose: Pose) -> None:
        self.pose = pose
        self.camera_to_base = pose_to_matrix(pose)
        self._view = view_matrix(self.camera_to_base)
        self._proj = projection_matrix(self._intrinsics, self.config.near, self.config.far, TINY_PIXEL_OFFSET)

    def capture(self) -> Frame:
        """Render now; ``Frame.stamp`` is the wall-clock time just before rendering."""
        if not pb.isConnected(self.client_id):
            raise CameraError(f"sim camera: pybullet client {self.client_id} is not connected")
        stamp = time.time()
        rgb, depth = self._mujoco.render(self.camera_to_base) if self._mujoco else self._render_tiny()
        depth = add_depth_noise(depth, self.config.noise, self._rng)
        self._seq += 1
        return Frame(rgb=rgb, depth=depth, intrinsics=self._intrinsics, stamp=stamp, seq=self._seq)

    def _render_tiny(self) -> tuple[np.ndarray, np.ndarray]:
        k = self._intrinsics
        _, _, rgba, depth_buf, _ = pb.getCameraImage(
            k.width,
            k.height,
            viewMatrix=self._view,
            projectionMatrix=self._proj,
            renderer=pb.ER_TINY_RENDERER,
            flags=pb.ER_NO_SEGMENTATION_MASK,
            physicsClientId=self.client_id,
        )
        rgb = np.ascontiguousarray(np.reshape(rgba, (k.height, k.width, 4))[:, :, :3], dtype=np.uint8)
        depth = buffer_to_metres(
            np.reshape(depth_buf, (k.height, k.width)), self.config.near, self.config.far
        )
        return rgb, depth

    def close(self) -> None:
        """Releases the renderer's OpenGL context; the scene (and its client) belongs to its owner."""
        if self._mujoco is not None:
            self._mujoco.close()
            self._mujoco = None


def camera_from_config(client_id: int, vision_config: VisionConfig) -> SimRGBDCamera:
    """The sim camera of a ``VisionConfig`` (rendered from ``sim.pose``, the physical placement)."""
    return SimRGBDCamera(client_id, vision_config.intrinsics, vision_config.sim_pose(), vision_config.sim)
