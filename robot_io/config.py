"""Configuration of the robot interface (the ``robot:`` section), typed so a bad YAML fails early."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from common.config import Section, Vec3, check_box
from robot_io.backends.franky_config import FrankaConfig, Joints
from robot_io.backends.pybullet_config import MockArmConfig
from robot_io.description import MODELS

MotionPreset = Literal["static", "slow", "fast", "erratic"]
"""The PyBullet backend's target motions, declared here so reading a config never loads sim; sim's
``MotionPreset`` names the same presets (tests/robot_io/test_panda_description.py holds them equal)."""


class WorkspaceBox(Section):
    """Axis-aligned box (base frame, metres) the end effector must stay inside."""

    lo: Vec3 = Field(
        (0.2, -0.45, 0.05), description="the box's lower corner (x, y, z) in the robot base frame, in metres"
    )
    hi: Vec3 = Field(
        (0.8, 0.45, 0.7),
        description="the box's upper corner (x, y, z) in the robot base frame, in metres; above lo on every"
        " axis",
    )

    @model_validator(mode="after")
    def _lo_below_hi(self) -> WorkspaceBox:
        check_box(self.lo, self.hi)
        return self


class IKConfig(Section):
    """Weights of the mink QP: track the position hard, keep the tool pointing down, stay near home."""

    position_cost: float = Field(1.0, gt=0)  # weight of reaching the target position (> 0: the point)
    orientation_cost: float = Field(
        0.2,
        ge=0,
        description="weight of keeping the tool's orientation at home (pointing down), relative to"
        " position_cost; 0 lets it turn freely",
    )
    posture_cost: float = Field(
        1e-3,
        ge=0,
        description="weight of staying near home_q, which picks one of the arm's redundant (7-joint)"
        " solutions",
    )
    damping: float = Field(
        1e-4,
        ge=0,
        description="damping added to every task of the QP (mink's ``damping``): higher is numerically"
        " steadier near singularities and converges slower",
    )
    solver: str = Field(
        "daqp",
        description="the QP solver mink calls (a qpsolvers name, e.g. daqp, quadprog, osqp; it must be"
        " installed)",
    )
    # Levenberg-Marquardt damping of the end-effector task, scaled by its squared error: it shortens the
    # step only when the goal is far (out of reach), where one full-period QP otherwise chatters up to
    # 4 mm back and forth at a limit (tests/robot_io/test_ik_tracking.py); 3-10 all pass, tracking
    # stays within 0.04 mm. With it one QP a period does (docs/robot_interface.md).
    lm_damping: float = Field(5.0, ge=0)
    # QP solves per control period, each integrating over period/iterations.
    iterations: int = Field(1, ge=1)


class TrackingConfig(Section):
    """How this arm's commanded TCP follows a displacement step within one control period, for the reach
    plan model (``tasks.reach.ArmTracking``): |moved| = step_m * tanh(gain * |step| / step_m), and the
    measured velocity it then reports as ``velocity_ratio`` of the period's mean. Measure it on the arm:
    ``python bench/reach_model.py --recording RUN.mcap`` fits it from a stack run's transitions."""

    gain: float = Field(
        gt=0,
        le=2,
        description="slope of the fitted tracking curve (dimensionless): small steps move gain times their"
        " length",
    )
    step_m: float = Field(
        gt=0,
        le=0.1,
        description="the most the TCP moves in one control period however long the step (metres): the"
        " curve's saturation",
    )
    velocity_ratio: float = Field(
        ge=0,
        le=2,
        description="the TCP velocity the arm reports after a step, as a fraction of the period's mean"
        " velocity",
    )


