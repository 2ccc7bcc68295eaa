"""How far a plan's prediction may miss before the plan counts as stale: a fixed kernel, or one learned
from how far predictions normally miss (issue #33).

The plan retreat's kernel term ``k(ŝ_i, s_i)`` compares the state a plan predicted ``i`` steps ahead with
the state reached (both normalised). :class:`FixedTolerance` is the policy's kernel with its widths scaled
by a per-task constant (``plan_kernel_scale``). A constant is wrong wherever the sensor's noise or the
model's error is not what it was tuned for: below the noise it fires on noise, above the task's
tolerance it misses a changed world.

:class:`LearnedTolerance` standardises the gap by its own history instead. Per plan step ``i`` and state
dimension ``d`` it keeps a running mean square ``σ̂²_{i,d}`` of the gap ``s − ŝ``, and

    k(ŝ_i, s_i) = exp(−½ Σ_d (s_d − ŝ_d)² / (κ² σ̂²_{i,d})),   κ² = χ²_{D, 1−α} / (2 ln(1/τ)),

so that for gaps of the usual spread (Gaussian, independent across dimensions) the kernel term alone falls
below the retreat threshold ``τ`` on a fraction ``α`` of ticks (``false_alarm``). The gradient agreement
that multiplies it in the statistic only lowers it further. A plan step with fewer than ``min_samples``
gaps borrows the spread of the nearest shorter step that has them, grown as a random walk's
(``σ̂²_j · i / j``); with none yet the term is 1 (the statistic is the gradient agreement alone). Each gap
updates the estimate clipped per dimension at its own ``1 − α`` quantile, so a changed world, which
the retreat is there to catch, does not teach the tolerance to ignore it.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from scipy.stats import chi2

from learner.kernels import GaussianKernel


class PlanTolerance(Protocol):
    """The plan retreat's kernel term between a predicted and a reached (normalised) state."""

    def value(self, ahead: int, predicted: np.ndarray, reached: np.ndarray) -> float: ...

    def observe(self, ahead: int, predicted: np.ndarray, reached: np.ndarray) -> None: ...


class FixedTolerance:
    """A Gaussian kernel of fixed widths (the policy's, scaled by ``plan_kernel_scale``)."""

    def __init__(self, kernel: GaussianKernel) -> None:
        self.kernel = kernel

    def value(self, ahead: int, predicted: np.ndarray, reached: np.ndarray) -> float:
        return self.kernel.pair(predicted, reached)

    def observe(self, ahead: int, predicted: np.ndarray, reached: np.ndarray) -> None:
        """Nothing to learn."""


class LearnedTolerance:
    """The gap standardised by its running mean square per plan step (see the module docstring)."""

    def __init__(
        self,
        dim: int,
        horizon: int,
        threshold: float,
        false_alarm: float = 0.01,
        memory: int = 2000,
        min_samples: int = 20,
        floor: float = 1e-3,
    ) -> None:
        if not 0.0 < false_alarm < 0.5:
            raise ValueError(f"plan_false_alarm must be in (0, 0.5), got {false_alarm}")
        if not 0.0 < threshold < 1.0:
            raise ValueError(f"a learned plan tolerance needs a retreat threshold in (0, 1), got {threshold}")
        if horizon < 1 or dim < 1:
            raise ValueError(f"horizon and dim must be >= 1, got {horizon} and {dim}")
        self.dim, self.horizon, self.memory, self.min_samples = dim, horizon, memory, min_samples
        self.floor2 = floor**2
        self.kappa2 = chi2.ppf(1.0 - false_alarm, dim) / (2.0 * math.log(1.0 / threshold))
        self.clip = chi2.ppf(1.0 - false_alarm, 1)  # per dimension, in units of its spread
        self.mean_square = np.zeros((horizon + 1, dim))
        self.count = np.zeros(horizon + 1, dtype=int)

    def spread2(self, ahead: int) -> np.ndarray | None:
        """``σ̂²`` per dimension ``ahead`` steps into a plan; None while no step has enough samples."""
        i = min(max(ahead, 1), self.horizon)
        j = i
        while j > 0 and self.count[j] < self.min_samples:
            j -= 1
        if j == 0:
            return None
        return np.maximum(self.mean_square[j] * (i / j), self.floor2)

    def _gap2(self, predicted: np.ndarray, reached: np.ndarray) -> np.ndarray:
        gap = np.asarray(reached, float) - np.asarray(predicted, float)
        if gap.shape != (self.dim,) or not np.all(np.isfinite(gap)):
            raise ValueError(
                f"plan tolerance: predicted and reached must be {self.dim} finite values, got {gap}"
            )
        return gap * gap

    def value(self, ahead: int, predicted: np.ndarray, reached: np.ndarray) -> float:
        gap2 = self._gap2(predicted, reached)
        s2 = self.spread2(ahead)
        if s2 is None:
            return 1.0
        return float(np.exp(-0.5 * np.sum(gap2 / (self.kappa2 * s2))))

    def observe(self, ahead: int, predicted: np.ndarray, reached: np.ndarray) -> None:
        """Learn this step's gap (clipped at the spread's ``1 − α`` quantile once a spread is known)."""
        gap2 = self._gap2(predicted, reached)
        s2 = self.spread2(ahead)
        if s2 is not None:
            gap2 = np.minimum(gap2, self.clip * s2)
        i = min(max(ahead, 1), self.horizon)
        self.count[i] += 1
        w = max(1.0 / self.count[i], 1.0 / self.memory)
        self.mean_square[i] += w * (gap2 - self.mean_square[i])

    def state_dict(self) -> dict:
        return {"mean_square": self.mean_square.copy(), "count": self.count.copy()}

    def load_state_dict(self, state: dict) -> None:
        self.mean_square, self.count = np.array(state["mean_square"]), np.array(state["count"])
