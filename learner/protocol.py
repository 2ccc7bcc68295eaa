"""The one agent protocol that AdaptiveH, the fixed-H RKHS learner and the TD3/DDPG adapters honour.

Like stable-baselines3: an agent is built around a gymnasium env and ``learn(total_steps)`` drives it.
Every agent records the same ``RunLog`` so that benchmarks, the CLI and the deployed learner node
treat them alike.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np


@dataclass
class EpisodeRecord:
    """One finished episode: its return, length, the global step at its end, and env info."""

    episode: int
    global_step: int
    ret: float
    length: int
    success: bool | None = None
    info: dict[str, float] = field(default_factory=dict)
    arm: str = ""  # the arm of a fleet that played it ("": the only one)


@dataclass
class SegmentRecord:
    """One action segment of an RKHS learner: its length H and why it ended."""

    index: int
    global_step: int
    H: int
    reason: str  # retreat | h_max | episode_end
    statistic: list[float] = field(default_factory=list)
    threshold: float = 0.0
    arm: str = ""  # the arm of a fleet that played it ("": the only one)


@dataclass
class RunLog:
    """What every agent's ``learn`` accumulates."""

    episodes: list[EpisodeRecord] = field(default_factory=list)
    segments: list[SegmentRecord] = field(default_factory=list)
    global_step: int = 0
    # Records moved out of memory before ``segments[0]`` / ``episodes[0]`` (learner.run_archive, for
    # runs of days).
    segments_before: int = 0
    episodes_before: int = 0

    def before(self, kind: str) -> int:
        """Records of ``kind`` ("segments" or "episodes") no longer in memory (on file)."""
        return int(getattr(self, f"{kind}_before"))

    def count(self, kind: str) -> int:
        """Every record of ``kind`` in the run, in memory or not: the next one's number."""
        return self.before(kind) + len(getattr(self, kind))

    def forget(self, kind: str, n: int) -> None:
        """Drop the oldest ``n`` in-memory records of ``kind`` (kept on file); numbering goes on."""
        del getattr(self, kind)[:n]
        setattr(self, f"{kind}_before", self.before(kind) + n)

    def since(self, kind: str, count: int) -> list[Any]:
        """The records of ``kind`` made after the first ``count`` of the run (those still in memory)."""
        newer = self.count(kind) - count
        return getattr(self, kind)[-newer:] if newer > 0 else []

    @property
    def segment_count(self) -> int:
        return self.count("segments")

    @property
    def episode_count(self) -> int:
        return self.count("episodes")

    def segments_since(self, count: int) -> list[SegmentRecord]:
        return self.since("segments", count)

    def to_dict(self) -> dict[str, Any]:
        return {
            "global_step": self.global_step,
            "episodes": [asdict(e) for e in self.episodes],
            "segments": [asdict(s) for s in self.segments],
            "segments_before": self.segments_before,
            "episodes_before": self.episodes_before,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunLog:
        return cls(
            episodes=[EpisodeRecord(**e) for e in data.get("episodes", [])],
            segments=[SegmentRecord(**s) for s in data.get("segments", [])],
            global_step=int(data.get("global_step", 0)),
            segments_before=int(data.get("segments_before", 0)),
            episodes_before=int(data.get("episodes_before", 0)),
        )


# Called after every environment step with (global_step, run_log); returning False stops learning.
StepCallback = Callable[[int, RunLog], bool | None]


@runtime_checkable
class Agent(Protocol):
    """What every learner offers."""

    name: str
    log: RunLog

    def learn(self, total_steps: int, callback: StepCallback | None = None) -> RunLog:
        """Interact with the env for ``total_steps`` more steps, learning as it goes."""
        ...

    def predict(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """The action the current policy takes at ``obs``."""
        ...

    def save(self, path: str | Path) -> None:
        """Write the agent's full state (policy, critic, RNG, log) to one file."""
        ...

    def load(self, path: str | Path) -> None:
        """Restore the state written by ``save``; learning continues as if never interrupted."""
        ...
