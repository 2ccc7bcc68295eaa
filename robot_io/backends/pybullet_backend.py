"""The mock arm: a simulated scene (sim's PyBullet Panda scene), stepped by the backend at the control rate.

The backend is handed its scene (``tasks.sim_world.robot_world`` builds it with robot_io's arm model):
robot_io imports neither ``sim`` nor PyBullet, so a real-arm config never loads them.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Protocol

import numpy as np

from common.config import ConfigError
from robot_io.backends.protocol import Fault, JointState
from robot_io.config import RobotConfig


class ArmScene(Protocol):
    """What the mock needs of a simulated world (``sim.panda_scene.PandaScene`` is one)."""

    time: float

    def reset_robot(self, q: np.ndarray | tuple[float, ...] | None = None) -> None: ...

    def reset_target(self, seed: int | None = None) -> None: ...

    def command_positions(self, q: np.ndarray, max_velocity: np.ndarray | None = None) -> None: ...

    def brake(self) -> None: ...

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]: ...

    def step(self, n: int = 1) -> None: ...

    def close(self) -> None: ...


class PyBulletBackend:
    name = "pybullet"

    def __init__(self, config: RobotConfig, scene: ArmScene | None) -> None:
        if scene is None:
            raise ConfigError(
                "robot.backend: pybullet needs a simulated scene; build the controller with "
                "tasks.sim_world.robot_world(config) as its world"
            )
        self.config = config
        self.scene = scene
        self.substeps = config.physics_substeps
        self.delay_s = config.mock.actuation_delay_ms / 1000.0
        self._pending: deque[tuple[float, np.ndarray, np.ndarray]] = deque()  # (due, q, speed)
        self._commanded: np.ndarray | None = None  # the newest delayed command (JointState.q_cmd)
        self.scene.reset_robot(config.home_q)

    def read_state(self) -> JointState:
        """Without a delay the servo reaches each command within its period: the command is the measured
        arm. With one, the arm lags its command as a real one does, and says where it is commanded."""
        q, dq = self.scene.joint_state()
        return JointState(q, dq, self.scene.time, None if self._commanded is None else self._commanded.copy())

    def send_joint_command(self, q: np.ndarray) -> None:
        """Servo to ``q`` at the constant speed that gets there in one control period (smooth, like an
        interpolating joint controller), rather than snapping there and waiting."""
        q = np.asarray(q, float)
        q_now, _ = self.scene.joint_state()
        speed = np.maximum(np.abs(q - q_now) / self.config.period, 1e-3)
        if self.delay_s > 0:  # a gap overlay: the command takes effect ``mock.actuation_delay_ms`` later
            self._pending.append((self.scene.time + self.delay_s, q, speed))
            self._commanded = q.copy()
            return
        self.scene.command_positions(q, max_velocity=speed)

    def hold(self) -> None:
        self._pending.clear()
        self._commanded = None
        self.scene.brake()

    def fault(self) -> Fault | None:
        return None  # the mock has no driver that could stop it

    def recover(self) -> bool:
        return True  # the mock has no driver errors to clear

    def reset(
        self, q_home: np.ndarray, seed: int | None, while_moving: Callable[[], None] | None = None
    ) -> None:
        """At once: the mock's arm is placed home, with nothing to wait for."""
        self._pending.clear()
        self._commanded = None
        self.scene.reset_robot(q_home)
        if seed is not None:  # a new target motion; without a seed the target keeps wandering
            self.scene.reset_target(seed)

    def step(self) -> None:
        if not self._pending:
            self.scene.step(self.substeps)
            return
        for _ in range(self.substeps):  # delayed commands take effect at the physics step they fall due
            while self._pending and self._pending[0][0] <= self.scene.time + 1e-9:
                _, q, speed = self._pending.popleft()
                self.scene.command_positions(q, max_velocity=speed)
            self.scene.step(1)

    def close(self) -> None:
        self.scene.close()
