"""The arm for Foxglove's 3D panel: each link's mesh, posed by forward kinematics of the state's joints.

Foxglove's URDF layer needs the URDF and its ``package://`` meshes reachable from the viewer's machine,
which a recording opened elsewhere does not have. So the meshes travel in the data instead: one
``SceneUpdate`` with a ``ModelPrimitive`` per link, each locked to the link's frame, sent once (the 3D
panel keeps entities without a lifetime), and a ``FrameTransform`` base -> link per link at state rate.
The meshes are the URDF's collision meshes (~100-1000 vertices each, ~0.3 MB in all, against ~10 MB for
the visual ones), converted from OBJ to binary STL, a format Foxglove's model loader reads without the
material files the OBJs name.
"""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from robot_io.kinematics import Kinematics


@dataclass(frozen=True)
class LinkMesh:
    """One link's mesh: binary STL bytes and its pose in the link frame (position, quaternion x y z w)."""

    link: str
    stl: bytes
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]


def obj_to_stl(text: str) -> bytes:
    """Binary STL of the triangles of a Wavefront OBJ (polygons fanned into triangles, normals zero)."""
    vertices: list[list[float]] = []
    triangles: list[tuple[int, int, int]] = []
    for line in text.splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            vertices.append([float(x) for x in parts[1:4]])
        elif parts[0] == "f":
            idx = [int(p.split("/")[0]) for p in parts[1:]]
            idx = [i - 1 if i > 0 else len(vertices) + i for i in idx]  # OBJ: 1-based, negative = relative
            triangles += [(idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1)]
    v = np.asarray(vertices, dtype="<f4")
    rows = np.zeros(len(triangles), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    rows["v"] = v[np.asarray(triangles, dtype=int)] if triangles else rows["v"]
    return b"\0" * 80 + struct.pack("<I", len(triangles)) + rows.tobytes()


def _origin(element: ET.Element) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    origin = element.find("origin")
    xyz = [float(x) for x in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()]
    rpy = [float(x) for x in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()]
    q = Rotation.from_euler("xyz", rpy).as_quat()  # URDF rpy: fixed axes x, y, z
    return (xyz[0], xyz[1], xyz[2]), (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def link_meshes(urdf_path: Path) -> list[LinkMesh]:
    """Every link's first collision mesh, read through the URDF (``package://`` = the URDF's folder)."""
    root = ET.parse(urdf_path).getroot()
    out = []
    for link in root.iter("link"):
        collision = link.find("collision")
        mesh = collision.find("geometry/mesh") if collision is not None else None
        if mesh is None:
            continue
        name = mesh.get("filename", "")
        path = urdf_path.parent / name.removeprefix("package://")
        if path.suffix.lower() != ".obj" or not path.is_file():
            continue
        position, quaternion = _origin(collision)
        out.append(LinkMesh(link.get("name", ""), obj_to_stl(path.read_text()), position, quaternion))
    return out


class ArmPoser:
    """Poses of the arm's links in the base frame from joint positions (the robot-io's Pinocchio model)."""

    def __init__(self, kinematics: Kinematics | None = None) -> None:
        import pinocchio as pin

        self.kin = kinematics or Kinematics()
        self._pin = pin
        frames = self.kin.model.frames
        self.links = [f.name for f in frames if f.type == pin.FrameType.BODY]
        self._ids = [self.kin.model.getFrameId(name) for name in self.links]
        self.meshes = link_meshes(self.kin.description.urdf_path)

    def poses(self, q: list[float] | np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """(link, position, quaternion x y z w) of every link for the arm joints ``q``."""
        model, data = self.kin.model, self.kin.data
        self._pin.framesForwardKinematics(model, data, np.asarray(q, float))
        placements = [data.oMf[fid] for fid in self._ids]
        quats = Rotation.from_matrix(np.stack([p.rotation for p in placements])).as_quat()  # one call: fast
        return [
            (name, p.translation.copy(), quat)
            for name, p, quat in zip(self.links, placements, quats, strict=True)
        ]
