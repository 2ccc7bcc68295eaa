"""NS Reach: reach a target that wanders with bounded, varying speed, with the Panda in PyBullet.

Action: end-effector displacement (m, each axis in [-0.05, 0.05], norm capped at 5 cm per step).
Observation (15 values, base frame): end-effector position and velocity, target position and velocity,
and the target relative to the end effector. The relative part is a function of the rest, but it is
the relation the task turns on: with it a kernel policy and critic can be wide in the absolute
coordinates and narrow in the relative ones (measured: AdaptiveH goes from 0 to 90-100 % success in
4k steps with it, and learns nothing in 20k without it). Every method gets the same observation.
Reward: minus the distance to the target after the step; ``info["success"]`` when it is under 5 cm.
The target keeps moving across episodes (its clock is global, like the other NS environments); the
step clock is in ``info["global_step"]``, the target's current speed in ``info["target_speed"]``.

The arm is robot_io's controller (same scene, same mink IK, same safety) so the in-process env and the
Zenoh deployment behave alike. That is the one place ``sim`` reaches up to ``robot_io``; the import is
deferred to construction so importing ``sim`` stays light and acyclic.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

SUCCESS_M = 0.05
MAX_STEP_M = 0.05
RELATIVE_RANGE_M = 0.6  # typical |target - ee| per axis, for normalisation (not a hard bound)


def reach_observation(
    ee_pos: np.ndarray, ee_vel: np.ndarray, target_pos: np.ndarray, target_vel: np.ndarray
) -> np.ndarray:
    """The NS Reach observation; the Zenoh env builds it with this same function."""
    ee_pos, target_pos = np.asarray(ee_pos, float), np.asarray(target_pos, float)
    return np.concatenate([ee_pos, ee_vel, target_pos, target_vel, target_pos - ee_pos]).astype(np.float32)


def reach_observation_bounds(
    workspace_lo: np.ndarray,
    workspace_hi: np.ndarray,
    target_lo: np.ndarray,
    target_hi: np.ndarray,
    target_speed_max: float,
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """(space low, space high, normalisation bounds) of the observation."""
    ws_lo, ws_hi = np.asarray(workspace_lo, float), np.asarray(workspace_hi, float)
    t_lo, t_hi = np.asarray(target_lo, float), np.asarray(target_hi, float)
    v_ee, v_t = np.ones(3), np.full(3, target_speed_max * 1.25)
    span = np.maximum(ws_hi, t_hi) - np.minimum(ws_lo, t_lo)
    low = np.concatenate([ws_lo, -v_ee, t_lo, -v_t, -span])
    high = np.concatenate([ws_hi, v_ee, t_hi, v_t, span])
    rel = np.full(3, RELATIVE_RANGE_M)
    norm = (np.concatenate([ws_lo, -v_ee, t_lo, -v_t, -rel]), np.concatenate([ws_hi, v_ee, t_hi, v_t, rel]))
    return low.astype(np.float32), high.astype(np.float32), norm


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
        from robot_io.config import RobotConfig  # deferred: see the module docstring
        from robot_io.controller import RobotController

        if max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        self.config = RobotConfig(
            backend="pybullet", target_motion=motion, seed=seed, control_rate_hz=control_rate_hz
        )
        self.arm = RobotController(self.config)
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
        self.global_step = 0
        self._steps = 0

    def _observe(self) -> tuple[np.ndarray, float]:
        state = self.arm.state()
        target = self.scene.target.position
        obs = reach_observation(state.ee_pos, state.ee_vel, target, self.scene.target_velocity())
        return obs, float(np.linalg.norm(state.ee_pos - target))

    def _info(self, distance: float) -> dict[str, Any]:
        return {
            "distance": distance,
            "success": distance < SUCCESS_M,
            "global_step": self.global_step,
            "target_speed": float(np.linalg.norm(self.scene.target_velocity())),
            "target_motion": self.config.target_motion,
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Home pose; the target keeps moving unless ``seed`` asks for a new target motion."""
        super().reset(seed=seed)
        self.arm.reset()
        if seed is not None:
            self.scene.reset_target(seed)
        self._steps = 0
        obs, distance = self._observe()
        return obs, self._info(distance)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        action = np.clip(np.asarray(action, float).reshape(3), -MAX_STEP_M, MAX_STEP_M)
        self.arm.step_action(action)
        self._steps += 1
        self.global_step += 1
        obs, distance = self._observe()
        info = self._info(distance)
        terminated = bool(self.terminate_on_success and info["success"])
        truncated = self._steps >= self.max_episode_steps
        return obs, -distance, terminated, truncated, info

    def close(self) -> None:
        self.arm.close()
