"""Configuration of the PyBullet mock arm (``robot.mock``), beside its backend
(``robot_io/backends/pybullet_backend.py``)."""

from __future__ import annotations

from pydantic import Field

from common.config import Section


class MockArmConfig(Section):
    """The PyBullet mock arm's own dynamics, for the reality-gap overlays (configs/gaps/): a real arm
    tracks with its own gains and its commands take effect later than the mock's."""

    position_gain: float = Field(0.3, gt=0, le=1)  # PyBullet's servo gain: lower tracks slower
    actuation_delay_ms: float = Field(0.0, ge=0, le=500)  # each joint command takes effect this late
