"""Configuration of a Franka arm through franky (``robot.franka``), beside its backend
(``robot_io/backends/franky_backend.py``)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from common.config import Section

Joints = Annotated[tuple[float, ...], Field(min_length=7, max_length=7)]
"""One number per arm joint."""
Wrench = Annotated[tuple[float, ...], Field(min_length=6, max_length=6)]
"""Force (x, y, z) then torque (x, y, z)."""


class FrankaConfig(Section):
    """The franky connection, how commands become motions, collision behaviour and fault recovery.

    ``stream`` picks how each control period's IK target reaches the arm (measured in
    bench/franka_bench.py): ``velocity`` sends a jerk-limited waypoint reached in one period *at the
    velocity the IK implies*, so consecutive targets blend into one continuous motion; ``rest`` sends a
    plain waypoint that the arm approaches to a stop (the stop-and-go that streaming reports describe).
    """

    ip: str = "172.16.0.2"  # the FCI address (franky-sim: the loopback address it prints)
    realtime: Literal["enforce", "ignore"] = "ignore"  # libfranka RealtimeConfig (enforce on a PREEMPT_RT PC)
    stream: Literal["velocity", "rest"] = Field(
        "velocity",
        description="how each period's IK target is sent: velocity (blended into one continuous motion) or"
        " rest (each waypoint approached to a stop)",
    )
    # franky's relative dynamics factor (velocity, acceleration, jerk) for the streamed motions; the IK
    # already bounds joint speed by robot.velocity_scale.
    dynamics: tuple[float, float, float] = (1.0, 0.3, 0.3)
    home_dynamics: float = Field(0.15, gt=0, le=1)  # reset's move home at this fraction of `dynamics`
    # mlockall at connect (robot_io/backends/memory_lock.py): no page fault stalls the 1 kHz loop. It needs
    # CAP_IPC_LOCK or `ulimit -l unlimited`; refused: fatal under realtime: enforce, else a warning.
    lock_memory: bool = False
    lower_torque_thresholds: Joints = Field(
        (20.0,) * 7,
        description="per joint, the external torque (Nm) above which libfranka reports a contact"
        " (set_collision_behavior)",
    )
    upper_torque_thresholds: Joints = Field(
        (40.0,) * 7,
        description="per joint, the external torque (Nm) above which libfranka stops the arm with a"
        " collision reflex",
    )
    lower_force_thresholds: Wrench = Field(
        (10.0,) * 6,
        description="the external Cartesian force (N: x, y, z) and torque (Nm: x, y, z) above which"
        " libfranka reports a contact",
    )
    upper_force_thresholds: Wrench = Field(
        (20.0,) * 6,
        description="the external Cartesian force (N: x, y, z) and torque (Nm: x, y, z) above which"
        " libfranka stops the arm with a collision reflex",
    )
    joint_impedance: Joints = Field(
        (3000.0, 3000.0, 3000.0, 2500.0, 2500.0, 2000.0, 2000.0),
        description="stiffness of libfranka's internal joint impedance controller, per joint (Nm/rad)",
    )
    # Faults recovered without the operator (libfranka error names, or ``connection_lost``), at most
    # ``auto_recover_limit`` times until the operator's next release; anything else holds for a release.
    auto_recover: tuple[str, ...] = ("communication_constraints_violation",)
    auto_recover_limit: int = Field(
        3,
        ge=0,
        description="how many times the faults in auto_recover are recovered without the operator until the"
        " operator's next release (0: never)",
    )
    # franky-sim only: robot-io scripts a target (robot.target_motion) and publishes it on sim/target_truth,
    # since no camera sees the simulator's world.
    simulated_target: bool = False

    @model_validator(mode="after")
    def _dynamics_in_range(self) -> FrankaConfig:
        if not all(0 < f <= 1 for f in self.dynamics):
            raise ValueError(f"dynamics {self.dynamics}: each factor must be in (0, 1]")
        return self
