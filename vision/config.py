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
    min_area_px: int = Field(
        12,
        ge=1,
        description="the smallest blob (pixels of the mask) taken for the target; a smaller one is no"
        " detection",
    )
    morph_kernel: int = Field(
        3,
        ge=0,
        description="side (pixels) of the elliptic kernel that opens then closes the colour mask, removing"
        " specks and filling holes; 0 or 1: none",
    )
    depth_patch: int = Field(
        9,
        ge=1,
        description="the largest side (pixels) of the square around the blob's centroid whose median valid"
        " depth is the target's depth (smaller for a small blob)",
    )
    min_depth: float = Field(
        0.1, gt=0, description="depth readings nearer than this (metres) are taken as invalid"
    )
    max_depth: float = Field(
        4.0, description="depth readings farther than this (metres) are taken as invalid; above min_depth"
    )
    min_valid_fraction: float = Field(0.2, gt=0, le=1)  # of the patch's mask pixels that must have depth
    target_shape: Literal["box", "sphere", "point"] = Field(
        "box",
        description="the target's shape, to go from the surface the camera sees to its centre: box (faces"
        " aligned to the base axes), sphere, or point",
    )
    target_size: float = Field(
        0.025,
        ge=0,
        description="the box's half-extent or the sphere's radius (metres): how far the centre lies behind"
        " the seen surface",
    )

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
    measurement_sigma: float = Field(
        0.004,
        gt=0,
        description="standard deviation of one detection's 3D position (metres): the filter's measurement"
        " noise",
    )
    lost_after_s: float = Field(0.3, gt=0)
    gate_sigma: float = Field(6.0, gt=0)
    max_dt: float = Field(
        0.5,
        gt=0,
        description="the longest time (seconds) the filter predicts over in one step; a longer gap is"
        " predicted as this long",
    )
    reacquire_after: int = Field(2, ge=1)
    max_speed: float = Field(
        1.0,
        gt=0,
        description="the fastest the target may move (m/s) between the agreeing detections that restart a"
        " track (reacquire_after)",
    )


class AnnotatedConfig(Section):
    """The downscaled annotated image for the monitor."""

    rate_hz: float = Field(
        2.0, ge=0, description="annotated images per second sent to the monitor (camera/annotated); 0: none"
    )
    width: int = Field(
        320,
        ge=16,
        description="the annotated image's width in pixels (its height keeps the camera's aspect ratio)",
    )
    jpeg_quality: int = Field(
        70, ge=1, le=100, description="JPEG quality of the annotated image, 1 (smallest) to 100 (best)"
    )


class CalibrationConfig(Section):
    """The ChArUco board carried by the hand for extrinsics calibration."""

    dictionary: str = Field(
        "DICT_4X4_50", description="the board's ArUco dictionary, by OpenCV's name (cv2.aruco.DICT_...)"
    )
    squares_x: int = Field(5, ge=3, description="the board's number of chessboard squares along x")
    squares_y: int = Field(5, ge=3, description="the board's number of chessboard squares along y")
    square_length: float = Field(
        0.03, description="side of one chessboard square as printed (metres); measure the printed board"
    )
    marker_length: float = Field(
        0.022, gt=0, description="side of one ArUco marker as printed (metres); below square_length"
    )
    min_corners: int = Field(
        6, ge=4, description="ChArUco corners an image needs to count as a view of the board"
    )

    @model_validator(mode="after")
    def _marker_inside_square(self) -> CalibrationConfig:
        if not self.marker_length < self.square_length:
            raise ValueError("need 0 < marker_length < square_length")
        return self


class VisionConfig(Section):
    """The whole ``vision:`` section."""

    camera: Literal["sim", "frames", "realsense"] = Field(
        "sim",
        description="where frames come from: sim (renders a replica of the simulated world), realsense (an"
        " Intel RealSense device), frames (the camera/frame topic, published by another"
        " process)",
    )
    rate_hz: float = Field(15.0, gt=0, le=240)  # the sim camera's frame rate (Hz)
    intrinsics: Intrinsics = Field(
        Intrinsics(), description="the simulated camera's lens (a RealSense reports its own)"
    )
    extrinsics: Pose = Field(
        Pose(),
        description="where the camera is: the calibrated camera-to-base pose (``adaptiveh calibrate``"
        " writes it) that maps detections into the robot base frame",
    )
    sim: SimCameraConfig = Field(SimCameraConfig(), description="the simulated camera (camera sim)")
    realsense: RealSenseConfig = Field(
        RealSenseConfig(), description="the RealSense device (camera realsense)"
    )
    detection: DetectionConfig = Field(
        DetectionConfig(), description="how the target is found in a frame: colour segmentation and depth"
    )
    tracking: TrackingConfig = Field(
        TrackingConfig(),
        description="the Kalman filter that smooths the target's position and estimates its velocity",
    )
    annotated: AnnotatedConfig = Field(
        AnnotatedConfig(), description="the downscaled, annotated image the monitor shows"
    )
    calibration: CalibrationConfig = Field(
        CalibrationConfig(), description="the ChArUco board used by ``adaptiveh calibrate``"
    )

    def sim_pose(self) -> Pose:
        """Where the simulated camera really is (ground truth for rendering)."""
        return self.sim.pose if self.sim.pose is not None else self.extrinsics
