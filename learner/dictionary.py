"""A kernel dictionary: centers, their Gram matrix and its Cholesky factor, under a size budget.

Approximate linear dependence (ALD, Engel et al.) decides whether a state earns a center: its residual
``δ(s) = k(s,s) - k_sᵀ K⁻¹ k_s`` is the squared RKHS distance of ``k(s,·)`` from the span of the
dictionary. The Cholesky factor grows by a block update on append (O(M²)); a failed update (numerical
loss of definiteness) refactors with a larger jitter. A removal refactors from scratch (O(M³)).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

from learner.kernels import GaussianKernel


def _triangular_solve(chol: np.ndarray, b: np.ndarray, transposed: bool = False) -> np.ndarray:
    """``L⁻¹ b`` (``L⁻ᵀ b`` when ``transposed``) for the lower Cholesky factor ``L``, by LAPACK's trtrs as
    scipy's ``solve_triangular`` calls it (the same numbers), without its checks: at the dictionary's
    sizes the wrapper costs five times the solve, and the learner solves three times a step."""
    x, info = lapack.dtrtrs(chol.T, np.asarray(b, float), lower=0, trans=0 if transposed else 1)
    if info > 0:
        raise np.linalg.LinAlgError(f"singular Cholesky factor: zero pivot at {info - 1}")
    if info < 0:
        raise ValueError(f"illegal value in argument {-info} of LAPACK trtrs")
    return x


def _cholesky_solve(chol: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(L Lᵀ)⁻¹ b`` by LAPACK's potrs, as scipy's ``cho_solve`` calls it, without its checks."""
    x, info = lapack.dpotrs(chol, np.asarray(b, float), lower=1)
    if info != 0:
        raise ValueError(f"illegal value in argument {-info} of LAPACK potrs")
    return x


