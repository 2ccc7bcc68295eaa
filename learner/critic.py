"""Kernel least-squares TD critics: recursive (O(M²) per step), ALD-sparsified, budgeted, forgetting.

The recursion is RLS-TD(0) (Xu, He & Hu 2002) on kernel features ``k(D, s)``: with ``u = φ_t`` and
``v = φ_t - γ φ_{t+1}``, ``θ ← θ + P u (r - vᵀθ) / (β + vᵀ P u)`` and
``P ← (P - P u vᵀ P / (β + vᵀ P u)) / β``. The forgetting factor ``β < 1`` discounts old transitions,
which the drifting world makes wrong. ``P`` is capped at its initial scale so it cannot wind up while a
region goes unvisited.

Three feature maps share the recursion:
- ``value``: ``φ(s) = k(D, s)``, ``V(s) = θᵀφ(s)``; the TD error is the advantage handed to the actor.
- ``q`` (kernel LSTD-Q, the paper's own ``Q̂(s,a)`` regression): a dictionary over state-action pairs
  ``z = (s, ã)`` (``ã`` the executed action scaled to [-1, 1]) with the product kernel
  ``k((s,ã),(c,b)) = k_S(s,c) k_A(ã,b)``, ``k_A`` Gaussian with its own ``action_bandwidth``. The target
  is expected SARSA: ``φ_{t+1} = E_{ã'~π(·|s')} φ(s', ã')``, which for a Gaussian policy and kernel is
  closed form, ``E k_A(ã', b) = Π_d β_d/√(β_d²+σ̃_d²) · exp(-(μ̃_d - b_d)²/(2(β_d²+σ̃_d²)))``, with
  ``μ̃, σ̃`` the policy mean and std in the same scaled units (the box clip of the executed action is
  ignored in the expectation). The same closed form gives the policy's value ``V(s) = E_a Q̂(s,a)`` and
  the paper's ``D(s) = ∫ Q̂(s,a) Σ⁻¹(a - h(s)) π(a|s) da`` (eq. 9) exactly, as the derivative of
  ``E_a Q̂`` in the mean (Stein's lemma): :meth:`KLSTDCritic.expected_gradient`. Its features do not
  depend on the policy, so nothing goes stale when the policy moves; but where an action's effect on
  the return is small against ``Q̂``'s error its action slope is noise (NS Pendulum: docs/learner.md).
- ``compatible``: per center ``[k_j, k_j · score(s,a)]`` (the paper's ``φ(s,a) = k(s,·)Σ⁻¹(a - h(s))``
  plus a value baseline); the advantage is the compatible part, and its expectation over actions,
  ``w(s)/σ̃²``, the natural-gradient direction (``expected_gradient``). Its features depend on the
  policy, so they go stale after each policy update (unstable with the sampled gradient, no better than
  the value critic with the expected one: docs/learner.md); kept for the comparison.

The value critic can also remove the state-only part of its TD error, ``B(s) ≈ E_a[δ | s]`` (its
Bellman residual), from the advantage (``residual_memory``; :meth:`KLSTDCritic.residual`), and counts
where the samples fell (:meth:`KLSTDCritic.visits`) for the actor's local step size.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import blas

from learner.dictionary import KernelDictionary
from learner.kernels import GaussianKernel

MODES = ("value", "compatible", "q")
RESIDUAL_P0 = 10.0  # the prior scale (and cap) of the least-squares residual fit's P
WEIGHT_FLOOR = 1e-200  # a center's squared weight above which its pruning loss cannot round to zero


def subtract_outer(p: np.ndarray, x: np.ndarray, y: np.ndarray) -> None:
    """``p -= np.outer(x, y)`` in place, with the same numbers: one GEMM of inner dimension 1 (each product
    rounded once, then subtracted; tests/learner/test_critic.py checks it against numpy's) instead of an
    M×M temporary, which at M = 1000 costs four times the update itself. ``p``: C-contiguous float64."""
    out = blas.dgemm(-1.0, y[:, None], x[None, :], 1.0, p.T, overwrite_c=True)
    if not np.shares_memory(out, p):  # not reached for a C-contiguous p; kept correct whatever p is
        p[...] = out.T


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
        action_bandwidth: float | np.ndarray = 1.0,
        residual_memory: float | None = None,
        visit_memory: float = 1.0,
        residual_fit: str = "kernel_mean",
        trace_lambda: float = 0.0,
    ):
        if mode not in MODES:
            raise ValueError(f"critic mode must be one of {MODES}, got {mode!r}")
        self.state_kernel = kernel
        self.state_dim, self.action_dim = kernel.dim, action_dim
        if mode == "q":
            ab = np.broadcast_to(np.asarray(action_bandwidth, float), (action_dim,)).copy()
            self.action_bw2 = ab**2
            joint = GaussianKernel(np.concatenate([kernel.bandwidth, ab]), kernel.dim + action_dim)
            self.dictionary = KernelDictionary(joint)
        else:
            self.dictionary = KernelDictionary(kernel)
        self.gamma, self.budget, self.ald_threshold = gamma, budget, ald_threshold
        self.forgetting, self.p0, self.mode = forgetting, p0, mode
        self.block = 1 + action_dim if mode == "compatible" else 1
        self.theta = np.zeros(0)
        self.P = np.zeros((0, 0))  # (the property below)
        # LSTD(λ) (Boyan 2002): the gain follows the eligibility trace z ← γλz + φ_t instead of φ_t. λ moves
        # the fixed point from TD(0)'s towards the least-squares fit of the Monte-Carlo returns (less bias
        # where the features cannot represent V, more variance). 0: RLS-TD(0).
        self.trace_lambda = trace_lambda
        self.trace = np.zeros(0)
        # The TD error's state-only part: a kernel-weighted running mean of TD errors (see residual()).
        if residual_memory is not None and mode != "value":
            raise ValueError("the residual baseline is for the value critic (critic: value)")
        if residual_fit not in ("kernel_mean", "least_squares"):
            raise ValueError(f"residual_fit must be 'kernel_mean' or 'least_squares', got {residual_fit!r}")
        self.residual_memory, self.residual_fit = residual_memory, residual_fit
        self.res_num = np.zeros(0)  # kernel_mean: Σ k_j δ and Σ k_j; least_squares: weights and P
        self.res_den = np.zeros(0)
        self.res_P = np.zeros((0, 0))
        self.visit_memory = visit_memory
        self.visit_counts = np.zeros(0)  # soft visit counts per center (see visits())

    def __len__(self) -> int:
        return len(self.dictionary)

    @property
    def P(self) -> np.ndarray:
        return self._P

    @P.setter
    def P(self, value: np.ndarray) -> None:
        self._P = value
        self._diag = None  # diag(P), kept beside it by update(): a strided read of M cache lines otherwise

    def _phi(self, kvec: np.ndarray, score: np.ndarray | None) -> np.ndarray:
        if self.mode == "value":
            return kvec
        extra = np.zeros(self.block - 1) if score is None else score
        return (kvec[:, None] * np.concatenate([[1.0], extra])[None, :]).ravel()

    def value(self, s: np.ndarray, mean: np.ndarray | None = None, sigma: np.ndarray | None = None) -> float:
        """The state-value part ``V(s)``; for ``q`` the policy's ``E_{ã~N(mean, sigma²)} Q̂(s, ã)`` (scaled
        action units), which needs ``mean`` and ``sigma``."""
        if self.mode == "q":
            return float(self._expected_phi(s, mean, sigma)[0] @ self.theta)
        kvec = self.dictionary.features(s)
        return float(self._phi(kvec, None) @ self.theta)

    def q_value(self, s: np.ndarray, action: np.ndarray) -> float:
        """``Q̂(s, ã)`` (mode ``q``; ``ã`` in scaled action units)."""
        return float(self.dictionary.features(np.concatenate([s, action])) @ self.theta)

    def _expected_phi(
        self, s: np.ndarray, mean: np.ndarray, sigma: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(``E_ã φ(s, ã)``, the action centers' offsets ``μ̃ - b_j``, ``β² + σ̃²``) for ``ã ~ N(mean, σ̃²)``."""
        centers = self.dictionary.centers
        if len(centers) == 0:
            return np.zeros(0), np.zeros((0, self.action_dim)), np.ones(self.action_dim)
        ks = self.state_kernel.vector(centers[:, : self.state_dim], s)
        var = self.action_bw2 + np.asarray(sigma, float) ** 2
        diff = np.asarray(mean, float)[None, :] - centers[:, self.state_dim :]
        m = np.prod(np.sqrt(self.action_bw2 / var)) * np.exp(-0.5 * np.sum(diff**2 / var, axis=1))
        return ks * m, diff, var

    def expected_gradient(self, s: np.ndarray, mean: np.ndarray, sigma: np.ndarray) -> np.ndarray:
        """The paper's ``D(s)`` in scaled action units, ``∂/∂μ̃ E_{ã~N(μ̃, σ̃²)} Q̂(s, ã)`` at ``μ̃ = mean``
        (equal to ``E[Q̂(s,ã) (ã - μ̃)/σ̃²]``), in closed form (mode ``q``)."""
        if self.mode == "compatible":
            # Â = w(s)ᵀ score with score = (ã - μ̃)/σ̃² (f's units): E[Â score | s] = w(s) / σ̃².
            kvec = self.dictionary.features(s)
            w = kvec @ self.theta.reshape(-1, self.block)[:, 1:]
            return w / np.asarray(sigma, float) ** 2
        if self.mode != "q":
            raise ValueError("the expected gradient needs a state-action critic (critic: q or compatible)")
        phi, diff, var = self._expected_phi(s, mean, sigma)
        if len(phi) == 0:
            return np.zeros(self.action_dim)
        return -((phi * self.theta)[:, None] * diff / var[None, :]).sum(axis=0)

    def advantage(self, s: np.ndarray, score: np.ndarray) -> float:
        """The compatible (advantage) part of ``Q̂(s,a)``; zero for the other critics."""
        if self.mode != "compatible":
            return 0.0
        kvec = self.dictionary.features(s)
        return float((self._phi(kvec, score) - self._phi(kvec, None)) @ self.theta)

    def td_error(self, s: np.ndarray, r: float, s_next: np.ndarray, terminal: bool) -> float:
        """``r + γV(s') - V(s) - B(s)`` under the critic as it stands, without fitting (value critic): the
        advantage a past transition gets when it is re-used (learner/replay.py)."""
        if self.mode != "value":
            raise ValueError("re-scoring a past transition needs the value critic (critic: value)")
        if len(self) == 0:
            return float(r)
        kvec = self.dictionary.features(s)
        baseline = self._residual_of(kvec) if self.residual_memory is not None else 0.0
        nxt = 0.0 if terminal else self.value(s_next)
        return float(r + self.gamma * nxt - kvec @ self.theta - baseline)

    def update(
        self,
        s: np.ndarray,
        r: float,
        s_next: np.ndarray,
        terminal: bool,
        score: np.ndarray | None = None,
        action: np.ndarray | None = None,
        mean: np.ndarray | None = None,
        next_mean: np.ndarray | None = None,
        sigma: np.ndarray | None = None,
    ) -> float:
        """Fit one transition; returns the advantage estimate for the actor, computed before the fit.

        ``value``: the TD error ``r + γV(s') - V(s)``. ``compatible``: ``Q̂(s,a) - V(s)``. ``q``:
        ``Q̂(s,ã) - E_ã Q̂(s,ã)``; it needs the executed ``action``, the policy's ``mean`` at ``s`` and
        ``next_mean`` at ``s'`` and its ``sigma`` (all in scaled action units).
        """
        if self.mode == "q":
            z = np.concatenate([s, action])
            u = self._maybe_add_center(z)
            u = self.dictionary.features(z) if u is None else u
            nxt = np.zeros_like(u) if terminal else self._expected_phi(s_next, next_mean, sigma)[0]
            advantage = float(u @ self.theta) - float(self._expected_phi(s, mean, sigma)[0] @ self.theta)
        else:
            kvec = self._maybe_add_center(s)
            kvec = self.dictionary.features(s) if kvec is None else kvec
            self._count_visit(kvec)
            u = self._phi(kvec, score)
            nxt = np.zeros_like(u) if terminal else self._phi(self.dictionary.features(s_next), None)
        v = u - self.gamma * nxt
        td_error = float(r - v @ self.theta)
        z = u
        if self.trace_lambda > 0.0:
            self.trace = self.gamma * self.trace_lambda * self.trace + u
            z = self.trace
        if self.mode == "value":
            advantage = td_error
            if self.residual_memory is not None:
                advantage = td_error - self._residual_step(u, td_error)
        elif self.mode == "compatible":
            advantage = self.advantage(s, score)
        if terminal:
            self.end_episode()
        pu = self.P @ z
        denom = self.forgetting + float(v @ pu)
        if abs(denom) < 1e-9:
            return advantage
        gain = pu / denom
        self.theta = self.theta + gain * td_error
        # P ← (P - gain (vᵀP)) / β in place: the same numbers as the expression, no M×M temporaries; its
        # diagonal by the same operations on the diagonal's elements.
        diag = np.diag(self.P).copy() if self._diag is None else self._diag
        vp = v @ self.P
        subtract_outer(self.P, gain, vp)
        np.divide(self.P, self.forgetting, out=self.P)
        diag = (diag - gain * vp) / self.forgetting
        peak = float(np.max(np.abs(diag)))
        if peak > self.p0:
            self.P *= self.p0 / peak
            diag *= self.p0 / peak
        self._diag = diag
        return advantage

    def end_episode(self) -> None:
        """An episode's credit never reaches into the next one: clear the eligibility trace."""
        self.trace = np.zeros_like(self.theta)

    def visits(self, s: np.ndarray) -> float:
        """How many past samples fell near ``s``: each sample adds its soft assignment to the centers,
        ``k_j(s_t) / Σ_i k_i(s_t)`` (summing to 1), forgotten at ``visit_memory`` per step, and ``s`` reads
        its own soft cell, ``Σ_j k_j(s) n_j / (Σ_j k_j(s) + 0.1)`` (the 0.1: far from every center, none).
        States only (value and compatible critics)."""
        if len(self) == 0 or self.mode == "q":
            return 0.0
        kvec = self.dictionary.features(s)
        return float(kvec @ self.visit_counts) / (float(kvec.sum()) + 0.1)

    def _count_visit(self, kvec: np.ndarray) -> None:
        self.visit_counts *= self.visit_memory
        total = float(kvec.sum())
        if total > 1e-12:
            self.visit_counts += kvec / total

    def residual(self, s: np.ndarray) -> float:
        """``B(s)``: the running estimate of ``E[δ | s]`` over actions, the part of the TD error that the
        critic's own error at ``s`` puts there (its Bellman residual; zero at an exact fixed point).

        ``kernel_mean``: ``B(s) = Σ_j k_j(s) N_j / (1 + Σ_j k_j(s) W_j)``, with ``N_j, W_j`` the
        exponentially forgotten (``residual_memory`` per step) sums of ``k_j(s_t) δ_t`` and ``k_j(s_t)``
        (Nadaraya-Watson on the critic's centers, shrunk to 0 where few samples fell).
        ``least_squares``: ``B(s) = βᵀk(s)``, ``β`` the recursive least-squares fit of ``δ_t`` on ``k(s_t)``
        with the same forgetting (a kernel ridge regression at the critic's own resolution).
        Either depends on other samples only, never on the action at hand, so ``δ - B(s)`` stays an
        unbiased advantage.
        """
        if self.residual_memory is None or len(self) == 0:
            return 0.0
        return self._residual_of(self.dictionary.features(s))

    def _residual_of(self, kvec: np.ndarray) -> float:
        if self.residual_fit == "least_squares":
            return float(kvec @ self.res_num)
        return float(kvec @ self.res_num) / (1.0 + float(kvec @ self.res_den))

    def _residual_step(self, kvec: np.ndarray, td_error: float) -> float:
        """``B(s)`` from the samples before this one, then this sample's TD error enters the fit."""
        b = self._residual_of(kvec)
        if self.residual_fit == "least_squares":
            beta = self.residual_memory
            pu = self.res_P @ kvec
            gain = pu / (beta + float(kvec @ pu))
            self.res_num = self.res_num + gain * (td_error - b)
            self.res_P = (self.res_P - np.outer(gain, pu)) / beta
            peak = float(np.max(np.diag(self.res_P))) if len(kvec) else 0.0
            if peak > RESIDUAL_P0:
                self.res_P *= RESIDUAL_P0 / peak
            return b
        self.res_num *= self.residual_memory
        self.res_den *= self.residual_memory
        self.res_num += kvec * td_error
        self.res_den += kvec
        return b

    def _maybe_add_center(self, s: np.ndarray) -> np.ndarray | None:
        """``s``: the state, or for ``q`` the state-action pair. Returns its features when the dictionary's
        centers are as they were (None: they changed).

        At the budget a new center is pruned at once: its weights are zero, so its pruning loss is, and
        every other center's is positive (while their weights are not vanishingly small). What admitting
        and pruning it would leave is then the dictionary as it was with its factor refactored from scratch
        (:meth:`KernelDictionary.refresh`): done so, without the O(M³) pruning. Only the factor's last
        digits can differ from before, and ``refresh`` reproduces them exactly."""
        kvec, half, delta = self.dictionary.residual(s)
        if delta <= self.ald_threshold:
            return kvec
        if len(self) >= self.budget and self._newcomer_pruned(delta):
            self.dictionary.refresh()
            return kvec
        self.dictionary.append(s, kvec, half)
        b, n = self.block, len(self.theta)
        self.theta = np.concatenate([self.theta, np.zeros(b)])
        self.trace = np.concatenate([self.trace, np.zeros(b)])  # past features of the new center: unknown
        grown = np.zeros((n + b, n + b))
        grown[:n, :n] = self.P
        grown[n:, n:] = self.p0 * np.eye(b)
        self.P = grown
        self.res_num = np.append(self.res_num, 0.0)
        self.res_den = np.append(self.res_den, 0.0)
        grown = np.zeros((n + 1, n + 1)) if b == 1 else np.zeros((0, 0))
        if b == 1:
            grown[:n, :n] = self.res_P
            grown[n, n] = RESIDUAL_P0
        self.res_P = grown
        self.visit_counts = np.append(self.visit_counts, 0.0)
        if len(self) > self.budget:
            self._prune()
        return None

    def _newcomer_pruned(self, delta: float) -> bool:
        """Whether :meth:`_prune` would drop a center admitted now (with residual ``delta``): every present
        center's loss, its removal residual (at least ~jitter) times its squared weight, is positive."""
        weight2 = (self.theta.reshape(-1, self.block) ** 2).sum(1)
        return bool(np.isfinite(delta) and len(weight2) and np.min(weight2) > WEIGHT_FLOOR)

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
        self.trace = self.trace[keep]
        if self.residual_fit == "least_squares" and b == 1:  # the removed center's weight, projected
            self.res_num = self.res_num[keep_c] + coeffs * self.res_num[j]
        else:
            self.res_num = self.res_num[keep_c]
        self.res_den = self.res_den[keep_c]
        if b == 1:
            self.res_P = self.res_P[np.ix_(keep_c, keep_c)]
        self.visit_counts = self.visit_counts[keep_c]

    def state_dict(self) -> dict:
        return {
            "dictionary": self.dictionary.state_dict(),
            "theta": self.theta,
            "P": self.P.copy(),  # updated in place
            "trace": self.trace,
            "res_num": self.res_num,
            "res_den": self.res_den,
            "res_P": self.res_P,
            "visit_counts": self.visit_counts,
        }

    def load_state_dict(self, state: dict) -> None:
        self.dictionary.load_state_dict(state["dictionary"])
        self.theta = state["theta"]
        self.P = np.array(state["P"], dtype=float, order="C")  # its own: updated in place
        self.trace = state.get("trace", np.zeros_like(self.theta))
        n = len(self.dictionary)
        self.res_num = state.get("res_num", np.zeros(n))
        self.res_den = state.get("res_den", np.zeros(n))
        self.res_P = state.get("res_P", RESIDUAL_P0 * np.eye(n) if self.block == 1 else np.zeros((0, 0)))
        self.visit_counts = state.get("visit_counts", np.zeros(n))
