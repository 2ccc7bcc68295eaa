"""Robot backends behind one protocol; ``make_backend`` picks one from the config."""

from __future__ import annotations

from robot_io.backends.protocol import Fault, JointState, RobotBackend
from robot_io.config import RobotConfig


def make_backend(config: RobotConfig) -> RobotBackend:
    if config.backend == "pybullet":
        from robot_io.backends.pybullet_backend import PyBulletBackend

        return PyBulletBackend(config)
    from robot_io.backends.franky_backend import FrankyBackend

    return FrankyBackend(config)


__all__ = ["Fault", "JointState", "RobotBackend", "make_backend"]
