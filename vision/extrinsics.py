"""Rigid transforms between the camera and the robot base frame.

Kept as 4x4 homogeneous matrices (numpy) with conversions to and from the config's position +
quaternion, so the pipeline, the sim renderer and calibration share one convention.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from vision.camera_model import Pose


def pose_to_matrix(pose: Pose) -> np.ndarray:
    """4x4 matrix of ``pose`` (maps child-frame points to the parent frame)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(pose.quaternion).as_matrix()
    T[:3, 3] = pose.position
    return T


def matrix_to_pose(T: np.ndarray) -> Pose:
    """Pose (position, quaternion xyzw) of a 4x4 rigid transform."""
    T = np.asarray(T, float)
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    return Pose(tuple(float(x) for x in T[:3, 3]), tuple(float(x) for x in q))


def make_transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, float).ravel()
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (no general matrix inverse needed)."""
    R, t = T[:3, :3], T[:3, 3]
    return make_transform(R.T, -R.T @ t)


def apply(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Transform one point (3,) or many (N, 3)."""
    p = np.asarray(points, float)
    return p @ T[:3, :3].T + T[:3, 3]


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> Pose:
    """Camera-to-base pose of a camera at ``eye`` whose optical axis points at ``target``.

    OpenCV camera axes: z forward, x right, y down (image rows), so y is -up projected.
    """
    eye, target, up = (np.asarray(v, float) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: viewing direction parallel to 'up'")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return matrix_to_pose(make_transform(np.column_stack([x, y, z]), eye))


def rotation_error_deg(Ta: np.ndarray, Tb: np.ndarray) -> float:
    """Angle (degrees) of the rotation taking ``Ta``'s orientation to ``Tb``'s."""
    R = Ta[:3, :3].T @ Tb[:3, :3]
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(R).as_rotvec())))


def translation_error(Ta: np.ndarray, Tb: np.ndarray) -> float:
    return float(np.linalg.norm(Ta[:3, 3] - Tb[:3, 3]))
