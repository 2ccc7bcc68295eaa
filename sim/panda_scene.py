"""The PyBullet Panda scene shared by NS Reach, the robot_io mock backend and the sim camera.

One scene, one physics client: a floor, a table whose top is the robot base plane (z = 0), the Panda
from ``pybullet_data`` (loaded from the package at run time, never copied) and a red target box that
moves with bounded, varying speed inside a reachable box. The target is visual-only (no collision) so
it never pushes the arm; its pose is ground truth for tests and for the sim camera's renderer, which
calls ``pybullet.getCameraImage(..., physicsClientId=scene.client_id)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol

import numpy as np
import pybullet as pb
import pybullet_data
from pydantic import Field, model_validator

from common.config import Box3, Section

PANDA_URDF = Path(pybullet_data.getDataPath()) / "franka_panda" / "panda.urdf"
TARGET_RGBA = (1.0, 0.0, 0.0, 1.0)
TARGET_HALF = 0.025  # the target box is 5 cm on a side
TABLE_TOP_Z = 0.0
TABLE_HEIGHT = 0.7


def panda_urdf_path() -> Path:
    """Path of the Panda URDF that the pybullet package ships (the one robot description)."""
    if not PANDA_URDF.is_file():
        raise FileNotFoundError(f"{PANDA_URDF}: pybullet_data has no franka_panda/panda.urdf")
    return PANDA_URDF


class SceneRobot(Protocol):
    """What the scene needs to know of its arm; robot_io's ``RobotModel`` is one (sim never imports it)."""

    @property
    def urdf_path(self) -> Path: ...
    @property
    def arm_joints(self) -> tuple[str, ...]: ...
    @property
    def finger_joints(self) -> tuple[str, ...]: ...
    @property
    def ee_link(self) -> str: ...
    @property
    def home_q(self) -> tuple[float, ...]: ...


@dataclass(frozen=True)
class StandalonePanda:
    """The arm of a scene built without robot_io (vision's replica and calibration scenes, benches).

    robot_io's ``MODELS["panda"]`` is the description the controller uses; a test holds the two equal.
    """

    urdf_path: Path = PANDA_URDF
    arm_joints: tuple[str, ...] = tuple(f"panda_joint{i}" for i in range(1, 8))
    finger_joints: tuple[str, ...] = ("panda_finger_joint1", "panda_finger_joint2")
    ee_link: str = "panda_grasptarget"  # the tool centre point, 0.105 m beyond the hand flange
    # A comfortable pose above the table, the usual Panda "ready" configuration.
    home_q: tuple[float, ...] = (0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4)


MotionPreset = Literal["static", "slow", "fast", "erratic"]


class TargetMotion(Section):
    """How the target wanders: speed varies smoothly within [speed_min, speed_max] (m/s).

    ``turn_rate`` (rad/s, rms) sets how fast the heading drifts, ``speed_period`` (s) how fast the
    speed swings. The target stays in ``box`` (lo xyz, hi xyz), reflected at its walls.
    """

    speed_min: float = Field(0.02, ge=0, description="the target's slowest speed (m/s)")
    speed_max: float = Field(0.06, description="the target's fastest speed (m/s); at least speed_min")
    speed_period: float = Field(
        8.0, gt=0, description="the period (seconds) of the speed's swing between speed_min and speed_max"
    )
    turn_rate: float = Field(0.6, ge=0, description="how fast the heading drifts (rad/s, rms)")
    box: Box3 = Field(
        ((0.35, -0.3, 0.12), (0.65, 0.3, 0.45)),
        description="the box (lo xyz, hi xyz; metres, robot base frame) the target stays in, reflected at"
        " its walls",
    )

    @model_validator(mode="after")
    def _min_below_max(self) -> TargetMotion:
        if self.speed_min > self.speed_max:
            raise ValueError(f"speed_min ({self.speed_min}) must be <= speed_max ({self.speed_max})")
        return self

    @staticmethod
    def preset(name: MotionPreset) -> TargetMotion:
        """``static``, ``slow``, ``fast`` or ``erratic`` (faster still, and its heading and speed swing
        within a second: kept apart from the presets the retreat was tuned on)."""
        presets = {
            "static": TargetMotion(speed_min=0.0, speed_max=0.0),
            "slow": TargetMotion(speed_min=0.02, speed_max=0.06, speed_period=10.0, turn_rate=0.5),
            "fast": TargetMotion(speed_min=0.08, speed_max=0.20, speed_period=4.0, turn_rate=1.2),
            "erratic": TargetMotion(speed_min=0.05, speed_max=0.25, speed_period=1.5, turn_rate=3.0),
        }
        if name not in presets:
            raise ValueError(f"unknown target motion preset {name!r}; choose from {sorted(presets)}")
        return presets[name]


