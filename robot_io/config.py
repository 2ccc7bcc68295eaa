"""Configuration of the robot interface (the ``robot:`` section), typed so a bad YAML fails early."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from common.config import Section, Vec3, check_box
from robot_io.description import MODELS

Joints = Annotated[tuple[float, ...], Field(min_length=7, max_length=7)]
"""One number per arm joint."""
Wrench = Annotated[tuple[float, ...], Field(min_length=6, max_length=6)]
"""Force (x, y, z) then torque (x, y, z)."""
MotionPreset = Literal["static", "slow", "fast", "erratic"]
"""The PyBullet backend's target motions, declared here so reading a config never loads sim; sim's
``MotionPreset`` names the same presets (tests/robot_io/test_panda_description.py holds them equal)."""


class WorkspaceBox(Section):
    """Axis-aligned box (base frame, metres) the end effector must stay inside."""

    lo: Vec3 = (0.2, -0.45, 0.05)
    hi: Vec3 = (0.8, 0.45, 0.7)

    @model_validator(mode="after")
    def _lo_below_hi(self) -> WorkspaceBox:
        check_box(self.lo, self.hi)
        return self


class IKConfig(Section):
    """Weights of the mink QP: track the position hard, keep the tool pointing down, stay near home."""

    position_cost: float = Field(1.0, gt=0)  # > 0: the end-effector task is the point
    orientation_cost: float = Field(0.2, ge=0)
    posture_cost: float = Field(1e-3, ge=0)
    damping: float = Field(1e-4, ge=0)
    solver: str = "daqp"
    # Levenberg-Marquardt damping of the end-effector task, scaled by its squared error: it shortens the
    # step only when the goal is far (out of reach), where one full-period QP otherwise chatters up to
    # 4 mm back and forth at a limit (tests/robot_io/test_ik_tracking.py); 3-10 all pass, tracking
    # stays within 0.04 mm. With it one QP a period does (docs/robot_interface.md).
    lm_damping: float = Field(5.0, ge=0)
    # QP solves per control period, each integrating over period/iterations.
    iterations: int = Field(1, ge=1)


class FrankaConfig(Section):
    """The franky connection, how commands become motions, collision behaviour and fault recovery.

    ``stream`` picks how each control period's IK target reaches the arm (measured in
    bench/franka_bench.py): ``velocity`` sends a jerk-limited waypoint reached in one period *at the
    velocity the IK implies*, so consecutive targets blend into one continuous motion; ``rest`` sends a
    plain waypoint that the arm approaches to a stop (the stop-and-go that streaming reports describe).
    """

    ip: str = "172.16.0.2"  # the FCI address (franky-sim: the loopback address it prints)
    realtime: Literal["enforce", "ignore"] = "ignore"  # libfranka RealtimeConfig (enforce on a PREEMPT_RT PC)
    stream: Literal["velocity", "rest"] = "velocity"
    # franky's relative dynamics factor (velocity, acceleration, jerk) for the streamed motions; the IK
    # already bounds joint speed by robot.velocity_scale.
    dynamics: tuple[float, float, float] = (1.0, 0.3, 0.3)
    home_dynamics: float = Field(0.15, gt=0, le=1)  # reset's point-to-point move home
    # mlockall at connect (robot_io/backends/memory_lock.py): no page fault stalls the 1 kHz loop. It needs
    # CAP_IPC_LOCK or `ulimit -l unlimited`; refused: fatal under realtime: enforce, else a warning.
    lock_memory: bool = False
    lower_torque_thresholds: Joints = (20.0,) * 7
    upper_torque_thresholds: Joints = (40.0,) * 7
    lower_force_thresholds: Wrench = (10.0,) * 6
    upper_force_thresholds: Wrench = (20.0,) * 6
    joint_impedance: Joints = (3000.0, 3000.0, 3000.0, 2500.0, 2500.0, 2000.0, 2000.0)
    # Faults recovered without the operator (libfranka error names, or ``connection_lost``), at most
    # ``auto_recover_limit`` times until the operator's next release; anything else holds for a release.
    auto_recover: tuple[str, ...] = ("communication_constraints_violation",)
    auto_recover_limit: int = Field(3, ge=0)
    # franky-sim only: robot-io scripts a target (robot.target_motion) and publishes it on sim/target_truth,
    # since no camera sees the simulator's world.
    simulated_target: bool = False

    @model_validator(mode="after")
    def _dynamics_in_range(self) -> FrankaConfig:
        if not all(0 < f <= 1 for f in self.dynamics):
            raise ValueError(f"dynamics {self.dynamics}: each factor must be in (0, 1]")
        return self


class TrackingConfig(Section):
    """How this arm's commanded TCP follows a displacement step within one control period, for the reach
    plan model (``tasks.reach.ArmTracking``): |moved| = step_m * tanh(gain * |step| / step_m), and the
    measured velocity it then reports as ``velocity_ratio`` of the period's mean. Measure it on the arm:
    ``python bench/reach_model.py --recording RUN.mcap`` fits it from a stack run's transitions."""

    gain: float = Field(gt=0, le=2)
    step_m: float = Field(gt=0, le=0.1)
    velocity_ratio: float = Field(ge=0, le=2)


class MockArmConfig(Section):
    """The PyBullet mock arm's own dynamics, for the reality-gap overlays (configs/gaps/): a real arm
    tracks with its own gains and its commands take effect later than the mock's."""

    position_gain: float = Field(0.3, gt=0, le=1)  # PyBullet's servo gain: lower tracks slower
    actuation_delay_ms: float = Field(0.0, ge=0, le=500)  # each joint command takes effect this late


class RobotConfig(Section):
    """The ``robot:`` section: backend, rates, limits and safety of one arm."""

    backend: Literal["pybullet", "franka"] = "pybullet"
    model: Literal["panda", "fr3"] = "panda"  # robot_io.description.MODELS: IK, FK and limits follow it
    control_rate_hz: float = Field(20.0, ge=1.0, le=1000.0)
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
    watchdog_timeout_s: float = Field(0.5, gt=0)
    # Niceness asked for robot-io's control thread (Linux; below 0 needs CAP_SYS_NICE, else it runs at the
    # process's and says so once): a starved control thread ticked late and held e-stops past 2 periods.
    control_thread_nice: int = Field(-5, ge=-20, le=19)
    target_motion: MotionPreset = "slow"  # pybullet
    seed: int = 0
    home_q: Joints = MODELS["panda"].home_q
    workspace: WorkspaceBox = WorkspaceBox()
    ik: IKConfig = IKConfig()
    franka: FrankaConfig = FrankaConfig()
    mock: MockArmConfig = MockArmConfig()  # pybullet only
    # The arm's measured tracking for the plan model; None: the PyBullet mock's (tasks.reach.TRACKING).
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
