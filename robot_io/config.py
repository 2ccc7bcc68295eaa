"""Configuration of the robot interface, validated on construction so a bad YAML fails early and clearly."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from sim.panda_scene import HOME_Q, TargetMotion

BACKENDS = ("pybullet", "franka")


def _vec(name: str, value: object, n: int) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in value)  # type: ignore[union-attr]
    except TypeError:
        raise ValueError(f"{name} must be a list of {n} numbers, got {value!r}") from None
    if len(out) != n or not all(math.isfinite(v) for v in out):
        raise ValueError(f"{name} must be {n} finite numbers, got {value!r}")
    return out


@dataclass(frozen=True)
class WorkspaceBox:
    """Axis-aligned box (base frame, metres) the end effector must stay inside."""

    lo: tuple[float, float, float] = (0.2, -0.45, 0.05)
    hi: tuple[float, float, float] = (0.8, 0.45, 0.7)

    def __post_init__(self) -> None:
        object.__setattr__(self, "lo", _vec("workspace.lo", self.lo, 3))
        object.__setattr__(self, "hi", _vec("workspace.hi", self.hi, 3))
        if any(lo >= hi for lo, hi in zip(self.lo, self.hi, strict=True)):
            raise ValueError(f"workspace.lo {self.lo} must be below workspace.hi {self.hi} on every axis")


@dataclass(frozen=True)
class IKConfig:
    """Weights of the mink QP: track the position hard, keep the tool pointing down, stay near home."""

    position_cost: float = 1.0
    orientation_cost: float = 0.2
    posture_cost: float = 1e-3
    damping: float = 1e-4
    solver: str = "daqp"
    iterations: int = 2  # QP solves per control period (each integrates over period/iterations)

    def __post_init__(self) -> None:
        for name in ("position_cost", "orientation_cost", "posture_cost", "damping"):
            if getattr(self, name) < 0:
                raise ValueError(f"ik.{name} must be >= 0, got {getattr(self, name)}")
        if self.position_cost <= 0:
            raise ValueError("ik.position_cost must be > 0 (the end effector task is the point)")
        if self.iterations < 1:
            raise ValueError(f"ik.iterations must be >= 1, got {self.iterations}")


@dataclass(frozen=True)
class FrankaConfig:
    """pylibfranka connection and the collision/impedance behaviour set on connect."""

    ip: str = "172.16.0.2"
    realtime: str = "ignore"  # enforce | ignore (libfranka RealtimeConfig)
    lower_torque_thresholds: tuple[float, ...] = (20.0,) * 7
    upper_torque_thresholds: tuple[float, ...] = (40.0,) * 7
    lower_force_thresholds: tuple[float, ...] = (10.0,) * 6
    upper_force_thresholds: tuple[float, ...] = (20.0,) * 6
    joint_impedance: tuple[float, ...] = (3000.0, 3000.0, 3000.0, 2500.0, 2500.0, 2000.0, 2000.0)
    recover_attempts: int = 3

    def __post_init__(self) -> None:
        if self.realtime not in ("enforce", "ignore"):
            raise ValueError(f"franka.realtime must be 'enforce' or 'ignore', got {self.realtime!r}")
        for name, n in (
            ("lower_torque_thresholds", 7),
            ("upper_torque_thresholds", 7),
            ("lower_force_thresholds", 6),
            ("upper_force_thresholds", 6),
            ("joint_impedance", 7),
        ):
            object.__setattr__(self, name, _vec(f"franka.{name}", getattr(self, name), n))
        if self.recover_attempts < 0:
            raise ValueError(f"franka.recover_attempts must be >= 0, got {self.recover_attempts}")


@dataclass(frozen=True)
class RobotConfig:
    """The ``robot:`` section: backend, rates, limits and safety of one arm."""

    backend: str = "pybullet"
    control_rate_hz: float = 20.0
    physics_substeps: int = 12  # pybullet: physics steps per control period
    max_step_m: float = 0.05  # largest end-effector displacement accepted per control period
    joint_margin_rad: float = 0.02  # commands must stay this far inside the URDF joint limits
    velocity_scale: float = 0.5  # fraction of the URDF joint velocity limits the IK may use
    watchdog_timeout_s: float = 0.5
    target_motion: str = "slow"  # pybullet: static | slow | fast
    seed: int = 0
    home_q: tuple[float, ...] = HOME_Q
    workspace: WorkspaceBox = field(default_factory=WorkspaceBox)
    ik: IKConfig = field(default_factory=IKConfig)
    franka: FrankaConfig = field(default_factory=FrankaConfig)

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {self.backend!r}")
        if not 1.0 <= self.control_rate_hz <= 1000.0:
            raise ValueError(f"control_rate_hz must be in [1, 1000], got {self.control_rate_hz}")
        if self.physics_substeps < 1:
            raise ValueError(f"physics_substeps must be >= 1, got {self.physics_substeps}")
        if not 0 < self.max_step_m <= 0.05:
            raise ValueError(
                f"max_step_m must be in (0, 0.05] (the 5 cm per step bound), got {self.max_step_m}"
            )
        if not 0 <= self.joint_margin_rad < 0.3:
            raise ValueError(f"joint_margin_rad must be in [0, 0.3), got {self.joint_margin_rad}")
        if not 0 < self.velocity_scale <= 1:
            raise ValueError(f"velocity_scale must be in (0, 1], got {self.velocity_scale}")
        if self.watchdog_timeout_s <= 0:
            raise ValueError(f"watchdog_timeout_s must be > 0, got {self.watchdog_timeout_s}")
        TargetMotion.preset(self.target_motion)  # raises with the list of presets
        object.__setattr__(self, "home_q", _vec("home_q", self.home_q, 7))
        for name, cls in (("workspace", WorkspaceBox), ("ik", IKConfig), ("franka", FrankaConfig)):
            if not isinstance(getattr(self, name), cls):
                raise ValueError(f"{name} must be a mapping of {cls.__name__} fields")

    @property
    def period(self) -> float:
        return 1.0 / self.control_rate_hz
