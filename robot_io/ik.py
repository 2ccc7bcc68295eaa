"""Differential IK with mink: a QP per step with configuration, velocity and workspace limits and a posture
task.

The end-effector task tracks a position with the tool kept pointing down (a softer orientation cost), and
a light posture task pulls towards home so the redundant joint does not drift. Because the QP respects the
limits, an unreachable target yields the closest reachable motion instead of an exception; ``IKResult``
says how far from the target the solution ended.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import mink
import numpy as np

from robot_io.config import IKConfig
from robot_io.description import RobotDescription
from robot_io.workspace_limit import WorkspaceLimit

log = logging.getLogger(__name__)

JOINT_INSET_RAD = 1e-3
"""The IK keeps each joint this much further inside than the command check's margin: at an active limit
the QP's answer, and an arm held there, stray some 1e-6 rad past it, and mink's limit then only ever
takes 95 % of the way back, so every later command would be refused (docs/robot_interface.md)."""

BOX_INSET_M = 5e-3
"""Likewise for the workspace box, and the most it asks back per period when outside it: one period's step
along a wall curves up to ~2 mm outwards of the linearised limit (docs/robot_interface.md)."""


@dataclass(frozen=True)
class IKResult:
    q: np.ndarray  # joint command (7)
    ee: np.ndarray  # end-effector position the command reaches (MuJoCo FK)
    error: float  # distance from that position to the requested target (m)
    solved: bool  # False when the QP failed and the command is the current configuration


class DifferentialIK:
    """One solver instance per arm; not thread-safe (it owns a MuJoCo data)."""

    def __init__(
        self,
        config: IKConfig,
        description: RobotDescription | None = None,
        velocity_scale: float = 0.5,
        joint_margin: float = 0.02,
        home_q: np.ndarray | None = None,
        box: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        self.config = config
        self.description = description or RobotDescription()
        self.model = self.description.mujoco_model()
        self.configuration = mink.Configuration(self.model)
        limits = self.description.limits
        self.ee_task = mink.FrameTask(
            frame_name=self.description.ee_frame,
            frame_type="body",
            position_cost=config.position_cost,
            orientation_cost=config.orientation_cost,
            lm_damping=config.lm_damping,
        )
        self.posture_task = mink.PostureTask(self.model, cost=config.posture_cost)
        self.limits: list[mink.Limit] = [
            mink.ConfigurationLimit(self.model, min_distance_from_limits=joint_margin + JOINT_INSET_RAD),
            mink.VelocityLimit(
                self.model,
                {
                    name: v * velocity_scale
                    for name, v in zip(self.description.arm_joints, limits.velocity, strict=True)
                },
            ),
        ]
        if box is not None:
            lo, hi = np.asarray(box[0], float) + BOX_INSET_M, np.asarray(box[1], float) - BOX_INSET_M
            self.limits.append(WorkspaceLimit(self.model, self.description.ee_frame, lo, hi, BOX_INSET_M))
        home = np.asarray(home_q if home_q is not None else np.zeros(7), float)
        self.configuration.update(home)
        self.posture_task.set_target(home)
        # Keep the tool orientation it has at home (pointing down at the table).
        self.rotation = self.configuration.get_transform_frame_to_world(
            self.description.ee_frame, "body"
        ).rotation()

    def solve(self, q: np.ndarray, target: np.ndarray, dt: float) -> IKResult:
        """Joint positions after ``dt`` seconds of limit-respecting motion towards ``target``."""
        target = np.asarray(target, float)
        self.configuration.update(np.asarray(q, float))
        self.ee_task.set_target(mink.SE3.from_rotation_and_translation(self.rotation, target))
        tasks = [self.ee_task, self.posture_task]
        h = dt / self.config.iterations
        solved = True
        for _ in range(self.config.iterations):
            try:
                velocity = mink.solve_ik(
                    self.configuration,
                    tasks,
                    h,
                    self.config.solver,
                    damping=self.config.damping,
                    limits=self.limits,
                )
            except mink.NoSolutionFound:
                log.warning("IK: %s found no solution; holding the current configuration", self.config.solver)
                self.configuration.update(np.asarray(q, float))
                solved = False
                break
            self.configuration.integrate_inplace(velocity, h)
        ee = self.configuration.get_transform_frame_to_world(self.description.ee_frame, "body").translation()
        return IKResult(self.configuration.q.copy(), ee.copy(), float(np.linalg.norm(ee - target)), solved)