class KernelDictionary:
    def __init__(self, kernel: GaussianKernel, jitter: float = 1e-8):
        self.kernel = kernel
        self.jitter = jitter
        self.centers = np.zeros((0, kernel.dim))
        self.gram = np.zeros((0, 0))
        self.chol = np.zeros((0, 0))
        # ``chol`` is the factor ``_refactor`` computes from ``gram`` and ``jitter`` (not a block update's):
        # refactoring again would give the same numbers (see ``refresh``).
        self.fresh = True

    def __len__(self) -> int:
        return len(self.centers)

    def features(self, s: np.ndarray) -> np.ndarray:
        return self.kernel.vector(self.centers, s)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``K⁻¹ b`` through the Cholesky factor."""
        if len(self) == 0:
            return np.zeros_like(b)
        return _cholesky_solve(self.chol, b)

    def residual(self, s: np.ndarray, kvec: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """(k_s, L⁻¹k_s, δ(s)): the ALD test without the projection, one triangular solve; the middle term
        is what :meth:`append` and :meth:`coefficients` take instead of solving again."""
        kvec = self.features(s) if kvec is None else kvec
        if len(self) == 0:
            return kvec, kvec, 1.0
        half = _triangular_solve(self.chol, kvec)
        return kvec, half, max(1.0 - float(half @ half), 0.0)

    def coefficients(self, half: np.ndarray) -> np.ndarray:
        """``K⁻¹k_s`` from :meth:`residual`'s ``L⁻¹k_s``."""
        if len(self) == 0:
            return half.copy()
        return _triangular_solve(self.chol, half, transposed=True)

    def ald(self, s: np.ndarray, kvec: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """(k_s, K⁻¹k_s, δ(s)): features, projection coefficients and ALD residual of ``s``."""
        kvec, half, delta = self.residual(s, kvec)
        return kvec, self.coefficients(half), delta

    def append(self, s: np.ndarray, kvec: np.ndarray | None = None, half: np.ndarray | None = None) -> None:
        """Add the center ``s``; ``kvec``, ``half``: its features and ``L⁻¹k_s`` (:meth:`residual`), if known
        (the same numbers, not computed again)."""
        kvec = self.features(s) if kvec is None else kvec
        m = len(self)
        gram = np.empty((m + 1, m + 1))
        gram[:m, :m] = self.gram
        gram[m, :m] = gram[:m, m] = kvec
        gram[m, m] = 1.0
        self.centers = np.vstack([self.centers, s[None, :]])
        self.gram = gram
        self.fresh = False
        if m == 0:
            self.chol = np.array([[np.sqrt(1.0 + self.jitter)]])
            return
        half = _triangular_solve(self.chol, kvec) if half is None else half
        d2 = 1.0 + self.jitter - float(half @ half)
        if d2 <= self.jitter * 0.5:
            self._refactor()
            return
        chol = np.zeros((m + 1, m + 1))
        chol[:m, :m] = self.chol
        chol[m, :m] = half
        chol[m, m] = np.sqrt(d2)
        self.chol = chol

    def remove(self, j: int) -> None:
        keep = np.arange(len(self)) != j
        self.centers = self.centers[keep]
        self.gram = self.gram[np.ix_(keep, keep)]
        self._refactor()

    def removal_residuals(self) -> np.ndarray:
        """δ_j of each center against all the others: ``1 / (K⁻¹)_jj``."""
        inv_diag = np.diag(self.solve(np.eye(len(self))))
        return 1.0 / np.maximum(inv_diag, 1e-12)

    def refresh(self) -> None:
        """The factor as :meth:`remove` leaves it, from scratch; nothing to do when it already is."""
        if not self.fresh:
            self._refactor()

    def _refactor(self) -> None:
        """Cholesky from scratch, raising the jitter until it succeeds."""
        eye = np.eye(len(self))
        while True:
            try:
                self.chol = np.linalg.cholesky(self.gram + self.jitter * eye)
                self.fresh = True
                return
            except np.linalg.LinAlgError:
                self.jitter = max(self.jitter * 10.0, 1e-10)

    def state_dict(self) -> dict:
        return {"centers": self.centers, "gram": self.gram, "chol": self.chol, "jitter": self.jitter}

    def load_state_dict(self, state: dict) -> None:
        self.centers, self.gram, self.chol = state["centers"], state["gram"], state["chol"]
        self.jitter = state["jitter"]
        self.fresh = False  # not known: the next refresh refactors


class RKHSFunction:
    """``f(s) = Σ_j k(s, c_j) w_j`` with ``w_j ∈ R^d``, kept under ``budget`` centers.

    ``add(s, g)`` adds the function ``k(s,·) g``: a new center when ``s`` passes the ALD test, else its
    RKHS projection onto the dictionary (``W += K⁻¹k_s gᵀ``). Over budget, the center whose removal
    loses the least RKHS norm (``‖w_j‖² δ_j``) is dropped and its weight projected onto the rest
    (kernel orthogonal-matching-pursuit style pruning). ``error_bound`` accumulates the RKHS-norm error
    each approximation made, so ``‖f_exact - f‖_H ≤ error_bound`` by the triangle inequality.
    """

    def __init__(self, kernel: GaussianKernel, out_dim: int, budget: int, ald_threshold: float):
        if budget < 1:
            raise ValueError(f"budget must be >= 1, got {budget}")
        self.dictionary = KernelDictionary(kernel)
        self.weights = np.zeros((0, out_dim))
        self.budget = budget
        self.ald_threshold = ald_threshold
        self.error_bound = 0.0

    def __len__(self) -> int:
        return len(self.dictionary)

    def __call__(self, s: np.ndarray) -> np.ndarray:
        return self.dictionary.features(s) @ self.weights

    def norm2(self) -> float:
        return float(np.einsum("id,ij,jd->", self.weights, self.dictionary.gram, self.weights))

    def scale(self, factor: float) -> None:
        self.weights *= factor

    def add(self, s: np.ndarray, g: np.ndarray) -> None:
        kvec, half, delta = self.dictionary.residual(s)
        if delta > self.ald_threshold:
            self.dictionary.append(s, kvec, half)
            self.weights = np.vstack([self.weights, g[None, :]])
            if len(self) > self.budget:
                self._prune()
        else:
            self.weights += np.outer(self.dictionary.coefficients(half), g)
            self.error_bound += float(np.sqrt(delta * (g @ g)))

    def _prune(self) -> None:
        residuals = self.dictionary.removal_residuals()
        loss = residuals * np.einsum("id,id->i", self.weights, self.weights)
        j = int(np.argmin(loss))
        w_j, k_j = self.weights[j].copy(), self.dictionary.gram[j].copy()
        keep = np.arange(len(self)) != j
        self.dictionary.remove(j)
        self.weights = self.weights[keep] + np.outer(self.dictionary.solve(k_j[keep]), w_j)
        self.error_bound += float(np.sqrt(loss[j]))

    def state_dict(self) -> dict:
        return {
            "dictionary": self.dictionary.state_dict(),
            "weights": self.weights,
            "error_bound": self.error_bound,
        }

    def load_state_dict(self, state: dict) -> None:
        self.dictionary.load_state_dict(state["dictionary"])
        self.weights = state["weights"]
        self.error_bound = state["error_bound"]
