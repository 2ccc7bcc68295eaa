"""How far a plan's prediction may miss before the plan counts as stale: a fixed kernel, that kernel
widened by the measured noise, or a tolerance learned from how far predictions normally miss.

The plan retreat's kernel term ``k(ŝ_i, s_i)`` compares the state a plan predicted ``i`` steps ahead with
the state reached (both normalised). :class:`FixedTolerance` is the policy's kernel with its widths scaled
by ``plan_kernel_scale`` on its narrowest dimensions (:func:`narrowest_scale`). Alone it is wrong wherever
the sensor is noisier than the kernel is narrow: it fires on noise.

:class:`NoiseFloorTolerance` keeps the fixed kernel as the task's tolerance and widens it by the
sensor's noise, measured where a plan can tell it from the model's error: along one plan the gap
``e_i = s_i − ŝ_i`` of a noisy sensor is ``n_i − n_0`` (the noise now minus the noise the plan started
from), whose increments ``d_i = e_i − e_{i−1}`` are negatively correlated, ``E[d_i d_{i+1}] = −σ²``, while
a model's error accumulates smoothly (increments positively correlated or constant). So per dimension

    σ̂² = max(0, −mean(d_i d_{i+1})),   k(ŝ_i, s_i) = exp(−½ Σ_d (s_d − ŝ_d)² / (w_d² + 2κ² σ̂²_d)),

with ``w`` the fixed kernel's widths and ``κ`` as below (``2σ²``: the gap's variance under noise alone). A
quiet sensor leaves the fixed kernel; a noisy one retreats on at most about ``α`` of ticks whose gap is
noise; a model that errs the same way every time still makes the plan stale as its error accumulates
(so the gap one step into a plan, which holds a step of that error, is not the floor: docs/learner_plans.md).

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


def narrowest_scale(bandwidth: np.ndarray, scale: float | list[float]) -> np.ndarray:
    """Per-dimension factors of the plan kernel: a list as given; one factor on the dimensions where the
    policy's kernel is narrowest (the coordinates a task turns on; NS Reach: the target relative to the
    end effector, 0.3 against 5 on the absolute 12), 1 elsewhere; every dimension when it has one width."""
    bandwidth = np.asarray(bandwidth, float)
    if np.ndim(scale) > 0:
        return np.broadcast_to(np.asarray(scale, float), bandwidth.shape).copy()
    return np.where(bandwidth == bandwidth.min(), float(scale), 1.0)


def kappa2(dim: int, threshold: float, false_alarm: float) -> float:
    """``κ² = χ²_{D, 1−α} / (2 ln(1/τ))``: Gaussian gaps of unit spread put the kernel term below ``τ`` on
    a fraction ``α`` of ticks."""
    if not 0.0 < false_alarm < 0.5:
        raise ValueError(f"plan_false_alarm must be in (0, 0.5), got {false_alarm}")
    if not 0.0 < threshold < 1.0:
        raise ValueError(f"a noise-aware plan tolerance needs a retreat threshold in (0, 1), got {threshold}")
    return float(chi2.ppf(1.0 - false_alarm, dim) / (2.0 * math.log(1.0 / threshold)))


def plan_gap(dim: int, predicted: np.ndarray, reached: np.ndarray) -> np.ndarray:
    """``s − ŝ`` per dimension; a clear error for a wrong shape or a non-finite value."""
    p, r = np.asarray(predicted, float), np.asarray(reached, float)
    if p.shape != (dim,) or r.shape != (dim,) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(r))):
        raise ValueError(
            f"plan tolerance: predicted and reached must be {dim} finite values, got {p} and {r}"
        )
    return r - p


class NoiseFloorTolerance:
    """The fixed kernel widened by the sensor noise measured along plans (see the module docstring)."""

    def __init__(
        self,
        widths: np.ndarray,
        threshold: float,
        false_alarm: float = 0.01,
        memory: int = 2000,
        min_samples: int = 50,
        floor: float = 1e-3,
        clip_quantile: float = 0.99,
    ) -> None:
        self.widths2 = np.asarray(widths, float) ** 2
        self.floor2 = floor**2
        self.dim, self.memory, self.min_samples = len(self.widths2), memory, min_samples
        self.kappa2 = kappa2(self.dim, threshold, false_alarm)
        # An increment is clipped at this many mean squares: its own 99 % quantile, whatever the false-alarm
        # rate (clipping at a looser α's quantile would shrink the noise estimate itself).
        self.clip = chi2.ppf(clip_quantile, 1)
        self.lag_product = np.zeros(self.dim)  # running mean of d_i d_{i+1}
        self.increment2 = np.zeros(self.dim)  # running mean square of d_i (for the clip)
        self.count = 0
        self._last: tuple[int, np.ndarray, np.ndarray | None] | None = None  # (ahead, gap, increment)

    def noise2(self) -> np.ndarray | None:
        """``σ̂²`` per dimension; None until ``min_samples`` pairs of increments were seen."""
        return np.maximum(-self.lag_product, 0.0) if self.count >= self.min_samples else None

    def width2(self) -> np.ndarray:
        noise2 = self.noise2()
        return self.widths2 if noise2 is None else self.widths2 + 2.0 * self.kappa2 * noise2

    def value(self, ahead: int, predicted: np.ndarray, reached: np.ndarray) -> float:
        gap = plan_gap(self.dim, predicted, reached)
        return float(np.exp(-0.5 * np.sum(gap * gap / self.width2())))

    def observe(self, ahead: int, predicted: np.ndarray, reached: np.ndarray) -> None:
        """Learn from this tick's gap if the tick before it was the same plan's previous one."""
        gap = plan_gap(self.dim, predicted, reached)  # the error for a bad state, before anything is kept
        last, self._last = self._last, (ahead, gap, None)
        if last is None or ahead != last[0] + 1:
            return  # a new plan (or a skipped tick): the chain of increments starts again
        increment = gap - last[1]
        if self.count:  # one jump of the world must not read as noise
            bound = np.sqrt(self.clip * np.maximum(self.increment2, self.floor2))
            increment = np.clip(increment, -bound, bound)
        self._last = (ahead, gap, increment)
        if last[2] is None:
            return
        self.count += 1
        w = max(1.0 / self.count, 1.0 / self.memory)
        self.lag_product += w * (increment * last[2] - self.lag_product)
        self.increment2 += w * (increment * increment - self.increment2)

    def state_dict(self) -> dict:
        return {
            "lag_product": self.lag_product.copy(),
            "increment2": self.increment2.copy(),
            "count": self.count,
        }

    def load_state_dict(self, state: dict) -> None:
        self.lag_product, self.increment2 = np.array(state["lag_product"]), np.array(state["increment2"])
        self.count = int(state["count"])


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
        if horizon < 1 or dim < 1:
            raise ValueError(f"horizon and dim must be >= 1, got {horizon} and {dim}")
        self.dim, self.horizon, self.memory, self.min_samples = dim, horizon, memory, min_samples
        self.floor2 = floor**2
        self.kappa2 = kappa2(dim, threshold, false_alarm)
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

    def value(self, ahead: int, predicted: np.ndarray, reached: np.ndarray) -> float:
        gap2 = plan_gap(self.dim, predicted, reached) ** 2
        s2 = self.spread2(ahead)
        if s2 is None:
            return 1.0
        return float(np.exp(-0.5 * np.sum(gap2 / (self.kappa2 * s2))))

    def observe(self, ahead: int, predicted: np.ndarray, reached: np.ndarray) -> None:
        """Learn this step's gap (clipped at the spread's ``1 − α`` quantile once a spread is known)."""
        gap2 = plan_gap(self.dim, predicted, reached) ** 2
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
