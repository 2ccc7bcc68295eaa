"""Robot backends behind one protocol; ``make_backend`` picks one from the config."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from robot_io.backends.protocol import Fault, JointState, RobotBackend

if TYPE_CHECKING:
    from robot_io.config import RobotConfig


def make_backend(config: RobotConfig, world: Any = None) -> RobotBackend:
    """The configured backend; ``world`` is the simulation it runs in or beside, built above robot_io
    (``tasks.sim_world.robot_world``): the mock's PyBullet scene, franky-sim's scripted target, or None."""
    if config.backend == "pybullet":
        from robot_io.backends.pybullet_backend import PyBulletBackend

        return PyBulletBackend(config, world)
    from robot_io.backends.franky_backend import FrankyBackend

    return FrankyBackend(config, target=world)


__all__ = ["Fault", "JointState", "RobotBackend", "make_backend"]
