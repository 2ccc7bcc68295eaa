"""The backend protocol: what the controller needs from an arm, simulated or real."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class JointState:
    q: np.ndarray  # 7 joint positions (rad)
    dq: np.ndarray  # 7 joint velocities (rad/s)
    stamp: float  # backend time (s): simulation time for pybullet, monotonic for franka
    # Where the arm is being commanded to be (franka: the last streamed target while streaming), or None
    # when that is the measured q. A position-controlled arm lags its command while moving; the IK
    # continues the commanded trajectory instead of restarting from the lagging measurement each period.
    q_cmd: np.ndarray | None = None


@dataclass(frozen=True)
class Fault:
    """What stopped the arm: the driver's error names (libfranka's reflex flags such as
    ``joint_velocity_violation``, or ``connection_lost``), which automatic recovery matches against
    ``robot.franka.auto_recover``, and the driver's own words for the operator."""

    kinds: tuple[str, ...]
    detail: str

    def __str__(self) -> str:
        return f"{', '.join(self.kinds)}: {self.detail}"


class RobotBackend(Protocol):
    name: str

    def read_state(self) -> JointState:
        """The latest measured joint state."""

    def send_joint_command(self, q: np.ndarray) -> None:
        """Servo to ``q``; already checked against limits by the caller."""

    def hold(self) -> None:
        """Stop now and keep the current position."""

    def fault(self) -> Fault | None:
        """A driver error that stopped the arm (reported until ``recover`` clears it), or None."""

    def recover(self) -> bool:
        """Clear a driver error (reflex, lost connection); True when the arm accepts commands again."""

    def reset(
        self, q_home: np.ndarray, seed: int | None, while_moving: Callable[[], None] | None = None
    ) -> None:
        """Go to ``q_home``; in simulation a ``seed`` also starts a new target motion. A real arm's move
        home takes seconds: ``while_moving`` is called about once a control period meanwhile (robot-io
        keeps publishing the arm's state, so a camera replica and the operator see it move)."""

    def step(self) -> None:
        """Let one control period pass: the simulation advances; a real arm moves on its own."""

    def close(self) -> None: ...
