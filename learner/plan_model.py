"""The plan's world model: the env's nominal one, optionally corrected online by what the world did.

A plan is sampled along the states the model predicts, and the plan retreat judges the gap between those
and the states reached. Where the nominal model errs the same way every time (NS Reach: the arm lags the
commanded step; NS CartPole: gravity has drifted), that error is no news about the world, yet it fills
the gap. :class:`CorrectedModel` learns it: a ridge regression over exponentially forgotten steps of
the one-step residual ``s' − f(s, a)`` on ``[s_normalised, a, 1]``, added to ``f`` while it predicts
better. "Better" is a paired one-sided test on each step's prediction made before that step was learned
(prequential): the correction is used while the forgotten mean of ``e_nominal² − e_corrected²``
(normalised units) exceeds ``z`` of its standard errors. Where the nominal model is exact and the sensor
noisy (NS Pendulum), a fit of noise on noisy states predicts no better, and the plans keep the nominal
model (measured: used there, such a fit wrecked a seed; docs/learner_plans.md).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Model = Callable[[np.ndarray, np.ndarray], np.ndarray]


class NominalModel:
    """The env's own model as it is: nothing to learn."""

    updates = 0  # steps learned from (none)

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
        z: float = 2.0,
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
        self.z, self.memory = z, memory
        self.gain_mean = self.gain_square = 0.0  # forgotten means of e_nom² − e_cor² and of its square
        self.active = False  # the correction predicts significantly better: plans use it

    def features(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        return np.concatenate([self.normalize(obs), np.asarray(action, float).ravel(), [1.0]])

    def __call__(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        if not self.active:
            return self.nominal(obs, action)
        return self.nominal(obs, action) + self.features(obs, action) @ self.W

    def observe(self, obs: np.ndarray, action: np.ndarray, next_obs: np.ndarray) -> None:
        """One step the world took: ``action`` from ``obs`` led to ``next_obs`` (non-finite: skipped)."""
        phi = self.features(obs, action)
        predicted = self.nominal(obs, action)
        residual = np.asarray(next_obs, float) - predicted
        if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(residual))):
            return
        self._judge(next_obs, predicted, phi)
        self.gram = self.forget * self.gram + np.outer(phi, phi)
        self.cross = self.forget * self.cross + np.outer(phi, residual)
        self.W = np.linalg.solve(self.gram + self.ridge, self.cross)
        self.updates += 1

    def _judge(self, next_obs: np.ndarray, predicted: np.ndarray, phi: np.ndarray) -> None:
        """Update the paired test with this step's errors (``predicted``: the nominal model's), each from
        the fit before the step."""
        seen = self.normalize(next_obs)
        e_nom = seen - self.normalize(predicted)
        e_cor = seen - self.normalize(predicted + phi @ self.W)
        gain = float(e_nom @ e_nom - e_cor @ e_cor)
        w = max(1.0 / (self.updates + 1), 1.0 / self.memory)
        self.gain_mean += w * (gain - self.gain_mean)
        self.gain_square += w * (gain * gain - self.gain_square)
        n = min(self.updates + 1, self.memory)
        spread = np.sqrt(max(self.gain_square - self.gain_mean**2, 0.0) / n)
        self.active = n > 1 and self.gain_mean > self.z * spread


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
