"""NS Reach in-process: reach a target that wanders with bounded, varying speed, with the Panda in PyBullet.

The task (observation, reward, success, the 5 cm action bound) is ``tasks.reach``. The target keeps
moving across episodes (its clock is global, like the other NS environments); the step clock is in
``info["global_step"]``, the target's current speed in ``info["target_speed"]``.

The arm is robot_io's controller on its PyBullet backend (same scene, same mink IK, same safety) so
the in-process env and the Zenoh deployment behave alike.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from robot_io.config import RobotConfig
from robot_io.controller import ArmState, RobotController
from tasks.reach import (
    MAX_STEP_M,
    predict_reach,
    reach_distance,
    reach_observation,
    reach_observation_bounds,
    reach_reward,
    reach_success,
    reach_task_record,
)
from tasks.sim_world import arm_scene


class NSReachEnv(gym.Env):
    metadata = {"render_modes": []}

    def __init__(
        self,
        motion: str = "slow",
        max_episode_steps: int = 200,
        seed: int = 0,
        control_rate_hz: float = 20.0,
        terminate_on_success: bool = False,
    ) -> None:
        if max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        self.config = RobotConfig(
            backend="pybullet", target_motion=motion, seed=seed, control_rate_hz=control_rate_hz
        )
        self.arm = RobotController(self.config, world=arm_scene(self.config))
        self.scene = self.arm.backend.scene
        self.max_episode_steps = max_episode_steps
        self.terminate_on_success = terminate_on_success
        t_lo, t_hi = self.scene.motion.box
        low, high, self.obs_bounds = reach_observation_bounds(
            self.config.workspace.lo,
            self.config.workspace.hi,
            t_lo,
            t_hi,
            max(self.scene.motion.speed_max, 0.05),
        )
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        self.action_space = gym.spaces.Box(-MAX_STEP_M, MAX_STEP_M, shape=(3,), dtype=np.float32)
        ws = self.config.workspace
        self.workspace = (np.asarray(ws.lo, float), np.asarray(ws.hi, float))  # the controller's goal box
        self.global_step = 0
        self._steps = 0

    def _observe(self, state: ArmState) -> tuple[np.ndarray, float]:
        """Observation and distance of the arm's ``state`` (the one its last call returned: read once)."""
        target = self.scene.target.position
        obs = reach_observation(state.ee_pos, state.ee_vel, target, self.scene.target_velocity())
        return obs, reach_distance(state.ee_pos, target)

    def _info(self, distance: float) -> dict[str, Any]:
        return {
            "distance": distance,
            "success": reach_success(distance),
            "global_step": self.global_step,
            "target_speed": float(np.linalg.norm(self.scene.target_velocity())),
            "target_motion": self.config.target_motion,
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Home pose; the target keeps moving unless ``seed`` asks for a new target motion."""
        super().reset(seed=seed)
        state = self.arm.reset()
        if seed is not None:
            self.scene.reset_target(seed)  # the target only: the arm's state stands
        self._steps = 0
        obs, distance = self._observe(state)
        return obs, self._info(distance)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        action = np.clip(np.asarray(action, float).reshape(3), -MAX_STEP_M, MAX_STEP_M)
        tick = self.arm.step_action(action)
        self._steps += 1
        self.global_step += 1
        obs, distance = self._observe(tick.state)
        info = self._info(distance)
        terminated = bool(self.terminate_on_success and info["success"])
        truncated = self._steps >= self.max_episode_steps
        return obs, reach_reward(distance), terminated, truncated, info

    def task_record(self) -> tuple:
        """What a checkpoint of a policy learned here records (``learner.provenance``)."""
        return reach_task_record(self.config.model, "NSReach-v0 (in-process, PyBullet mock)")

    def predict_next(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        """The plan model (``tasks.reach.predict_reach``): what a plan made now assumes."""
        return predict_reach(obs, action, self.config.period, workspace=self.workspace)

    def close(self) -> None:
        self.arm.close()
