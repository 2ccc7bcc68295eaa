"""Configuration of the simulated camera (``vision.sim``), beside its backend (``vision/cameras/sim.py``)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from common.config import Section
from vision.camera_model import Pose


class DepthNoise(Section):
    """Sim depth noise: sigma = base + per_m2 * z^2 (stereo error grows with distance squared)."""

    base_sigma: float = Field(
        0.0005, ge=0, description="depth noise standard deviation at zero distance (metres)"
    )
    sigma_per_m2: float = Field(
        0.0015,
        ge=0,
        description="depth noise standard deviation added per squared metre of depth (metres per m²)",
    )
    dropout: float = Field(0.01, ge=0, lt=1)  # fraction of pixels with no depth (reported as 0)
    enabled: bool = Field(True, description="add the noise and dropout at all (false: exact depth)")


class SimCameraConfig(Section):
    """The simulated camera: where it physically is (``pose``, camera-to-base) and its depth range.

    ``pose`` is the ground truth used for rendering; the pipeline uses ``VisionConfig.extrinsics``
    (the calibrated estimate), so calibration can be exercised in simulation.
    """

    pose: Pose | None = None  # None: the same as the calibrated extrinsics
    # mujoco: MuJoCo's OpenGL renderer (MUJOCO_GL egl or osmesa); tiny: PyBullet's TinyRenderer, several
    # times slower, and what the camera falls back to, with a warning, when no OpenGL context opens.
    renderer: Literal["mujoco", "tiny"] = "mujoco"
    near: float = Field(
        0.05, gt=0, description="the renderer's near clipping distance (metres): nothing nearer is seen"
    )
    far: float = Field(4.0, description="the renderer's far clipping distance (metres); above near")
    noise: DepthNoise = Field(DepthNoise(), description="the simulated depth noise")
    seed: int | None = Field(0, description="seeds the depth noise (null: a different noise each run)")

    @model_validator(mode="after")
    def _near_below_far(self) -> SimCameraConfig:
        if not self.near < self.far:
            raise ValueError(f"need 0 < near < far, got near={self.near}, far={self.far}")
        return self
