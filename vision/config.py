"""Validated configuration of the vision module (the ``vision:`` section of a stack config).

Every dataclass checks itself in ``__post_init__`` so a bad YAML value fails at start-up with a message
naming the key, not mid-run. Lists from YAML are accepted and normalised to tuples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

CAMERAS = ("sim", "frames", "realsense")
TARGET_SHAPES = ("box", "sphere", "point")


def _floats(value: object, n: int, name: str) -> tuple[float, ...]:
    try:
        out = tuple(float(x) for x in value)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected {n} numbers, got {value!r}") from None
    if len(out) != n or not all(math.isfinite(x) for x in out):
        raise ValueError(f"{name}: expected {n} finite numbers, got {value!r}")
    return out


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole model in OpenCV convention: pixel (u, v) centre at integer coordinates, v down."""

    width: int = 640
    height: int = 480
    fx: float = 615.0
    fy: float = 615.0
    cx: float = 319.5
    cy: float = 239.5

    def __post_init__(self) -> None:
        if int(self.width) != self.width or int(self.height) != self.height:
            raise ValueError(f"intrinsics width/height must be integers, got {self.width}x{self.height}")
        if not (8 <= self.width <= 8192 and 8 <= self.height <= 8192):
            raise ValueError(f"intrinsics size {self.width}x{self.height} out of range [8, 8192]")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"intrinsics fx, fy must be > 0, got {self.fx}, {self.fy}")
        if not (0 <= self.cx < self.width and 0 <= self.cy < self.height):
            raise ValueError(
                f"principal point ({self.cx}, {self.cy}) outside the {self.width}x{self.height} image"
            )
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, float(getattr(self, name)))

    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same lens at another resolution (pixel centres kept consistent)."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            width, height, self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5
        )


@dataclass(frozen=True)
class Pose:
    """A rigid transform as position (m) and unit quaternion (x, y, z, w).

    For extrinsics it is camera-to-base: it maps points in the camera frame (OpenCV: x right,
    y down, z along the optical axis) to the robot base frame.
    """

    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quaternion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", _floats(self.position, 3, "position"))
        q = np.array(_floats(self.quaternion, 4, "quaternion (x, y, z, w)"))
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > 1e-3:
            raise ValueError(f"quaternion must have unit norm, got norm {norm:.6f}")
        object.__setattr__(self, "quaternion", tuple(float(x) for x in q / norm))


@dataclass(frozen=True)
class DepthNoise:
    """Sim depth noise: sigma = base + per_m2 * z^2 (stereo error grows with distance squared)."""

    base_sigma: float = 0.0005
    sigma_per_m2: float = 0.0015
    dropout: float = 0.01  # fraction of pixels with no depth (reported as 0)
    enabled: bool = True

    def __post_init__(self) -> None:
        if self.base_sigma < 0 or self.sigma_per_m2 < 0:
            raise ValueError("depth noise sigmas must be >= 0")
        if not 0 <= self.dropout < 1:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")


@dataclass(frozen=True)
class SimCameraConfig:
    """The simulated camera: where it physically is (``pose``, camera-to-base) and its depth range.

    ``pose`` is the ground truth used for rendering; the pipeline uses ``VisionConfig.extrinsics``
    (the calibrated estimate), so calibration can be exercised in simulation.
    """

    pose: Pose | None = None  # None: the same as the calibrated extrinsics
    near: float = 0.05
    far: float = 4.0
    noise: DepthNoise = field(default_factory=DepthNoise)
    seed: int | None = 0

    def __post_init__(self) -> None:
        if isinstance(self.pose, dict):
            object.__setattr__(self, "pose", Pose(**self.pose))
        if isinstance(self.noise, dict):
            object.__setattr__(self, "noise", DepthNoise(**self.noise))
        if not 0 < self.near < self.far:
            raise ValueError(f"need 0 < near < far, got near={self.near}, far={self.far}")


