"""Typed configuration of the vision module (the ``vision:`` section of a stack config).

Every section declares its types, ranges and closed sets, so a bad YAML value fails at start-up with a
message naming the key path, not mid-run. Lists from YAML become tuples.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from common.config import Section
from vision.camera_model import Intrinsics, Pose
from vision.cameras.realsense_config import RealSenseConfig
from vision.cameras.sim_config import SimCameraConfig

Hue = Annotated[int, Field(ge=0, le=180)]  # OpenCV's H is 0..180
Byte = Annotated[int, Field(ge=0, le=255)]
HSVRange = tuple[Hue, Byte, Byte, Hue, Byte, Byte]  # (hmin, smin, vmin, hmax, smax, vmax)


class DetectionConfig(Section):
    """Colour segmentation of the target and how its depth is taken.

    ``hsv_ranges``: OpenCV HSV (H in 0..180) lower/upper bounds, several ranges OR-ed (red wraps).
    Depth is the median of valid depth in a ``depth_patch`` square around the blob's centroid, i.e.
    where the ray through the target's centre enters its surface. ``target_shape``/``target_size``
    turn that surface point into the centre: a sphere of radius ``size`` is ``size`` deeper along the
    ray; a box of half-extent ``size`` with faces aligned to the base axes (the sim target) is
    ``size / max|ray_i|`` deeper; ``point`` adds nothing.
    """

    hsv_ranges: Annotated[tuple[HSVRange, ...], Field(min_length=1)] = (
        (0, 120, 60, 8, 255, 255),
        (172, 120, 60, 180, 255, 255),
    )
    min_area_px: int = Field(12, ge=1)
    morph_kernel: int = Field(3, ge=0)
    depth_patch: int = Field(9, ge=1)
    min_depth: float = Field(0.1, gt=0)
    max_depth: float = 4.0
    min_valid_fraction: float = Field(0.2, gt=0, le=1)  # of the patch's mask pixels that must have depth
    target_shape: Literal["box", "sphere", "point"] = "box"
    target_size: float = Field(0.025, ge=0)

    @field_validator("hsv_ranges")
    @classmethod
    def _lower_below_upper(cls, ranges: tuple[HSVRange, ...]) -> tuple[HSVRange, ...]:
        for i, r in enumerate(ranges):
            if any(r[k] > r[k + 3] for k in range(3)):
                raise ValueError(f"hsv_ranges[{i}]: lower bound above upper bound in {list(r)}")
        return ranges

    @model_validator(mode="after")
    def _depth_range(self) -> DetectionConfig:
        if not self.min_depth < self.max_depth:
            raise ValueError(f"need 0 < min_depth < max_depth, got {self.min_depth}, {self.max_depth}")
        return self


class TrackingConfig(Section):
    """Constant-velocity Kalman filter on the base-frame position.

    ``accel_sigma``: white-acceleration noise (m/s^2) — how fast the target may change velocity.
    ``lost_after_s``: time without an accepted detection after which the target is reported lost.
    ``gate_sigma``: Mahalanobis gate rejecting measurements that jump implausibly far.
    ``reacquire_after``: this many consecutive gated-out detections that agree with each other (moving
    at most ``max_speed`` m/s between them) mean the target really moved (picked up and put down, a
    sim reset): the track restarts there instead of coasting on the old one until it is lost.
    """

    accel_sigma: float = Field(0.4, gt=0)
    measurement_sigma: float = Field(0.004, gt=0)
    lost_after_s: float = Field(0.3, gt=0)
    gate_sigma: float = Field(6.0, gt=0)
    max_dt: float = Field(0.5, gt=0)
    reacquire_after: int = Field(2, ge=1)
    max_speed: float = Field(1.0, gt=0)


class AnnotatedConfig(Section):
    """The downscaled annotated image for the monitor."""

    rate_hz: float = Field(2.0, ge=0)
    width: int = Field(320, ge=16)
    jpeg_quality: int = Field(70, ge=1, le=100)


class CalibrationConfig(Section):
    """The ChArUco board carried by the hand for extrinsics calibration."""

    dictionary: str = "DICT_4X4_50"
    squares_x: int = Field(5, ge=3)
    squares_y: int = Field(5, ge=3)
    square_length: float = 0.03
    marker_length: float = Field(0.022, gt=0)
    min_corners: int = Field(6, ge=4)

    @model_validator(mode="after")
    def _marker_inside_square(self) -> CalibrationConfig:
        if not self.marker_length < self.square_length:
            raise ValueError("need 0 < marker_length < square_length")
        return self


class VisionConfig(Section):
    """The whole ``vision:`` section."""

    camera: Literal["sim", "frames", "realsense"] = "sim"
    rate_hz: float = Field(15.0, gt=0, le=240)  # the sim camera's frame rate
    intrinsics: Intrinsics = Intrinsics()
    extrinsics: Pose = Pose()
    sim: SimCameraConfig = SimCameraConfig()
    realsense: RealSenseConfig = RealSenseConfig()
    detection: DetectionConfig = DetectionConfig()
    tracking: TrackingConfig = TrackingConfig()
    annotated: AnnotatedConfig = AnnotatedConfig()
    calibration: CalibrationConfig = CalibrationConfig()

    def sim_pose(self) -> Pose:
        """Where the simulated camera really is (ground truth for rendering)."""
        return self.sim.pose if self.sim.pose is not None else self.extrinsics
