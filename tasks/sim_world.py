"""The simulated world handed to robot_io's and vision's simulation backends, which never build it.

robot_io and vision import neither ``sim`` nor PyBullet (docs/departures.md, "Layering"): the layer above
both wires sim's PyBullet Panda scene (or franky-sim's scripted target) into them. ``sim`` is imported
only when a simulated world is built, so robot-io on a real arm never loads PyBullet (and vision's
replica scene does not load robot_io's kinematics).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from robot_io.config import RobotConfig

if TYPE_CHECKING:
    from robot_io.controller import RobotController
    from sim.panda_scene import PandaScene


def arm_scene(config: RobotConfig) -> PandaScene:
    """The mock arm's world: the Panda (robot_io's model) and the moving target, at the config's physics
    step."""
    from robot_io.description import robot_model
    from sim.panda_scene import PandaScene

    return PandaScene(
        motion=config.target_motion,
        seed=config.seed,
        time_step=config.period / config.physics_substeps,
        robot=robot_model(config.model),  # the config allows the Panda only here
        position_gain=config.mock.position_gain,
    )


class ScriptedTarget:
    """A scripted target for franky-sim, whose world no camera sees (``franka.simulated_target``).

    It has the fields robot-io's ground-truth publisher reads from the PyBullet scene (``target``,
    ``target_velocity``), and moves by the control period each ``step``, like the mock's target.
    """

    def __init__(self, config: RobotConfig) -> None:
        from sim.panda_scene import TargetMotion, TargetState

        self.motion = TargetMotion.preset(config.target_motion)
        self._start = TargetState.start
        self.target = self._start(self.motion, config.seed)

    def reset(self, seed: int | None) -> None:
        self.target = self._start(self.motion, seed)

    def advance(self, dt: float) -> None:
        self.target.advance(dt)

    def target_velocity(self) -> np.ndarray:
        return self.target.velocity.copy()


def robot_world(config: RobotConfig) -> PandaScene | ScriptedTarget | None:
    """What the configured backend runs in or beside: the mock's scene, franky-sim's scripted target, or
    nothing (a real arm)."""
    if not config.simulated:
        return None
    return arm_scene(config) if config.backend == "pybullet" else ScriptedTarget(config)


def robot_controller(config: RobotConfig) -> RobotController:
    """The controller with its simulated world, as robot-io runs it."""
    from robot_io.controller import RobotController

    return RobotController(config, world=robot_world(config))


def replica_scene(seed: int = 0) -> PandaScene:
    """A scene for vision's sim camera to pose and render (a replica of robot-io's world), or for a
    simulated calibration to pose the arm in."""
    from sim.panda_scene import PandaScene

    return PandaScene(motion="static", seed=seed)
