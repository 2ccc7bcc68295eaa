"""Forward kinematics, Jacobians and command checks with Pinocchio (independent of the IK's MuJoCo model)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from robot_io.description import RobotDescription


@dataclass(frozen=True)
class CommandCheck:
    """Why a joint command is refused; ``ok`` when it is not."""

    ok: bool
    kind: str = ""  # not_finite | joint_limit | velocity_limit | workspace
    detail: str = ""


class Kinematics:
    """Tool-centre-point kinematics of the Panda arm (7 joints).

    Placements are remembered for the last few configurations, so one control tick computes each
    configuration's forward kinematics once whoever asks (the state, the action's anchor, the command
    check: the anchor's configurations are the previous tick's state and command).
    """

    REMEMBERED = 4

    def __init__(self, description: RobotDescription | None = None) -> None:
        self.description = description or RobotDescription()
        self.model = self.description.pinocchio_model()
        self.data = self.model.createData()
        self.ee_id = self.model.getFrameId(self.description.ee_frame)
        limits = self.description.limits
        self.lower, self.upper, self.velocity = limits.lower, limits.upper, limits.velocity
        self._placements: dict[bytes, pin.SE3] = {}

    def fk(self, q: np.ndarray) -> pin.SE3:
        q = np.asarray(q, float)
        key = q.tobytes()
        placement = self._placements.get(key)
        if placement is None:
            pin.framesForwardKinematics(self.model, self.data, q)
            placement = self._remember(key, self.data.oMf[self.ee_id].copy())
        return placement

    def _remember(self, key: bytes, placement: pin.SE3) -> pin.SE3:
        if len(self._placements) >= self.REMEMBERED:
            del self._placements[next(iter(self._placements))]  # the oldest
        self._placements[key] = placement
        return placement

    def ee_position(self, q: np.ndarray) -> np.ndarray:
        return self.fk(q).translation.copy()

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """6x7 Jacobian of the tool centre point, world-aligned (linear rows first)."""
        q = np.asarray(q, float)
        J = pin.computeFrameJacobian(self.model, self.data, q, self.ee_id, pin.LOCAL_WORLD_ALIGNED)
        pin.updateFramePlacement(self.model, self.data, self.ee_id)  # the same pass gives the placement
        self._remember(q.tobytes(), self.data.oMf[self.ee_id].copy())
        return J

    def ee_position_velocity(self, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The tool centre point's position and linear velocity from one kinematics pass."""
        J = self.jacobian(q)
        return self.ee_position(q), J[:3] @ np.asarray(dq, float)

    def ee_velocity(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        return self.jacobian(q)[:3] @ np.asarray(dq, float)

    def check(
        self,
        q_cmd: np.ndarray,
        q_now: np.ndarray,
        dt: float,
        margin: float,
        velocity_scale: float,
        box: tuple[np.ndarray, np.ndarray],
    ) -> CommandCheck:
        """Check a command before it is sent: joint limits, joint velocity, end effector in the box.

        A joint or the end effector already outside its bounds (a start there, a hand-guided arm) may
        hold or come back, never go further out: refusing every command would hold it there for good."""
        q_cmd, q_now = np.asarray(q_cmd, float), np.asarray(q_now, float)
        if not (np.all(np.isfinite(q_cmd)) and np.all(np.isfinite(q_now))):
            return CommandCheck(False, "not_finite", f"joint command {q_cmd.tolist()} from {q_now.tolist()}")
        low = np.minimum(self.lower + margin, q_now)
        high = np.maximum(self.upper - margin, q_now)
        bad = np.flatnonzero((q_cmd < low - 1e-9) | (q_cmd > high + 1e-9))
        if bad.size:
            j = int(bad[0])
            return CommandCheck(
                False, "joint_limit", f"joint {j + 1} = {q_cmd[j]:.4f} outside [{low[j]:.4f}, {high[j]:.4f}]"
            )
        speed = np.abs(q_cmd - q_now) / dt
        vmax = self.velocity * velocity_scale
        bad = np.flatnonzero(speed > vmax * 1.05 + 1e-9)
        if bad.size:
            j = int(bad[0])
            return CommandCheck(
                False, "velocity_limit", f"joint {j + 1} at {speed[j]:.3f} rad/s > {vmax[j]:.3f}"
            )
        p, p_now = self.ee_position(q_cmd), self.ee_position(q_now)
        lo, hi = np.minimum(box[0], p_now), np.maximum(box[1], p_now)
        if np.any(p < lo - 1e-6) or np.any(p > hi + 1e-6):
            return CommandCheck(False, "workspace", f"end effector {np.round(p, 4).tolist()} outside the box")
        return CommandCheck(True)
