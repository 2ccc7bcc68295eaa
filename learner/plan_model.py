"""The plan's world model: the env's nominal one, optionally corrected online by what the world did.

A plan is sampled along the states the model predicts, and the plan retreat judges the gap between those
and the states reached. Where the nominal model errs the same way every time (NS Reach: the arm lags the
commanded step; NS CartPole: gravity has drifted), that error is no news about the world, yet it fills
the gap. :class:`CorrectedModel` learns it: a linear regression, by recursive least squares with
forgetting, of the one-step residual ``s' − f(s, a)`` on ``[s_normalised, a, 1]``, added to ``f``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Model = Callable[[np.ndarray, np.ndarray], np.ndarray]


class NominalModel:
    """The env's own model as it is: nothing to learn."""

    def __init__(self, nominal: Model) -> None:
        self.nominal = nominal

    def __call__(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        return self.nominal(obs, action)

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> None:
        """Nothing to learn."""


class CorrectedModel:
    """``f(s, a) + Wᵀ φ(s, a)``, ``W`` fitted online to the residuals (see the module docstring).

    ``W`` is the ridge solution over the exponentially forgotten steps, solved afresh each step: the
    prior stays as strong as it started, so a direction the data stop exciting falls back to the nominal
    model instead of winding up (recursive least squares with forgetting lets it grow without bound)."""

    def __init__(
        self,
        nominal: Model,
        normalize: Callable[[np.ndarray], np.ndarray],
        obs_dim: int,
        action_dim: int,
        memory: int = 1000,
        prior: float = 1.0,
    ) -> None:
        if memory < 2:
            raise ValueError(f"plan model memory must be >= 2 steps, got {memory}")
        self.nominal, self.normalize = nominal, normalize
        n = obs_dim + action_dim + 1
        self.forget = 1.0 - 1.0 / memory
        self.ridge = prior * np.eye(n)
        self.gram = np.zeros((n, n))  # forgotten sum of φ φᵀ
        self.cross = np.zeros((n, obs_dim))  # forgotten sum of φ rᵀ
        self.W = np.zeros((n, obs_dim))
        self.updates = 0

    def features(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        return np.concatenate([self.normalize(obs), np.asarray(action, float).ravel(), [1.0]])

    def __call__(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        return self.nominal(obs, action) + self.features(obs, action) @ self.W

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> None:
        """One step the world took: ``action`` from ``obs`` led to ``next_obs`` (non-finite: skipped)."""
        phi = self.features(obs, action)
        residual = np.asarray(next_obs, float) - self.nominal(obs, action)
        if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(residual))):
            return
        self.gram = self.forget * self.gram + np.outer(phi, phi)
        self.cross = self.forget * self.cross + np.outer(phi, residual)
        self.W = np.linalg.solve(self.gram + self.ridge, self.cross)
        self.updates += 1


def plan_model(
    kind: str,
    nominal: Model,
    normalize: Callable[[np.ndarray], np.ndarray],
    dims: tuple[int, int],
    memory: int,
) -> NominalModel | CorrectedModel:
    """The plan model ``plan_model`` names: ``nominal`` or ``corrected``; ``dims``: (obs, action)."""
    if kind == "corrected":
        return CorrectedModel(nominal, normalize, *dims, memory=memory)
    return NominalModel(nominal)
