"""The strategic-retreat check: is the newest policy gradient still an ascent direction?

Theorem 1 of the paper: while ``‖∇_h J‖²_H ≥ ε`` (h is not yet ε-optimal) and the kernel is narrow
enough, ``⟨∇J|_{s0}, ∇J|_{s'}⟩_H ≥ Z ε / 2`` with ``Z = sqrt(2π det Σ_H)``. A segment whose gradients
break that bound has left the regime where the start-of-segment policy's ascent direction holds, so
the agent retreats: drops the rest of its queued actions and updates.

The theorem speaks of the *expected* gradient ``D(s)ρ(s)``, not of one sample. Taken literally on
per-sample gradients ``k(s0,si) g0ᵀgi`` (mode ``literal``) the test reads the sign of exploration
noise: on a prototype it fired every 2-3 steps whatever the world did. Mode ``cosine`` (default)
follows the theorem more closely:
- it replaces each per-sample gradient by the mean of ``window`` consecutive gradient functions, a
  Monte-Carlo estimate of the expected gradient around those states;
- it takes the tightest ε the theorem allows, ``ε = ‖∇J‖²_H``, estimated by ``‖Ḡ_0‖ ‖Ḡ_i‖``, so the
  bound ``⟨Ḡ_0, Ḡ_i⟩ ≥ (Z/2) ε`` becomes ``cos_H(Ḡ_0, Ḡ_i) ≥ Z/2``: scale-free, so it does not
  drift with the size of TD errors. The default threshold is ``min(Z/2, 0.5)``.
All inner products are exact: ``⟨Σ_a k(s_a,·)g_a, Σ_b k(s_b,·)g_b⟩_H = Σ_ab k(s_a,s_b) g_aᵀg_b``.
"""

from __future__ import annotations

import numpy as np

from learner.kernels import GaussianKernel

MODES = ("cosine", "literal", "off")


def rkhs_inner(
    kernel: GaussianKernel, sa: np.ndarray, ga: np.ndarray, sb: np.ndarray, gb: np.ndarray
) -> float:
    """``⟨Σ_a k(s_a,·)g_a, Σ_b k(s_b,·)g_b⟩_H`` in closed form."""
    return float(np.sum(kernel(sa, sb) * (ga @ gb.T)))


def default_threshold(mode: str, kernel: GaussianKernel, epsilon: float) -> float:
    z = kernel.normaliser_z
    if mode == "literal":
        return z * epsilon / 2.0
    return min(z / 2.0, 0.5)


class RetreatCheck:
    """Feed it each step's (state, gradient); it says whether the segment should end in a retreat."""

    def __init__(self, kernel: GaussianKernel, mode: str, threshold: float, window: int):
        if mode not in MODES:
            raise ValueError(f"retreat mode must be one of {MODES}, got {mode!r}")
        self.kernel, self.mode, self.threshold, self.window = kernel, mode, threshold, window
        self.states: list[np.ndarray] = []
        self.grads: list[np.ndarray] = []
        self.trace: list[float] = []

    def reset(self) -> None:
        self.states, self.grads, self.trace = [], [], []

    def push(self, s: np.ndarray, g: np.ndarray) -> bool:
        """Record a step; True when the retreat condition fails (statistic below threshold)."""
        self.states.append(s)
        self.grads.append(g)
        if self.mode == "off":
            return False
        stat = self._statistic()
        if stat is None:
            return False
        self.trace.append(stat)
        return stat < self.threshold

    def _statistic(self) -> float | None:
        n = len(self.states)
        if self.mode == "literal":
            if n < 2:
                return None
            return self.kernel.pair(self.states[0], self.states[-1]) * float(self.grads[0] @ self.grads[-1])
        w = self.window
        if n < 2 * w:
            return None
        s0, g0 = np.array(self.states[:w]), np.array(self.grads[:w])
        si, gi = np.array(self.states[-w:]), np.array(self.grads[-w:])
        cross = rkhs_inner(self.kernel, s0, g0, si, gi)
        norm0 = rkhs_inner(self.kernel, s0, g0, s0, g0)
        normi = rkhs_inner(self.kernel, si, gi, si, gi)
        denom = np.sqrt(norm0 * normi)
        return float(cross / denom) if denom > 1e-300 else 1.0
