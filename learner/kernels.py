"""The Gaussian kernel of the paper (eq. rbf), on normalised states, with per-dimension bandwidths."""

from __future__ import annotations

import numpy as np


class GaussianKernel:
    """``k(s, s') = exp(-(s-s')^T Σ_H^{-1} (s-s') / 2)`` with diagonal ``Σ_H = diag(bandwidth²)``.

    Matrix-valued use (``k(s,s') I_d``) needs nothing more: every output dimension shares this scalar.
    """

    def __init__(self, bandwidth: np.ndarray | float, dim: int):
        bw = np.broadcast_to(np.asarray(bandwidth, dtype=float), (dim,)).copy()
        if np.any(bw <= 0) or not np.all(np.isfinite(bw)):
            raise ValueError(f"kernel bandwidth must be positive and finite, got {bw}")
        self.bandwidth = bw
        self.dim = dim
        self._inv = 1.0 / bw

    @property
    def normaliser_z(self) -> float:
        """The paper's ``Z = sqrt(2π det Σ_H)`` (Theorem 1)."""
        return float(np.sqrt(2.0 * np.pi * np.prod(self.bandwidth**2)))

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Gram block ``K[i, j] = k(x_i, y_j)`` for ``x`` (n, dim) and ``y`` (m, dim)."""
        xs = np.atleast_2d(x) * self._inv
        ys = np.atleast_2d(y) * self._inv
        sq = (xs * xs).sum(1)[:, None] + (ys * ys).sum(1)[None, :] - 2.0 * xs @ ys.T
        return np.exp(-0.5 * np.maximum(sq, 0.0))

    def vector(self, centers: np.ndarray, s: np.ndarray) -> np.ndarray:
        """``k(c_j, s)`` for every center: shape (M,)."""
        if len(centers) == 0:
            return np.zeros(0)
        d = (centers - s) * self._inv
        return np.exp(-0.5 * np.einsum("ij,ij->i", d, d))

    def pair(self, x: np.ndarray, y: np.ndarray) -> float:
        d = (x - y) * self._inv
        return float(np.exp(-0.5 * d @ d))
