"""Renders a PyBullet world with MuJoCo's OpenGL renderer (EGL or OSMesa, headless).

PyBullet's TinyRenderer rasterises on the CPU in one thread: 640x480 came out at under 6 fps here, a
fifth of a D435's 30 fps. MuJoCo's renderer on Mesa's llvmpipe draws the same scene several times
faster (``bench/vision_bench.py`` measures both side by side). PyBullet stays the owner of the world:
this module copies each body's visual shapes (meshes, boxes, spheres) once into a MuJoCo model of
mocap bodies, then poses them from PyBullet's link frames before every frame. Colour and depth come out
of one render pass; depth is z-depth in metres, 0 where nothing was hit, as a depth camera reports it.
Textures are not drawn (a shape shows its colour): the simulated calibration board, a textured quad, is
rendered with TinyRenderer.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import pybullet as pb

from common.errors import AdaptiveHError
from vision.camera_model import Intrinsics


class RendererUnavailable(AdaptiveHError, RuntimeError):
    """No OpenGL context could be made (no EGL/OSMesa library, no driver)."""


def gl_platform() -> str:
    """MuJoCo's ``MUJOCO_GL`` as the user set it; headless EGL (Mesa's llvmpipe without a GPU) if unset."""
    return os.environ.get("MUJOCO_GL", "").strip().lower() or "egl"


def _gl_context(width: int, height: int) -> Any:
    """A headless OpenGL context of ``gl_platform()``, chosen here rather than when ``mujoco`` was first
    imported (mink imports it before any camera exists)."""
    platform = gl_platform()
    try:
        if platform == "egl":
            from mujoco.egl import GLContext
        elif platform == "osmesa":
            from mujoco.osmesa import GLContext
        else:
            raise RendererUnavailable(f"MUJOCO_GL={platform}: a headless camera needs egl or osmesa")
        return GLContext(width, height)
    except RendererUnavailable:
        raise
    except Exception as exc:  # each platform library raises its own errors (ImportError, OSError, ...)
        raise RendererUnavailable(
            f"MuJoCo could not open an OpenGL context (MUJOCO_GL={platform}): {exc}"
        ) from exc


@dataclass(frozen=True)
class VisualLink:
    """One PyBullet link (or a body's base, ``link`` -1) with visual shapes, as a MuJoCo mocap body."""

    body: int
    link: int
    geoms: tuple[str, ...]  # the MJCF of its geoms, in the link's frame


def _geom_xml(shape: tuple, meshes: dict[tuple[str, tuple[float, ...]], str]) -> str | None:
    """MJCF for one ``getVisualShapeData`` row, or None for a kind this renderer does not draw."""
    kind, dims, path = shape[2], shape[3], shape[4].decode()
    pos = " ".join(f"{x:.6g}" for x in shape[5])
    x, y, z, w = shape[6]
    rgba = " ".join(f"{c:.4g}" for c in shape[7])
    placed = f'pos="{pos}" quat="{w:.6g} {x:.6g} {y:.6g} {z:.6g}" rgba="{rgba}"'
    if kind == pb.GEOM_BOX:
        size = " ".join(f"{d / 2:.6g}" for d in dims)
        return f'<geom type="box" size="{size}" {placed}/>'
    if kind == pb.GEOM_SPHERE:
        return f'<geom type="sphere" size="{dims[0]:.6g}" {placed}/>'
    if kind in (pb.GEOM_CYLINDER, pb.GEOM_CAPSULE):
        name = "cylinder" if kind == pb.GEOM_CYLINDER else "capsule"
        return f'<geom type="{name}" size="{dims[1]:.6g} {dims[0] / 2:.6g}" {placed}/>'
    if kind == pb.GEOM_MESH and path:
        key = (path, tuple(round(float(d), 6) for d in dims))
        name = meshes.setdefault(key, f"mesh{len(meshes)}")
        return f'<geom type="mesh" mesh="{name}" {placed}/>'
    return None


def _visual_links(client: int) -> tuple[list[VisualLink], dict[tuple[str, tuple[float, ...]], str]]:
    meshes: dict[tuple[str, tuple[float, ...]], str] = {}
    by_link: dict[tuple[int, int], list[str]] = {}
    for i in range(pb.getNumBodies(physicsClientId=client)):
        body = pb.getBodyUniqueId(i, physicsClientId=client)
        for shape in pb.getVisualShapeData(body, physicsClientId=client):
            geom = _geom_xml(shape, meshes)
            if geom is not None:
                by_link.setdefault((body, shape[1]), []).append(geom)
    links = [VisualLink(body, link, tuple(geoms)) for (body, link), geoms in by_link.items()]
    return links, meshes


def read_obj(path: str, scale: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (scaled) and triangles of every object in an OBJ file.

    MuJoCo's own OBJ loader keeps only part of a file made of several objects (the Panda's hand), so
    the meshes are read here and handed to MuJoCo as vertex and face lists.
    """
    vertices: list[list[float]] = []
    faces: list[list[int]] = []
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                vertices.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("f "):
                idx = [int(c.split("/")[0]) for c in line.split()[1:]]
                idx = [i - 1 if i > 0 else len(vertices) + i for i in idx]
                faces.extend([idx[0], idx[j], idx[j + 1]] for j in range(1, len(idx) - 1))
    return np.asarray(vertices) * np.asarray(scale), np.asarray(faces, dtype=np.int64)


@functools.lru_cache(maxsize=64)
def _mesh_lists(path: str, scale: tuple[float, ...]) -> tuple[str, str]:
    """The MJCF vertex and face lists of a mesh (parsed once per process: a model is rebuilt whenever
    bodies come or go)."""
    vertices, faces = read_obj(path, scale)
    return " ".join(f"{x:.6g}" for x in vertices.ravel()), " ".join(str(i) for i in faces.ravel())


def _mesh_xml(name: str, path: str, scale: tuple[float, ...]) -> str:
    v, f = _mesh_lists(path, scale)
    return f'<mesh name="{name}" vertex="{v}" face="{f}" inertia="shell"/>'


def _model_xml(
    links: list[VisualLink],
    meshes: dict[tuple[str, tuple[float, ...]], str],
    k: Intrinsics,
    near: float,
    far: float,
) -> str:
    assets = "".join(_mesh_xml(name, path, scale) for (path, scale), name in meshes.items())
    bodies = "".join(f'<body mocap="true">{"".join(link.geoms)}</body>' for link in links)
    # extent 1: znear/zfar are then the clip distances in metres. No MSAA and no shadows: a depth
    # camera's picture has neither, and each multiplies llvmpipe's cost.
    return (
        "<mujoco><compiler angle='radian'/>"
        f"<statistic extent='1' center='0 0 0'/>"
        f"<visual><global offwidth='{k.width}' offheight='{k.height}'/>"
        f"<quality offsamples='0' shadowsize='0'/><map znear='{near}' zfar='{far}'/>"
        "<headlight ambient='0.4 0.4 0.4' diffuse='0.6 0.6 0.6' specular='0 0 0'/></visual>"
        f"<asset>{assets}</asset>"
        "<default><geom contype='0' conaffinity='0' density='0'/></default>"
        f"<worldbody>{bodies}</worldbody></mujoco>"
    )


class MujocoRenderer:
    """Colour and metric depth of PyBullet client ``client`` through a pinhole camera, by MuJoCo.

    The MuJoCo model follows the client's bodies: it is rebuilt when one is added or removed. Not
    thread-safe; the OpenGL context is current on the rendering thread only while it renders.
    """

    def __init__(self, client: int, intrinsics: Intrinsics, near: float, far: float) -> None:
        self.client = int(client)
        self.intrinsics = intrinsics
        self.near, self.far = float(near), float(far)
        self._gl = _gl_context(intrinsics.width, intrinsics.height)
        self._bodies: tuple[int, ...] | None = None
        self._context: Any = None
        self._option, self._perturb = mujoco.MjvOption(), mujoco.MjvPerturb()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._rect = mujoco.MjrRect(0, 0, intrinsics.width, intrinsics.height)
        self._rgb = np.empty((intrinsics.height, intrinsics.width, 3), np.uint8)
        self._depth = np.empty((intrinsics.height, intrinsics.width), np.float32)
        self._sync()

    def _sync(self) -> None:
        """(Re)build the MuJoCo model, its GPU context and scene if the client's bodies changed."""
        n = pb.getNumBodies(physicsClientId=self.client)
        bodies = tuple(pb.getBodyUniqueId(i, physicsClientId=self.client) for i in range(n))
        if bodies == self._bodies:
            return
        self._links, meshes = _visual_links(self.client)
        self._link_frames()
        k = self.intrinsics
        self.model = mujoco.MjModel.from_xml_string(_model_xml(self._links, meshes, k, self.near, self.far))
        self.data = mujoco.MjData(self.model)
        with self._gl.as_current():
            if self._context is not None:
                self._context.free()
            self._context = mujoco.MjrContext(self.model, mujoco.mjtFontScale.mjFONTSCALE_100)
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        self._context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(self.model, maxgeom=max(100, 2 * self.model.ngeom))
        for flag in (
            mujoco.mjtRndFlag.mjRND_SHADOW,
            mujoco.mjtRndFlag.mjRND_REFLECTION,
            mujoco.mjtRndFlag.mjRND_SKYBOX,
            mujoco.mjtRndFlag.mjRND_HAZE,
        ):
            self._scene.flags[flag] = False
        self._bodies = bodies

    def _link_frames(self) -> None:
        """What posing needs of the links, fixed while the bodies are: each body's moving links (read in
        one call a body) and each base's inertial-to-link offset (PyBullet gives a base's inertial frame;
        its visuals hang off its link frame)."""
        self._moving: dict[int, list[int]] = {}
        self._base_offsets: dict[int, tuple] = {}
        for link in self._links:
            if link.link < 0:
                inertial = pb.getDynamicsInfo(link.body, -1, physicsClientId=self.client)[3:5]
                self._base_offsets[link.body] = pb.invertTransform(*inertial)
            else:
                self._moving.setdefault(link.body, []).append(link.link)

    def _pose_links(self) -> None:
        frames: dict[tuple[int, int], tuple] = {}
        for body, links in self._moving.items():
            states = pb.getLinkStates(body, links, computeForwardKinematics=True, physicsClientId=self.client)
            frames.update({(body, j): (state[4], state[5]) for j, state in zip(links, states, strict=True)})
        for body, offset in self._base_offsets.items():
            com = pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
            frames[body, -1] = pb.multiplyTransforms(*com, *offset)
        for i, link in enumerate(self._links):
            pos, quat = frames[link.body, link.link]
            self.data.mocap_pos[i] = pos
            self.data.mocap_quat[i] = (quat[3], quat[0], quat[1], quat[2])
        mujoco.mj_kinematics(self.model, self.data)

    def _set_camera(self, camera_to_base: np.ndarray) -> None:
        """The GL camera and its off-centre frustum: pixel (u, v)'s centre lands where OpenCV puts it."""
        k, n = self.intrinsics, self.near
        left, right = (-0.5 - k.cx) * n / k.fx, (k.width - 0.5 - k.cx) * n / k.fx
        for gl in self._scene.camera:  # mono: both eyes the same
            gl.pos[:] = camera_to_base[:3, 3]
            gl.forward[:] = camera_to_base[:3, 2]
            gl.up[:] = -camera_to_base[:3, 1]
            gl.frustum_center = (left + right) / 2
            gl.frustum_width = (right - left) / 2
            gl.frustum_top = (0.5 + k.cy) * n / k.fy
            gl.frustum_bottom = -(k.height - 0.5 - k.cy) * n / k.fy
            gl.frustum_near, gl.frustum_far = n, self.far
            gl.orthographic = 0

    def render(self, camera_to_base: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """RGB (H, W, 3) uint8 and z-depth (H, W) float32 metres (0: nothing hit) of the world now."""
        self._sync()
        self._pose_links()
        mujoco.mjv_updateScene(
            self.model,
            self.data,
            self._option,
            self._perturb,
            self._camera,
            mujoco.mjtCatBit.mjCAT_ALL,
            self._scene,
        )
        self._set_camera(camera_to_base)
        with self._gl.as_current():  # released after: whichever thread captures next can take it
            mujoco.mjr_render(self._rect, self._scene, self._context)
            mujoco.mjr_readPixels(self._rgb, self._depth, self._rect, self._context)
        return np.flipud(self._rgb).copy(), self._metres(np.flipud(self._depth))

    def _metres(self, buffer: np.ndarray) -> np.ndarray:
        """Reversed-Z depth buffer (1 at near, 0 at far) to z-depth: z = n f / (n + d (f - n))."""
        n, f = self.near, self.far
        d = buffer.astype(np.float64)
        z = n * f / (n + d * (f - n))
        z[d <= 0.0] = 0.0
        return z.astype(np.float32)

    def close(self) -> None:
        with self._gl.as_current():
            self._context.free()
        self._gl.free()