@dataclass
class TargetState:
    """The target's integrated state; advanced deterministically from a seeded generator."""

    motion: TargetMotion
    rng: np.random.Generator
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    heading: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    phase: float = 0.0

    @classmethod
    def start(cls, motion: TargetMotion, seed: int | None) -> TargetState:
        rng = np.random.default_rng(seed)
        lo, hi = (np.asarray(b, float) for b in motion.box)
        margin = 0.1 * (hi - lo)
        heading = rng.normal(size=3)
        state = cls(motion=motion, rng=rng, position=rng.uniform(lo + margin, hi - margin))
        state.heading = heading / np.linalg.norm(heading)
        state.phase = float(rng.uniform(0, 2 * math.pi))
        state.velocity = state.speed() * state.heading
        return state

    def speed(self) -> float:
        m = self.motion
        return m.speed_min + (m.speed_max - m.speed_min) * 0.5 * (1.0 + math.sin(self.phase))

    def advance(self, dt: float) -> None:
        """Move by ``dt`` seconds: drift the heading, swing the speed, reflect at the box walls.

        Runs every physics step (12 a control period), so it avoids numpy's wrappers where a plain call
        gives the same numbers (``sqrt(h·h)`` is what ``np.linalg.norm`` computes for a vector)."""
        m = self.motion
        # The speed phase itself jitters so the swing is not a pure sinusoid (varying, still bounded).
        self.phase += dt * 2 * math.pi / m.speed_period * (1.0 + 0.5 * self.rng.uniform(-1, 1))
        heading = self.heading + m.turn_rate * math.sqrt(dt) * self.rng.normal(size=3)
        heading /= np.sqrt(heading.dot(heading))
        self.heading = heading
        pos = self.position + self.speed() * heading * dt
        lo, hi = m.box
        for axis in range(3):
            p, low, high = float(pos[axis]), lo[axis], hi[axis]
            if p < low or p > high:
                wall = min(max(p, low), high)
                pos[axis] = min(max(2 * wall - p, low), high)
                heading[axis] = -heading[axis]
        self.velocity = (pos - self.position) / dt if dt > 0 else np.zeros(3)
        self.position = pos


