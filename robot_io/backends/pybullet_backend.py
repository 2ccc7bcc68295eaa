"""The mock arm: sim's PyBullet scene with robot_io's arm model, stepped by the backend at the control rate.

The one robot_io module that uses ``sim``: the simulation backend (DESIGN section 1).
"""

from __future__ import annotations

import numpy as np

from robot_io.backends.protocol import Fault, JointState
from robot_io.config import RobotConfig
from robot_io.description import robot_model
from sim.panda_scene import PandaScene


class PyBulletBackend:
    name = "pybullet"

    def __init__(self, config: RobotConfig, scene: PandaScene | None = None) -> None:
        self.config = config
        self.scene = scene or PandaScene(
            motion=config.target_motion,
            seed=config.seed,
            time_step=config.period / config.physics_substeps,
            robot=robot_model(config.model),  # the config allows the Panda only here
        )
        self.substeps = config.physics_substeps
        self.scene.reset_robot(config.home_q)

    def read_state(self) -> JointState:
        q, dq = self.scene.joint_state()
        return JointState(q, dq, self.scene.time)

    def send_joint_command(self, q: np.ndarray) -> None:
        """Servo to ``q`` at the constant speed that gets there in one control period (smooth, like an
        interpolating joint controller), rather than snapping there and waiting."""
        q = np.asarray(q, float)
        q_now, _ = self.scene.joint_state()
        speed = np.maximum(np.abs(q - q_now) / self.config.period, 1e-3)
        self.scene.command_positions(q, max_velocity=speed)

    def hold(self) -> None:
        self.scene.brake()

    def fault(self) -> Fault | None:
        return None  # the mock has no driver that could stop it

    def recover(self) -> bool:
        return True  # the mock has no driver errors to clear

    def reset(self, q_home: np.ndarray, seed: int | None) -> None:
        self.scene.reset_robot(q_home)
        if seed is not None:  # a new target motion; without a seed the target keeps wandering
            self.scene.reset_target(seed)

    def step(self) -> None:
        self.scene.step(self.substeps)

    def close(self) -> None:
        self.scene.close()
