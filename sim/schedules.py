"""Bounded drift signals on a global step clock: the hidden non-stationarity of every environment.

The clock counts environment steps and never resets with episodes; the signal is seeded, so a seed
reproduces the whole run. Value = clip(base + amplitude·sin(2πt/period + phase) + walk + jump, low, high)
where ``walk`` is a reflected Gaussian random walk and ``jump`` a piecewise-constant offset redrawn
every ``jump_every`` steps; ``step_size`` is added once the clock reaches ``step_at`` (one abrupt change,
for measuring how the learner responds to it).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from common.config import Section


class DriftConfig(Section):
    base: float = Field(description="the signal's value before any drift; within [low, high]")
    low: float = Field(description="the signal never goes below this")
    high: float = Field(description="the signal never goes above this")
    amplitude: float = Field(0.0, ge=0, description="amplitude of the sine wave added to base")
    period: int = Field(10_000, ge=1)  # steps
    walk_std: float = Field(
        0.0,
        ge=0,
        description="standard deviation of the reflected random walk's step, per environment step (0: no"
        " walk)",
    )
    jump_every: int = Field(0, ge=0)  # 0: no jumps
    jump_size: float = Field(
        0.0, ge=0, description="each jump offset is drawn uniformly from [-jump_size, jump_size]"
    )
    step_at: int = Field(0, ge=0)  # one abrupt change of ``step_size`` at this step (0: none)
    step_size: float = Field(0.0, description="the abrupt change added once the clock reaches step_at")

    @model_validator(mode="after")
    def _base_in_band(self) -> DriftConfig:
        if not self.low <= self.base <= self.high:
            raise ValueError(f"base {self.base} must lie in [low, high] = [{self.low}, {self.high}]")
        return self


class DriftSchedule:
    def __init__(self, config: DriftConfig, seed: int):
        self.config = config
        self.rng = np.random.default_rng(seed)
        self.phase = float(self.rng.uniform(0.0, 2.0 * np.pi)) if config.amplitude > 0 else 0.0
        self.t = 0
        self.walk = 0.0
        self.jump = 0.0

    @property
    def value(self) -> float:
        c = self.config
        wave = c.amplitude * np.sin(2.0 * np.pi * self.t / c.period + self.phase)
        step = c.step_size if 0 < c.step_at <= self.t else 0.0
        return float(np.clip(c.base + wave + self.walk + self.jump + step, c.low, c.high))

    def advance(self) -> None:
        """One tick of the global clock."""
        c = self.config
        self.t += 1
        if c.walk_std > 0:
            half = (c.high - c.low) / 2.0
            self.walk += float(self.rng.normal(0.0, c.walk_std))
            if abs(self.walk) > half:  # reflect so the walk stays within the band
                self.walk = float(np.sign(self.walk) * (2 * half - abs(self.walk)))
        if c.jump_every and self.t % c.jump_every == 0:
            self.jump = float(self.rng.uniform(-c.jump_size, c.jump_size))

    def get_state(self) -> dict:
        return {
            "rng": self.rng.bit_generator.state,
            "t": self.t,
            "walk": self.walk,
            "jump": self.jump,
            "phase": self.phase,
            "config": self.config.model_dump(),
        }

    def set_state(self, state: dict) -> None:
        self.rng.bit_generator.state = state["rng"]
        self.t, self.walk, self.jump, self.phase = state["t"], state["walk"], state["jump"], state["phase"]
