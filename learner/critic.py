"""Kernel least-squares TD critics: recursive (O(M²) per step), ALD-sparsified, budgeted, forgetting.

The recursion is RLS-TD(0) (Xu, He & Hu 2002) on kernel features ``k(D, s)``: with ``u = φ_t`` and
``v = φ_t - γ φ_{t+1}``, ``θ ← θ + P u (r - vᵀθ) / (β + vᵀ P u)`` and
``P ← (P - P u vᵀ P / (β + vᵀ P u)) / β``. The forgetting factor ``β < 1`` discounts old transitions,
which the drifting world makes wrong. ``P`` is capped at its initial scale so it cannot wind up while a
region goes unvisited.

Two feature maps share the recursion:
- ``value``: ``φ(s) = k(D, s)``, ``V(s) = θᵀφ(s)``; the TD error is the advantage handed to the actor.
- ``compatible``: per center ``[k_j, k_j · score(s,a)]`` (the paper's ``φ(s,a) = k(s,·)Σ⁻¹(a - h(s))``
  plus a value baseline); the advantage is the compatible part. Its features depend on the policy, so
  they go stale after each policy update (measured: unstable learning); kept for the comparison.
"""

from __future__ import annotations

import numpy as np

from learner.dictionary import KernelDictionary
from learner.kernels import GaussianKernel


class KLSTDCritic:
    def __init__(
        self,
        kernel: GaussianKernel,
        gamma: float,
        budget: int,
        ald_threshold: float,
        forgetting: float = 1.0,
        p0: float = 10.0,
        mode: str = "value",
        action_dim: int = 1,
    ):
        if mode not in ("value", "compatible"):
            raise ValueError(f"critic mode must be 'value' or 'compatible', got {mode!r}")
        self.dictionary = KernelDictionary(kernel)
        self.gamma, self.budget, self.ald_threshold = gamma, budget, ald_threshold
        self.forgetting, self.p0, self.mode = forgetting, p0, mode
        self.block = 1 if mode == "value" else 1 + action_dim
        self.theta = np.zeros(0)
        self.P = np.zeros((0, 0))

    def __len__(self) -> int:
        return len(self.dictionary)

    def _phi(self, kvec: np.ndarray, score: np.ndarray | None) -> np.ndarray:
        if self.mode == "value":
            return kvec
        extra = np.zeros(self.block - 1) if score is None else score
        return (kvec[:, None] * np.concatenate([[1.0], extra])[None, :]).ravel()

    def value(self, s: np.ndarray) -> float:
        """The state-value part ``V(s)``."""
        kvec = self.dictionary.features(s)
        return float(self._phi(kvec, None) @ self.theta)

    def advantage(self, s: np.ndarray, score: np.ndarray) -> float:
        """The compatible (advantage) part of ``Q̂(s,a)``; zero for the value critic."""
        if self.mode == "value":
            return 0.0
        kvec = self.dictionary.features(s)
        return float((self._phi(kvec, score) - self._phi(kvec, None)) @ self.theta)

    def update(
        self, s: np.ndarray, r: float, s_next: np.ndarray, terminal: bool, score: np.ndarray | None = None
    ) -> float:
        """Fit one transition; returns the advantage estimate for the actor, computed before the fit.

        ``value``: the TD error ``r + γV(s') - V(s)``. ``compatible``: ``Q̂(s,a) - V(s)``.
        """
        self._maybe_add_center(s)
        u = self._phi(self.dictionary.features(s), score)
        nxt = np.zeros_like(u) if terminal else self._phi(self.dictionary.features(s_next), None)
        v = u - self.gamma * nxt
        td_error = float(r - v @ self.theta)
        advantage = td_error if self.mode == "value" else self.advantage(s, score)
        pu = self.P @ u
        denom = self.forgetting + float(v @ pu)
        if abs(denom) < 1e-9:
            return advantage
        gain = pu / denom
        self.theta = self.theta + gain * td_error
        self.P = (self.P - np.outer(gain, v @ self.P)) / self.forgetting
        peak = float(np.max(np.abs(np.diag(self.P))))
        if peak > self.p0:
            self.P *= self.p0 / peak
        return advantage

    def _maybe_add_center(self, s: np.ndarray) -> None:
        kvec, _, delta = self.dictionary.ald(s)
        if delta <= self.ald_threshold:
            return
        self.dictionary.append(s, kvec)
        b, n = self.block, len(self.theta)
        self.theta = np.concatenate([self.theta, np.zeros(b)])
        grown = np.zeros((n + b, n + b))
        grown[:n, :n] = self.P
        grown[n:, n:] = self.p0 * np.eye(b)
        self.P = grown
        if len(self) > self.budget:
            self._prune()

    def _prune(self) -> None:
        """Drop the center whose value weight loses the least RKHS norm; project it onto the rest."""
        b = self.block
        blocks = self.theta.reshape(-1, b)
        loss = self.dictionary.removal_residuals() * (blocks**2).sum(1)
        j = int(np.argmin(loss))
        k_j = self.dictionary.gram[j].copy()
        keep_c = np.arange(len(self)) != j
        self.dictionary.remove(j)
        coeffs = self.dictionary.solve(k_j[keep_c])
        blocks = blocks[keep_c] + np.outer(coeffs, blocks[j])
        self.theta = blocks.ravel()
        keep = np.repeat(keep_c, b)
        self.P = self.P[np.ix_(keep, keep)]

    def state_dict(self) -> dict:
        return {"dictionary": self.dictionary.state_dict(), "theta": self.theta, "P": self.P}

    def load_state_dict(self, state: dict) -> None:
        self.dictionary.load_state_dict(state["dictionary"])
        self.theta, self.P = state["theta"], state["P"]
