"""What a checkpoint was trained on, and whether a policy may be handed from one run to another.

A handoff (``learner.policy_from``) starts a learner from a policy another run trained: in-process on
the PyBullet mock, or another stack run. The policy is a function of the normalised observation and
acts in the arm's Cartesian frame, so it is only meaningful on the same task, the same observation
layout (names and normalisation bounds), the same action bounds, and an arm whose tool centre point is
the same point in the same kinematic family (the Panda's and the FR3's TCPs are 1.6 mm apart). A
mismatch is refused with ``HandoffMismatch`` naming the field, never reshaped.
"""

from __future__ import annotations

import functools
import subprocess
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from common.errors import AdaptiveHError

TCP_TOLERANCE_M = 0.005  # two arms whose tool centre points differ by more act on other points
BOUND_TOLERANCE = 1e-6


class HandoffMismatch(AdaptiveHError):
    """A checkpoint trained on something else than this learner's task; ``field`` names what differs."""

    def __init__(self, field_name: str, recorded: Any, here: Any, source: str = "") -> None:
        self.field = field_name
        where = f"{source}: " if source else ""
        super().__init__(
            f"{where}policy handoff refused: {field_name} differs (checkpoint: {recorded!r}; this run: "
            f"{here!r})"
        )


@dataclass(frozen=True)
class ArmRecord:
    """The arm a Cartesian policy acted through: its model, kinematic family and TCP beyond the flange."""

    model: str
    family: str
    tcp_offset_m: float


@dataclass(frozen=True)
class TrainedOn:
    """A checkpoint's record of what its policy was trained on (``trained_on`` in the checkpoint)."""

    task: str
    observation: tuple[str, ...]
    observation_low: tuple[float, ...]  # the normalisation bounds the policy's kernel saw
    observation_high: tuple[float, ...]
    action_low: tuple[float, ...]
    action_high: tuple[float, ...]
    arm: ArmRecord | None = None
    commit: str = field(default="", compare=False)
    source: str = field(default="", compare=False)  # how it was trained: in-process env id, or the stack

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainedOn:
        arm = data.get("arm")
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items() if k != "arm"}
        return cls(**values, arm=ArmRecord(**arm) if arm else None)


def trained_on(env: gym.Env, normalize_bounds: tuple[np.ndarray, np.ndarray]) -> TrainedOn:
    """The record of ``env`` as a learner with normalisation ``normalize_bounds`` sees it: the env's own
    (``task_record``, the reach envs) or, for any other env, its id and generic observation names."""
    own = getattr(env.unwrapped, "task_record", None)
    low, high = (tuple(float(x) for x in np.asarray(b, float)) for b in normalize_bounds)
    space = env.action_space
    common = {
        "observation_low": low,
        "observation_high": high,
        "action_low": tuple(float(x) for x in np.asarray(space.low, float).ravel()),
        "action_high": tuple(float(x) for x in np.asarray(space.high, float).ravel()),
        "commit": commit(),
    }
    if own is not None:
        task, names, arm, source = own()
        return TrainedOn(task=task, observation=tuple(names), arm=arm, source=source, **common)
    env_id = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
    names = tuple(f"s{i}" for i in range(len(low)))
    return TrainedOn(task=env_id, observation=names, source=env_id, **common)


def check_handoff(recorded: TrainedOn, here: TrainedOn, source: str = "") -> None:
    """Raise ``HandoffMismatch`` naming the first field in which ``recorded`` cannot serve ``here``."""
    for name in ("task", "observation"):
        if getattr(recorded, name) != getattr(here, name):
            raise HandoffMismatch(name, getattr(recorded, name), getattr(here, name), source)
    for name in ("observation_low", "observation_high", "action_low", "action_high"):
        a, b = np.asarray(getattr(recorded, name)), np.asarray(getattr(here, name))
        if a.shape != b.shape or not np.allclose(a, b, rtol=0, atol=BOUND_TOLERANCE):
            raise HandoffMismatch(name, getattr(recorded, name), getattr(here, name), source)
    _check_arm(recorded.arm, here.arm, source)


def _check_arm(recorded: ArmRecord | None, here: ArmRecord | None, source: str) -> None:
    if (recorded is None) != (here is None):
        raise HandoffMismatch("arm", recorded, here, source)
    if recorded is None or here is None:
        return
    if recorded.family != here.family:
        raise HandoffMismatch("arm.family", recorded.family, here.family, source)
    if abs(recorded.tcp_offset_m - here.tcp_offset_m) > TCP_TOLERANCE_M:
        raise HandoffMismatch("arm.tcp_offset_m", recorded.tcp_offset_m, here.tcp_offset_m, source)


def checkpoint_path(path: str | Path) -> Path:
    """``path`` itself, or the ``checkpoint.pkl`` in the run folder it names."""
    path = Path(path)
    return path / "checkpoint.pkl" if path.is_dir() else path


@functools.cache
def commit() -> str:
    """This code's git commit (``-dirty`` when the tree has changes), or "" outside a git checkout."""
    try:
        head = _git("rev-parse", "--short=12", "HEAD")
        dirty = _git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return ""
    return head + ("-dirty" if dirty else "")


def _git(*args: str) -> str:
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run(
        ["git", "-C", str(root), *args], capture_output=True, text=True, timeout=5, check=True
    )
    return done.stdout.strip()
