"""From a pixel and its depth to a 3D point: the inverse of the pinhole model, plus the shape offset."""

from __future__ import annotations

import numpy as np

from vision.camera_model import Intrinsics


def deproject(k: Intrinsics, u: float, v: float, depth: float) -> np.ndarray:
    """Camera-frame point (OpenCV axes) of pixel (u, v) at z-depth ``depth`` metres."""
    return np.array([(u - k.cx) * depth / k.fx, (v - k.cy) * depth / k.fy, depth])


def project(k: Intrinsics, point: np.ndarray) -> tuple[float, float]:
    """Pixel (u, v) of a camera-frame point in front of the camera."""
    x, y, z = np.asarray(point, float)
    if z <= 0:
        raise ValueError(f"point {point} is not in front of the camera")
    return float(k.fx * x / z + k.cx), float(k.fy * y / z + k.cy)


def surface_to_centre(
    surface_point_cam: np.ndarray, shape: str, size: float, base_from_cam_rotation: np.ndarray
) -> np.ndarray:
    """Move a point on the target's visible surface to its centre, along the viewing ray.

    ``sphere``: the ray through the centre enters the surface ``size`` before it. ``box`` (faces along
    the base axes, half-extent ``size``): it enters through the face most facing the camera,
    ``size / max_i |ray_i|`` before the centre (ray in base coordinates). ``point``: unchanged.
    """
    p = np.asarray(surface_point_cam, float)
    ray = p / np.linalg.norm(p)
    if shape == "point" or size == 0:
        return p
    if shape == "sphere":
        return p + size * ray
    if shape == "box":
        ray_base = base_from_cam_rotation @ ray
        return p + (size / float(np.max(np.abs(ray_base)))) * ray
    raise ValueError(f"unknown target shape {shape!r}")
