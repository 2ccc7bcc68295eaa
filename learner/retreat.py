"""The strategic-retreat check: is the newest policy gradient still an ascent direction?

Theorem 1 of the paper: while ``‖∇_h J‖²_H ≥ ε`` (h is not yet ε-optimal) and the kernel is narrow
enough, ``⟨∇J|_{s0}, ∇J|_{s'}⟩_H ≥ Z ε / 2`` with ``Z = sqrt(2π det Σ_H)``. A segment whose gradients
break that bound has left the regime where the start-of-segment policy's ascent direction holds, so
the agent retreats: drops the rest of its queued actions and updates.

The theorem speaks of the *expected* gradient ``D(s)ρ(s)``, not of one sample. Taken literally on
per-sample gradients ``k(s0,si) g0ᵀgi`` (mode ``literal``) the test reads the sign of exploration
noise: on a prototype it fired every 2-3 steps whatever the world did, and a cosine of short windowed
means did no better (median H 6-7 at stationary, slow and fast gravity alike). Mode ``smoothed``
(default) follows the theorem more closely:
- the expected gradient field is estimated by ``G ← (1-λ) G + λ k(s_t,·) g_t/‖g_t‖``, an
  exponentially weighted RKHS average of the per-sample gradient directions (``λ`` = ``smoothing``;
  unit directions because TD errors are heavy-tailed), kept sparse under a budget like the
  policy. Exploration noise averages out; a systematic change of the gradient (the world drifted,
  the critic's errors turned) rotates ``G``;
- ``G_0`` is ``G`` when the segment opened, ``G_i`` is ``G`` now. In (39) the bound is
  ``⟨G_0, G_i⟩ ≥ Z ε / 2`` with ``ε ≤ ‖∇J‖²``, while ``⟨G_0, G_0⟩`` itself is ``Z ε`` at the tightest
  ``ε`` (eq. 37 at ``s' = s0``). Dividing both by it removes ``Z`` and the gradient's scale: the
  statistic is the projection ratio ``⟨G_0, G_i⟩_H / ‖G_0‖²_H`` and the retreat fires below ``1/2``.
All inner products are exact: ``⟨Σ_a k(s_a,·)g_a, Σ_b k(s_b,·)g_b⟩_H = Σ_ab k(s_a,s_b) g_aᵀg_b``.
"""

from __future__ import annotations

import numpy as np

from learner.dictionary import RKHSFunction
from learner.kernels import GaussianKernel

MODES = ("smoothed", "literal", "off")


def rkhs_inner(
    kernel: GaussianKernel, sa: np.ndarray, ga: np.ndarray, sb: np.ndarray, gb: np.ndarray
) -> float:
    """``⟨Σ_a k(s_a,·)g_a, Σ_b k(s_b,·)g_b⟩_H`` in closed form."""
    return float(np.sum(kernel(sa, sb) * (ga @ gb.T)))


def default_threshold(mode: str, kernel: GaussianKernel, epsilon: float) -> float:
    if mode == "literal":
        return kernel.normaliser_z * epsilon / 2.0
    return 0.5


class RetreatCheck:
    """Feed it each step's (state, gradient); it says whether the segment should end in a retreat."""

    def __init__(
        self,
        kernel: GaussianKernel,
        mode: str,
        threshold: float,
        smoothing: float = 0.05,
        budget: int = 200,
        ald_threshold: float = 0.05,
    ):
        if mode not in MODES:
            raise ValueError(f"retreat mode must be one of {MODES}, got {mode!r}")
        if not 0.0 < smoothing <= 1.0:
            raise ValueError(f"retreat smoothing must be in (0, 1], got {smoothing}")
        self.kernel, self.mode, self.threshold, self.smoothing = kernel, mode, threshold, smoothing
        self.field = RKHSFunction(kernel, 0, budget, ald_threshold)  # out_dim set on first push
        self._snapshot: tuple[np.ndarray, np.ndarray, float] | None = None
        self.states: list[np.ndarray] = []
        self.grads: list[np.ndarray] = []
        self.trace: list[float] = []

    def reset(self) -> None:
        """Open a new segment: the current gradient field becomes ``G_0``."""
        self.states, self.grads, self.trace = [], [], []
        self._snapshot = None

    def push(self, s: np.ndarray, g: np.ndarray) -> bool:
        """Record a step; True when the retreat condition fails (statistic below threshold)."""
        self.states.append(s)
        self.grads.append(g)
        if self.mode == "off":
            return False
        stat = self._literal() if self.mode == "literal" else self._smoothed(s, g)
        if stat is None:
            return False
        self.trace.append(stat)
        return stat < self.threshold

    def _literal(self) -> float | None:
        if len(self.states) < 2:
            return None
        return self.kernel.pair(self.states[0], self.states[-1]) * float(self.grads[0] @ self.grads[-1])

    def _smoothed(self, s: np.ndarray, g: np.ndarray) -> float | None:
        field = self.field
        if field.weights.shape[1] != len(g):
            field.weights = np.zeros((len(field), len(g)))
        if self._snapshot is None:
            self._snapshot = (field.dictionary.centers.copy(), field.weights.copy(), field.norm2())
        field.scale(1.0 - self.smoothing)
        norm = float(np.linalg.norm(g))
        if norm > 0:  # directions only: heavy-tailed TD errors must not let one sample swing G
            field.add(s, self.smoothing * g / norm)
        centers0, weights0, norm0 = self._snapshot
        if norm0 <= 1e-300 or len(centers0) == 0:
            return None  # no gradient history yet: nothing to compare with
        cross = float(np.sum(self.kernel(centers0, field.dictionary.centers) * (weights0 @ field.weights.T)))
        return cross / norm0

    def state_dict(self) -> dict:
        return {
            "field": self.field.state_dict(),
            "snapshot": self._snapshot,
            "states": self.states,
            "grads": self.grads,
            "trace": self.trace,
        }

    def load_state_dict(self, state: dict) -> None:
        self.field.load_state_dict(state["field"])
        self._snapshot = state["snapshot"]
        self.states, self.grads = list(state["states"]), list(state["grads"])
        self.trace = list(state["trace"])
