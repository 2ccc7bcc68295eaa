"""The backend protocol: what the controller needs from an arm, simulated or real."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class JointState:
    q: np.ndarray  # 7 joint positions (rad)
    dq: np.ndarray  # 7 joint velocities (rad/s)
    stamp: float  # backend time (s): simulation time for pybullet, monotonic for franka


class RobotBackend(Protocol):
    name: str

    def read_state(self) -> JointState:
        """The latest measured joint state."""

    def send_joint_command(self, q: np.ndarray) -> None:
        """Servo to ``q``; already checked against limits by the caller."""

    def hold(self) -> None:
        """Stop now and keep the current position."""

    def fault(self) -> str | None:
        """A driver error that stopped the arm, or None."""

    def recover(self) -> bool:
        """Clear a driver error (reflex, collision); True when the arm accepts commands again."""

    def reset(self, q_home: np.ndarray, seed: int | None) -> None:
        """Go to ``q_home``; in simulation a ``seed`` also starts a new target motion."""

    def step(self) -> None:
        """Let one control period pass: the simulation advances; a real arm moves on its own."""

    def close(self) -> None: ...