class PandaScene:
    """The PyBullet world. ``step()`` advances physics and the target by one ``time_step``.

    ``client_id``, ``robot_id`` and ``target_id`` are public so other parts (the sim camera) can use
    the same client. Not thread-safe: one owner steps and renders it.
    """

    def __init__(
        self,
        motion: TargetMotion | str = "slow",
        seed: int | None = 0,
        time_step: float = 1.0 / 240.0,
        gui: bool = False,
        joint_force: float = 500.0,
        robot: SceneRobot | None = None,
        position_gain: float = 0.3,
    ) -> None:
        self.robot: SceneRobot = robot or StandalonePanda()
        self.time_step = float(time_step)
        self.joint_force = float(joint_force)
        self.position_gain = float(position_gain)
        self.motion = TargetMotion.preset(motion) if isinstance(motion, str) else motion
        self.client_id = pb.connect(pb.GUI if gui else pb.DIRECT)
        if self.client_id < 0:
            raise RuntimeError("pybullet could not connect")
        cid = self.client_id
        pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=cid)
        pb.setGravity(0, 0, -9.81, physicsClientId=cid)
        pb.setTimeStep(self.time_step, physicsClientId=cid)
        self.plane_id = pb.loadURDF("plane.urdf", [0, 0, TABLE_TOP_Z - TABLE_HEIGHT], physicsClientId=cid)
        self.table_id = self._make_table()
        urdf = self.robot.urdf_path
        if not urdf.is_file():
            raise FileNotFoundError(f"{urdf}: no such URDF")
        self.robot_id = pb.loadURDF(str(urdf), [0, 0, 0], useFixedBase=True, physicsClientId=cid)
        names = {
            pb.getJointInfo(self.robot_id, j, physicsClientId=cid)[1].decode(): j
            for j in range(pb.getNumJoints(self.robot_id, physicsClientId=cid))
        }
        self.arm_joints = [names[n] for n in self.robot.arm_joints]
        self.finger_joints = [names[n] for n in self.robot.finger_joints]
        # A link's index equals its parent joint's index in PyBullet.
        self.ee_link = next(
            j
            for j in names.values()
            if pb.getJointInfo(self.robot_id, j, physicsClientId=cid)[12].decode() == self.robot.ee_link
        )
        self.target_id = self._make_target()
        self.time = 0.0
        self.target = TargetState.start(self.motion, seed)
        self.reset_robot()
        self._place_target()

    # -- construction ------------------------------------------------------------------------------
    def _make_table(self) -> int:
        cid = self.client_id
        half = [0.45, 0.7, TABLE_HEIGHT / 2]
        center = [0.55, 0.0, TABLE_TOP_Z - TABLE_HEIGHT / 2]
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=cid)
        vis = pb.createVisualShape(
            pb.GEOM_BOX, halfExtents=half, rgbaColor=[0.55, 0.4, 0.25, 1.0], physicsClientId=cid
        )
        return pb.createMultiBody(0, col, vis, center, physicsClientId=cid)

    def _make_target(self) -> int:
        cid = self.client_id
        vis = pb.createVisualShape(
            pb.GEOM_BOX, halfExtents=[TARGET_HALF] * 3, rgbaColor=list(TARGET_RGBA), physicsClientId=cid
        )
        # No collision shape: the target is something to reach, not an obstacle.
        return pb.createMultiBody(0, -1, vis, [0.5, 0.0, 0.3], physicsClientId=cid)

    # -- robot -------------------------------------------------------------------------------------
    def reset_robot(self, q: np.ndarray | tuple[float, ...] | None = None) -> None:
        """Teleport the arm to ``q`` (default: its home pose) at rest and hold it there (fingers open)."""
        q = self.robot.home_q if q is None else q
        cid = self.client_id
        for j, qj in zip(self.arm_joints, q, strict=True):
            pb.resetJointState(self.robot_id, j, float(qj), 0.0, physicsClientId=cid)
        for j in self.finger_joints:
            pb.resetJointState(self.robot_id, j, 0.04, 0.0, physicsClientId=cid)
        pb.setJointMotorControlArray(
            self.robot_id,
            self.finger_joints,
            pb.POSITION_CONTROL,
            targetPositions=[0.04, 0.04],
            forces=[20.0, 20.0],
            physicsClientId=cid,
        )
        self.command_positions(np.asarray(q, float))

    def command_positions(self, q: np.ndarray, max_velocity: np.ndarray | None = None) -> None:
        """Servo the arm joints to ``q`` (PD position control, optionally velocity-capped per joint)."""
        cid = self.client_id
        for i, j in enumerate(self.arm_joints):
            kwargs = {} if max_velocity is None else {"maxVelocity": float(max_velocity[i])}
            pb.setJointMotorControl2(
                self.robot_id,
                j,
                pb.POSITION_CONTROL,
                targetPosition=float(q[i]),
                targetVelocity=0.0,
                force=self.joint_force,
                positionGain=self.position_gain,
                velocityGain=1.0,
                physicsClientId=cid,
                **kwargs,
            )

    def brake(self) -> None:
        """Stop: servo to the current position with full force and no speed cap (PD braking)."""
        q, _ = self.joint_state()
        self.command_positions(q)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Arm joint positions and velocities (7 each)."""
        states = pb.getJointStates(self.robot_id, self.arm_joints, physicsClientId=self.client_id)
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])

    def ee_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """End-effector (tool centre point) position and quaternion xyzw in the base/world frame."""
        s = pb.getLinkState(
            self.robot_id, self.ee_link, computeForwardKinematics=True, physicsClientId=self.client_id
        )
        return np.array(s[4]), np.array(s[5])

    def ee_velocity(self) -> np.ndarray:
        s = pb.getLinkState(
            self.robot_id,
            self.ee_link,
            computeLinkVelocity=True,
            computeForwardKinematics=True,
            physicsClientId=self.client_id,
        )
        return np.array(s[6])

    # -- target ------------------------------------------------------------------------------------
    def reset_target(self, seed: int | None = None, motion: TargetMotion | str | None = None) -> None:
        """Start a new target motion (new start point, heading and speed phase) from ``seed``."""
        if motion is not None:
            self.motion = TargetMotion.preset(motion) if isinstance(motion, str) else motion
        self.target = TargetState.start(self.motion, seed)
        self._place_target()

    def target_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Ground-truth target position and quaternion xyzw (for tests and the sim camera only)."""
        pos, quat = pb.getBasePositionAndOrientation(self.target_id, physicsClientId=self.client_id)
        return np.array(pos), np.array(quat)

    def target_velocity(self) -> np.ndarray:
        return self.target.velocity.copy()

    def _place_target(self) -> None:
        pb.resetBasePositionAndOrientation(
            self.target_id, self.target.position.tolist(), [0, 0, 0, 1], physicsClientId=self.client_id
        )

    def show(self, q: np.ndarray, target_position: np.ndarray) -> None:
        """Pose the arm and the target without physics: a kinematic replica for rendering elsewhere."""
        cid = self.client_id
        for j, qj in zip(self.arm_joints, q, strict=True):
            pb.resetJointState(self.robot_id, j, float(qj), 0.0, physicsClientId=cid)
        pb.resetBasePositionAndOrientation(
            self.target_id, [float(x) for x in target_position], [0, 0, 0, 1], physicsClientId=cid
        )

    # -- time --------------------------------------------------------------------------------------
    def step(self, n: int = 1) -> None:
        """Advance physics and the target by ``n`` time steps."""
        for _ in range(n):
            self.target.advance(self.time_step)
            pb.stepSimulation(physicsClientId=self.client_id)
            self.time += self.time_step
        self._place_target()  # visual only (no collision shape): no physics step needs it moved sooner

    def steps_for(self, seconds: float) -> int:
        """How many physics steps make ``seconds`` (at least one)."""
        return max(1, round(seconds / self.time_step))

    def close(self) -> None:
        if self.client_id >= 0 and pb.isConnected(self.client_id):
            pb.disconnect(self.client_id)
        self.client_id = -1

    def __enter__(self) -> PandaScene:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
