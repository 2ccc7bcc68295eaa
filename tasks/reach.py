"""The reach task: observation, reward and success, one definition for every env that plays it.

The in-process ``NSReach-v0`` (``tasks.reach_env``) and the deployed Zenoh env (``deploy.zenoh_env``)
both build their observation, reward and success here, so a policy learned in one reads the other's
states the same way.

Action: end-effector displacement (m, each axis in [-0.05, 0.05], norm capped at 5 cm per step).
Observation (15 values, base frame): end-effector position and velocity, target position and velocity,
and the target relative to the end effector. The relative part is a function of the rest, but it is
the relation the task turns on: with it a kernel policy and critic can be wide in the absolute
coordinates and narrow in the relative ones (measured: AdaptiveH goes from 0 to 90-100 % success in
4k steps with it, and learns nothing in 20k without it). Every method gets the same observation.
Reward: minus the distance to the target after the step; success when it is under 5 cm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from learner.provenance import ArmRecord
from robot_io.description import robot_model
from robot_io.step_cap import cap_step_length

SUCCESS_M = 0.05
MAX_STEP_M = 0.05
RELATIVE_RANGE_M = 0.6  # typical |target - ee| per axis, for normalisation (not a hard bound)


def reach_observation(
    ee_pos: np.ndarray, ee_vel: np.ndarray, target_pos: np.ndarray, target_vel: np.ndarray
) -> np.ndarray:
    """The 15-value observation of the module docstring."""
    ee_pos, target_pos = np.asarray(ee_pos, float), np.asarray(target_pos, float)
    return np.concatenate([ee_pos, ee_vel, target_pos, target_vel, target_pos - ee_pos]).astype(np.float32)


OBSERVATION_NAMES = tuple(
    f"{part}_{axis}" for part in ("ee", "ee_vel", "target", "target_vel", "target_rel") for axis in "xyz"
)
TASK = "reach"


def reach_task_record(model: str, source: str) -> tuple[str, tuple[str, ...], ArmRecord, str]:
    """(task, observation names, the arm, how it is run): what a reach policy's checkpoint records
    (``learner.provenance``) for the arm ``model``."""
    arm = robot_model(model)
    return TASK, OBSERVATION_NAMES, ArmRecord(arm.name, arm.family, arm.tcp_offset_m), source


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


def reach_distance(ee_pos: np.ndarray, target_pos: np.ndarray) -> float:
    """Euclidean distance (m) from the end effector to the target."""
    return float(np.linalg.norm(np.asarray(ee_pos, float) - np.asarray(target_pos, float)))


def reach_reward(distance: float) -> float:
    """Dense reward: minus the distance after the step."""
    return -distance


def reach_success(distance: float) -> bool:
    """Within ``SUCCESS_M`` of the target."""
    return distance < SUCCESS_M


# How the simulated arm (robot_io's controller on the PyBullet Panda: the in-process NS Reach and the
# stack's mock) follows a displacement command within one control period, measured by
# ``python bench/reach_model.py`` (results/reach_model.json): it covers ~0.97 of a small step and
# saturates towards 28 mm a period (0.55 m/s: the IK's joint-speed limits), |moved| ≈
# TRACK_STEP_M * tanh(TRACK_GAIN * |action| / TRACK_STEP_M); the end-effector velocity it reports at the
# end of the period is ~0.53 of the period's mean (the position controller is settling).
TRACK_GAIN = 0.975
TRACK_STEP_M = 0.0275
TRACK_VELOCITY_RATIO = 0.53


@dataclass(frozen=True)
class ArmTracking:
    """How far the end effector gets in a period when told a step: |moved| = step_m * tanh(gain * |step| /
    step_m) (``step_m`` None: gain * |step|, no saturation), and the velocity it then reports, as
    ``velocity_ratio`` of the period's mean."""

    gain: float
    step_m: float | None
    velocity_ratio: float


TRACKING = ArmTracking(TRACK_GAIN, TRACK_STEP_M, TRACK_VELOCITY_RATIO)  # the simulated arm's, measured
FACE_VALUE = ArmTracking(1.0, None, 1.0)  # the commanded step taken as done (the model before)


def tracked_step(
    action: np.ndarray, max_step: float = MAX_STEP_M, tracking: ArmTracking = TRACKING
) -> np.ndarray:
    """Where the end effector goes in one period when told ``action``: clipped per axis to the action
    box, capped at ``max_step`` as the robot caps it, then shortened as the arm tracks it (above)."""
    action = np.clip(np.asarray(action, float), -max_step, max_step)
    norm = min(float(np.linalg.norm(action)), max_step)
    action = cap_step_length(action, max_step)
    if norm == 0.0:
        return action
    if tracking.step_m is None:
        return tracking.gain * action
    return action * (tracking.step_m * np.tanh(tracking.gain * norm / tracking.step_m) / norm)


def predict_reach(
    obs: np.ndarray,
    action: np.ndarray,
    dt: float,
    max_step: float = MAX_STEP_M,
    tracking: ArmTracking = TRACKING,
    workspace: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """The reach task's world model, one control period ahead: the end effector moves as the arm tracks
    the action (``tracked_step``; the model once took the commanded step at face value and its 10-step
    predictions were off by ~7 cm, ~3 cm with the tracking, bench/reach_model.py), towards a goal held
    inside the ``workspace`` box (lo, hi) as robot-io clips it (a model without the walls predicts a
    pinned arm moving on, and the retreat fired on that every few ticks: docs/learner_plans.md), and the
    target keeps its estimated velocity. It knows nothing of the target's turns: what a plan made from it
    assumes, and what the retreat checks against."""
    obs = np.asarray(obs, float)
    if workspace is not None:
        ee = obs[0:3]
        action = np.clip(ee + np.clip(np.asarray(action, float), -max_step, max_step), *workspace) - ee
    step = tracked_step(action, max_step, tracking)
    nxt = obs.copy()
    nxt[0:3] = obs[0:3] + step
    nxt[3:6] = tracking.velocity_ratio * step / dt
    nxt[6:9] = obs[6:9] + obs[9:12] * dt
    nxt[12:15] = nxt[6:9] - nxt[0:3]
    return nxt
