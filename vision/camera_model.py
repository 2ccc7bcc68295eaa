"""A camera's model: its lens (pinhole intrinsics) and where it is (a pose). The camera backends, the
calibration and the pipeline share it."""

from __future__ import annotations

import math
from typing import Annotated

import numpy as np
from pydantic import Field, field_validator, model_validator

from common.config import Section, Vec3


class Intrinsics(Section):
    """Pinhole model in OpenCV convention: pixel (u, v) centre at integer coordinates, v down."""

    width: int = Field(640, ge=8, le=8192, description="image width in pixels")
    height: int = Field(480, ge=8, le=8192, description="image height in pixels")
    fx: float = Field(615.0, gt=0, description="focal length along x, in pixels")
    fy: float = Field(615.0, gt=0, description="focal length along y, in pixels")
    cx: float = Field(
        319.5, description="principal point's x (pixels, from the left image edge; pixel centres at integers)"
    )
    cy: float = Field(
        239.5, description="principal point's y (pixels, from the top image edge; pixel centres at integers)"
    )

    @model_validator(mode="after")
    def _principal_point_inside(self) -> Intrinsics:
        if not (0 <= self.cx < self.width and 0 <= self.cy < self.height):
            raise ValueError(
                f"principal point ({self.cx}, {self.cy}) outside the {self.width}x{self.height} image"
            )
        return self

    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same lens at another resolution (pixel centres kept consistent)."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            width=width,
            height=height,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
        )


class Pose(Section):
    """A rigid transform as position (m) and unit quaternion (x, y, z, w).

    For extrinsics it is camera-to-base: it maps points in the camera frame (OpenCV: x right,
    y down, z along the optical axis) to the robot base frame.
    """

    position: Vec3 = Field((0.0, 0.0, 0.0), description="translation (x, y, z) in metres")
    quaternion: Annotated[tuple[float, ...], Field(min_length=4, max_length=4)] = Field(
        (0.0, 0.0, 0.0, 1.0), description="rotation as a unit quaternion (x, y, z, w); normalised when loaded"
    )

    @field_validator("quaternion")
    @classmethod
    def _unit(cls, q: tuple[float, ...]) -> tuple[float, ...]:
        """Within 1e-3 of unit norm (rounded YAML values), then normalised exactly."""
        norm = math.hypot(*q)  # no overflow on a huge component: the error names its norm, not inf
        if abs(norm - 1.0) > 1e-3:
            raise ValueError(f"quaternion (x, y, z, w) must have unit norm, got norm {norm:.6g}")
        return tuple(float(x) / norm for x in q)
