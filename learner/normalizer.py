"""Per-dimension state normalisation from each environment's declared bounds.

The kernel bandwidth is set on normalised states, so one bandwidth serves every environment.
Environments declare ``obs_bounds = (low, high)`` (typical ranges, not hard limits) because their
observation spaces are often unbounded.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np


class StateNormalizer:
    def __init__(self, low: np.ndarray, high: np.ndarray):
        low, high = np.asarray(low, float), np.asarray(high, float)
        if low.shape != high.shape or np.any(high <= low) or not np.all(np.isfinite(low + high)):
            raise ValueError(f"state bounds must be finite with high > low, got {low}, {high}")
        self.centre = (high + low) / 2.0
        self.scale = (high - low) / 2.0

    @classmethod
    def for_env(cls, env: gym.Env) -> StateNormalizer:
        bounds = getattr(env.unwrapped, "obs_bounds", None)
        if bounds is None:
            space = env.observation_space
            if not (np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))):
                raise ValueError(
                    f"{env.spec.id if env.spec else env}: observation space is unbounded and the env "
                    "declares no obs_bounds; the RKHS learner needs them to normalise states"
                )
            bounds = (space.low, space.high)
        return cls(*bounds)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return (np.asarray(obs, float) - self.centre) / self.scale
