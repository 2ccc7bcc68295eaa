"""The RKHS Gaussian policy ``π(a|s) = N(μ(s), Σ)`` with its mean bounded inside the action box.

``μ(s) = c + r ⊙ tanh(f(s))`` where ``f ∈ H`` is the RKHS function of the paper's ``h`` and ``c, r`` are
the box's centre and half-range. The squash keeps the mean inside the box: a mean that drifts
outside makes every clipped action the same and nothing pulls it back. Weight decay on ``f`` relaxes
saturated regions back toward the centre.
Actions are clipped to the box for execution only; likelihood and gradient use the unclipped sample.
"""

from __future__ import annotations

import numpy as np

from learner.dictionary import RKHSFunction
from learner.kernels import GaussianKernel


class RKHSGaussianPolicy:
    def __init__(
        self,
        kernel: GaussianKernel,
        low: np.ndarray,
        high: np.ndarray,
        sigma: np.ndarray,
        budget: int,
        ald_threshold: float,
    ):
        self.low = np.asarray(low, dtype=float)
        self.high = np.asarray(high, dtype=float)
        self.centre = (self.high + self.low) / 2.0
        self.half_range = (self.high - self.low) / 2.0
        self.sigma = np.broadcast_to(np.asarray(sigma, float), self.low.shape).copy()
        self.sigma_inv2 = 1.0 / self.sigma**2
        self.f = RKHSFunction(kernel, len(self.low), budget, ald_threshold)

    def explore(self, sigma: np.ndarray | float) -> None:
        """Sample with std ``sigma`` from now on. The score keeps the initial ``Σ⁻¹``: for an action drawn
        at std σ it is the true score times σ²/σ₀², the step shrinking with the std as the natural
        gradient's does (the Fisher information of the mean is Σ⁻¹)."""
        self.sigma = np.broadcast_to(np.asarray(sigma, float), self.low.shape).copy()

    def mean(self, s: np.ndarray) -> np.ndarray:
        return self.centre + self.half_range * np.tanh(self.f(s))

    def sample(self, s: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """(executed action clipped to the box, unclipped sample used by the gradient)."""
        action, raw, _ = self.draw(s, rng)
        return action, raw

    def draw(self, s: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`sample` and the exploration noise it added to the mean (``raw - μ(s)``)."""
        noise = self.sigma * rng.standard_normal(self.low.shape)
        raw = self.mean(s) + noise
        return np.clip(raw, self.low, self.high), raw, noise

    def noise_log_prob_and_score(self, noise: np.ndarray) -> tuple[float, np.ndarray]:
        """(log-likelihood, score) of a sample whose deviation from the mean that drew it was ``noise``: the
        score of the policy that acted, whatever this policy's mean has become since (an actor's lag)."""
        return self._log_density(noise), self._score(noise)

    def score(self, s: np.ndarray, raw_action: np.ndarray) -> np.ndarray:
        """The paper's ``Σ⁻¹(a - h(s))`` in f's units: ``r ⊙ Σ⁻¹(a - μ(s))``.

        The exact derivative through the squash carries ``1 - tanh²(f)``, which vanishes where the
        mean saturates, and the policy then sits at a box edge with a zero gradient for whole episodes.
        This straight-through form keeps the sign and scale of the paper's gradient, and weight decay
        pulls saturated regions back.
        """
        return self._score(raw_action - self.mean(s))

    def log_prob_and_score(self, s: np.ndarray, raw_action: np.ndarray) -> tuple[float, np.ndarray]:
        """(:meth:`log_prob`, :meth:`score`) from one evaluation of the mean."""
        deviation = raw_action - self.mean(s)
        return self._log_density(deviation), self._score(deviation)

    def _score(self, deviation: np.ndarray) -> np.ndarray:
        return self.half_range * self.sigma_inv2 * deviation

    def _log_density(self, deviation: np.ndarray) -> float:
        z = deviation / self.sigma
        return float(-0.5 * z @ z - np.log(self.sigma).sum() - 0.5 * len(z) * np.log(2 * np.pi))

    def bound_gradient(self, s: np.ndarray, g: np.ndarray, limit: float | None) -> np.ndarray:
        """``g`` without the components that would push ``|f(s)|`` further past ``limit``.

        The straight-through score keeps pushing ``f`` where the mean already sits at the box edge, and
        nothing but weight decay pulls it back, until the mean is a frozen bang-bang map that one sample
        cannot move (NS Pendulum: docs/learner.md). Dropping the outward component past ``limit``
        (``tanh(3) = 0.995``) projects the step onto ``|f(s)| ≤ limit`` at the sample's state; ``None``
        keeps the unbounded straight-through step.
        """
        if limit is None:
            return g
        f = self.f(s)
        outward = (np.abs(f) >= limit) & (np.sign(g) == np.sign(f))
        return np.where(outward, 0.0, g) if outward.any() else g

    def log_prob(self, s: np.ndarray, raw_action: np.ndarray) -> float:
        return self._log_density(raw_action - self.mean(s))

    def update(
        self,
        states: list[np.ndarray],
        grads: list[np.ndarray],
        step: float,
        decay: float,
        limit: float | None = None,
    ) -> None:
        """``f ← (1 - step·decay) f + step Σ_t k(s_t,·) g_t`` then sparsify (inside ``RKHSFunction.add``).

        ``limit``: each term is bounded against ``f`` as the terms before it left it
        (:meth:`bound_gradient`), so a segment cannot wind ``f`` up either.
        """
        if decay > 0.0:
            self.f.scale(max(1.0 - step * decay * len(states), 0.0))
        for s, g in zip(states, grads, strict=True):
            self.f.add(s, step * self.bound_gradient(s, g, limit))