class RobotConfig(Section):
    """The ``robot:`` section: backend, rates, limits and safety of one arm."""

    backend: Literal["pybullet", "franka"] = Field(
        "pybullet",
        description="the arm: pybullet (a simulated Panda in this process, no hardware) or franka (a Franka"
        " arm, or franky-sim, through franky)",
    )
    model: Literal["panda", "fr3"] = "panda"  # robot_io.description.MODELS: IK, FK and limits follow it
    control_rate_hz: float = Field(
        20.0,
        ge=1.0,
        le=1000.0,
        description="robot-io's control loop rate, in Hz: one action of a chunk is played per period (20"
        " Hz: one every 50 ms)",
    )
    physics_substeps: int = Field(12, ge=1)  # pybullet: physics steps per control period
    # Largest end-effector displacement accepted per control period (the task's 5 cm per step bound).
    max_step_m: float = Field(0.05, gt=0, le=0.05)
    # How far the commanded TCP may lead the measured one. A streamed position-controlled arm (franky)
    # lags its command by a few periods; the command goes on from where it was commanded, held within this
    # of the hand, so it never runs away from a slow or blocked arm. On franky-sim 0.05 capped the hand at
    # ~15 mm a period, 0.1 let it reach ~25 (docs/robot_interface.md); the mock tracks within ~1 cm.
    command_lead_m: float = Field(0.1, gt=0, le=0.3)
    # Longest chunk (plan) accepted: 25 s at 20 Hz, far beyond any learner's horizon (h_max 50); a longer
    # one is a learner bug and is refused whole, which also bounds the queue.
    max_plan_actions: int = Field(500, ge=1)
    # A chunk numbered further ahead of its session's last one than this is refused (robot_io.command_gate):
    # a learner numbers its chunks 1 by 1, so a big jump is a corrupted or forged number, not lost ones.
    max_chunk_seq_gap: int = Field(32, ge=1, le=10_000)
    joint_margin_rad: float = Field(0.02, ge=0, lt=0.3)  # commands stay this far inside the URDF limits
    velocity_scale: float = Field(0.5, gt=0, le=1)  # fraction of the URDF joint velocity limits for the IK
    watchdog_timeout_s: float = Field(
        0.5,
        gt=0,
        description="with no command for this long (seconds), robot-io holds the arm where it is until"
        " commands resume",
    )
    # Niceness asked for robot-io's control thread (Linux; below 0 needs CAP_SYS_NICE, else it runs at the
    # process's and says so once): a starved control thread ticked late and held e-stops past 2 periods.
    control_thread_nice: int = Field(-5, ge=-20, le=19)
    # How the simulated target moves (the pybullet mock, franky-sim's scripted target).
    target_motion: MotionPreset = "slow"
    seed: int = Field(
        0,
        description="seeds the simulated target's motion (the pybullet mock's, and franky-sim's scripted"
        " target)",
    )
    home_q: Joints = Field(
        MODELS["panda"].home_q,
        description="joint positions (rad, joints 1 to 7) the arm goes to at start-up and at each episode"
        " reset; also the IK's posture target",
    )
    workspace: WorkspaceBox = Field(
        WorkspaceBox(),
        description="the box the end effector must stay inside: a target outside it is clipped to it",
    )
    ik: IKConfig = Field(
        IKConfig(),
        description="the weights of the IK that turns each end-effector target into joint positions",
    )
    franka: FrankaConfig = Field(
        FrankaConfig(), description="the franky connection and the arm's own settings (backend franka only)"
    )
    mock: MockArmConfig = MockArmConfig()  # the PyBullet mock arm's dynamics (backend pybullet only)
    # The arm's measured tracking for the plan model; None: the PyBullet mock's (tasks.reach.TRACKING),
    # which a franka stack config may not leave it at (bench/reach_model.py fits an arm's own).
    tracking: TrackingConfig | None = None

    @model_validator(mode="after")
    def _mock_arm_is_a_panda(self) -> RobotConfig:
        if self.backend == "pybullet" and self.model != "panda":
            raise ValueError(f"model {self.model!r}: the pybullet mock arm is the Panda; use backend franka")
        return self

    @property
    def simulated(self) -> bool:
        """The arm or its target is simulated: the backend needs a world built above robot_io
        (``tasks.sim_world.robot_world``)."""
        return self.backend == "pybullet" or self.franka.simulated_target

    @property
    def period(self) -> float:
        return 1.0 / self.control_rate_hz