@dataclass(frozen=True)
class RealSenseConfig:
    """A RealSense device: colour and depth streams at one size, depth aligned to colour."""

    serial: str = ""  # empty: the first device found
    width: int = 640
    height: int = 480
    fps: int = 30
    timeout_ms: int = 1000
    max_timeouts: int = 3  # consecutive frame timeouts before a reconnect (hardware reset)
    reconnect_wait_s: float = 3.0

    def __post_init__(self) -> None:
        if self.fps not in (6, 15, 30, 60, 90):
            raise ValueError(f"realsense fps must be one of 6, 15, 30, 60, 90, got {self.fps}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"realsense size must be positive, got {self.width}x{self.height}")
        if self.timeout_ms <= 0 or self.max_timeouts < 1 or self.reconnect_wait_s < 0:
            raise ValueError("realsense timeout_ms > 0, max_timeouts >= 1, reconnect_wait_s >= 0 required")


@dataclass(frozen=True)
class DetectionConfig:
    """Colour segmentation of the target and how its depth is taken.

    ``hsv_ranges``: OpenCV HSV (H in 0..180) lower/upper bounds, several ranges OR-ed (red wraps).
    Depth is the median of valid depth in a ``depth_patch`` square around the blob's centroid, i.e.
    where the ray through the target's centre enters its surface. ``target_shape``/``target_size``
    turn that surface point into the centre: a sphere of radius ``size`` is ``size`` deeper along the
    ray; a box of half-extent ``size`` with faces aligned to the base axes (the sim target) is
    ``size / max|ray_i|`` deeper; ``point`` adds nothing.
    """

    hsv_ranges: tuple[tuple[int, int, int, int, int, int], ...] = (
        (0, 120, 60, 8, 255, 255),
        (172, 120, 60, 180, 255, 255),
    )
    min_area_px: int = 12
    morph_kernel: int = 3
    depth_patch: int = 9
    min_depth: float = 0.1
    max_depth: float = 4.0
    min_valid_fraction: float = 0.2  # of the patch's mask pixels that must have depth
    target_shape: str = "box"
    target_size: float = 0.025

    def __post_init__(self) -> None:
        ranges = []
        for i, r in enumerate(self.hsv_ranges):
            lo_hi = _floats(r, 6, f"hsv_ranges[{i}] (hmin, smin, vmin, hmax, smax, vmax)")
            if not all(0 <= x <= 255 for x in lo_hi) or lo_hi[0] > 180 or lo_hi[3] > 180:
                raise ValueError(f"hsv_ranges[{i}]: H in 0..180, S and V in 0..255, got {r}")
            if any(lo_hi[k] > lo_hi[k + 3] for k in range(3)):
                raise ValueError(f"hsv_ranges[{i}]: lower bound above upper bound in {r}")
            ranges.append(tuple(int(x) for x in lo_hi))
        if not ranges:
            raise ValueError("hsv_ranges: need at least one range")
        object.__setattr__(self, "hsv_ranges", tuple(ranges))
        if self.min_area_px < 1 or self.morph_kernel < 0 or self.depth_patch < 1:
            raise ValueError("min_area_px >= 1, morph_kernel >= 0 and depth_patch >= 1 required")
        if not 0 < self.min_depth < self.max_depth:
            raise ValueError(f"need 0 < min_depth < max_depth, got {self.min_depth}, {self.max_depth}")
        if not 0 < self.min_valid_fraction <= 1:
            raise ValueError(f"min_valid_fraction must be in (0, 1], got {self.min_valid_fraction}")
        if self.target_shape not in TARGET_SHAPES:
            raise ValueError(f"target_shape must be one of {TARGET_SHAPES}, got {self.target_shape!r}")
        if self.target_size < 0:
            raise ValueError(f"target_size must be >= 0, got {self.target_size}")


@dataclass(frozen=True)
class TrackingConfig:
    """Constant-velocity Kalman filter on the base-frame position.

    ``accel_sigma``: white-acceleration noise (m/s^2) — how fast the target may change velocity.
    ``lost_after_s``: time without an accepted detection after which the target is reported lost.
    ``gate_sigma``: Mahalanobis gate rejecting measurements that jump implausibly far.
    ``reacquire_after``: this many consecutive gated-out detections that agree with each other (moving
    at most ``max_speed`` m/s between them) mean the target really moved (picked up and put down, a
    sim reset): the track restarts there instead of coasting on the old one until it is lost.
    """

    accel_sigma: float = 0.4
    measurement_sigma: float = 0.004
    lost_after_s: float = 0.3
    gate_sigma: float = 6.0
    max_dt: float = 0.5
    reacquire_after: int = 2
    max_speed: float = 1.0

    def __post_init__(self) -> None:
        if self.accel_sigma <= 0 or self.measurement_sigma <= 0:
            raise ValueError("accel_sigma and measurement_sigma must be > 0")
        if self.lost_after_s <= 0:
            raise ValueError(f"lost_after_s must be > 0, got {self.lost_after_s}")
        if self.gate_sigma <= 0 or self.max_dt <= 0:
            raise ValueError("gate_sigma and max_dt must be > 0")
        if self.reacquire_after < 1:
            raise ValueError(f"reacquire_after must be >= 1, got {self.reacquire_after}")
        if self.max_speed <= 0:
            raise ValueError(f"max_speed must be > 0, got {self.max_speed}")


@dataclass(frozen=True)
class AnnotatedConfig:
    """The downscaled annotated image for the monitor."""

    rate_hz: float = 2.0
    width: int = 320
    jpeg_quality: int = 70

    def __post_init__(self) -> None:
        if self.rate_hz < 0 or self.width < 16 or not 1 <= self.jpeg_quality <= 100:
            raise ValueError("annotated: rate_hz >= 0, width >= 16, jpeg_quality in 1..100 required")


@dataclass(frozen=True)
class CalibrationConfig:
    """The ChArUco board carried by the hand for extrinsics calibration."""

    dictionary: str = "DICT_4X4_50"
    squares_x: int = 5
    squares_y: int = 5
    square_length: float = 0.03
    marker_length: float = 0.022
    min_corners: int = 6

    def __post_init__(self) -> None:
        if self.squares_x < 3 or self.squares_y < 3:
            raise ValueError("calibration board needs at least 3x3 squares")
        if not 0 < self.marker_length < self.square_length:
            raise ValueError("need 0 < marker_length < square_length")
        if self.min_corners < 4:
            raise ValueError("min_corners must be >= 4")


@dataclass(frozen=True)
class VisionConfig:
    """The whole ``vision:`` section."""

    camera: str = "sim"
    rate_hz: float = 15.0  # the sim camera's frame rate
    intrinsics: Intrinsics = field(default_factory=Intrinsics)
    extrinsics: Pose = field(default_factory=Pose)
    sim: SimCameraConfig = field(default_factory=SimCameraConfig)
    realsense: RealSenseConfig = field(default_factory=RealSenseConfig)
    detection: DetectionConfig = field(default_factory=DetectionConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    annotated: AnnotatedConfig = field(default_factory=AnnotatedConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)

    def __post_init__(self) -> None:
        if self.camera not in CAMERAS:
            raise ValueError(f"camera must be one of {CAMERAS}, got {self.camera!r}")
        if not 0 < self.rate_hz <= 240:
            raise ValueError(f"rate_hz must be in (0, 240], got {self.rate_hz}")

    def sim_pose(self) -> Pose:
        """Where the simulated camera really is (ground truth for rendering)."""
        return self.sim.pose if self.sim.pose is not None else self.extrinsics
