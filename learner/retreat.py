"""The strategic-retreat check: is the newest policy gradient still an ascent direction?

Theorem 1 of the paper: while ``‖∇_h J‖²_H ≥ ε`` (h is not yet ε-optimal) and the kernel is narrow
enough, ``⟨∇J|_{s0}, ∇J|_{s'}⟩_H ≥ Z ε / 2`` with ``Z = sqrt(2π det Σ_H)``. A segment whose gradients
break that bound has left the regime where the start-of-segment policy's ascent direction holds, so
the agent retreats: drops the rest of its queued actions and updates.

The theorem speaks of the *expected* gradient ``D(s)ρ(s)``, not of one sample. Taken literally on
per-sample gradients ``k(s0,si) g0ᵀgi`` (mode ``literal``) the test reads the sign of exploration
noise, whatever the world does (docs/learner.md). Both other modes estimate the expected gradient field
first:

    G ← (1-λ) G + λ k(s_t,·) g_t/‖g_t‖

an exponentially weighted RKHS average of the per-sample gradient directions (``λ`` = ``smoothing``;
unit directions because TD errors are heavy-tailed), kept sparse under a budget like the policy.
Exploration noise averages out; a systematic change of the gradient rotates ``G``.

- ``local`` (default), the theorem's own inner product with ``G`` in place of samples: both
  gradients of the current ``h`` (the policy is fixed within a segment), at the segment's first state
  and at the newest, ``⟨k(s0,·)G(s0), k(si,·)G(si)⟩_H = k(s0,si) G(s0)ᵀG(si)``, against ``Z ε / 2``
  with the tightest ``ε`` the statement allows at ``s0``, ``ε = ‖k(s0,·)G(s0)‖² = ‖G(s0)‖²``.
  Dividing by it gives the scale-free statistic ``k(s0,si) G(s0)ᵀG(si) / ‖G(s0)‖²`` and the
  threshold ``Z/2`` (capped at 1/2). It fires when the state leaves the kernel's reach of ``s0`` or
  the estimated ascent directions at ``s0`` and ``si`` disagree. Both gradients come from the current
  field: one frozen at the segment's start destabilised learning (docs/learner_measurements.md).
- ``smoothed``: the whole field, ``G_0`` when the segment opened against ``G_i`` now. At ``s'=s0`` eq.
  37 makes ``⟨G_0, G_0⟩`` equal ``Z ε``; dividing the bound ``⟨G_0, G_i⟩ ≥ Z ε / 2`` by it leaves the
  projection ratio ``⟨G_0, G_i⟩_H / ‖G_0‖²_H ≥ 1/2``. It acts as a timer: each step
  shrinks the ratio by ``1-λ`` and local agreement adds little against the global norm, so
  ``H ≈ ln 2 / λ`` whatever the world does.
- ``plan`` (for plan execution, ``learner.plans``): the same inner product taken where plan and world
  can disagree, between the gradient at the state the plan predicted and at the state reached,
  ``k(ŝ_i,s_i) G(ŝ_i)ᵀG(s_i) / ‖G(ŝ_i)‖²`` against the same threshold. A plan made from a snapshot of
  the world fails it when the world has left the kernel's reach of what the plan assumed, or when the
  ascent directions there disagree; ``local`` compares actual states only and cannot see a plan going
  stale. Without a plan (closed loop) it never fires. ``k(ŝ_i,s_i)`` may be narrower than the policy's
  (the config's ``plan_kernel_scale``): the policy's kernel is as wide as generalisation wants, and a
  plan can then drift by a task's whole tolerance before the kernel notices; or learned from how far
  the plan's predictions normally miss (``plan_tolerance: learned``, ``learner.plan_tolerance``).
All inner products are exact: ``⟨Σ_a k(s_a,·)g_a, Σ_b k(s_b,·)g_b⟩_H = Σ_ab k(s_a,s_b) g_aᵀg_b``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, get_args

import numpy as np

from learner.dictionary import RKHSFunction
from learner.kernels import GaussianKernel
from learner.plan_tolerance import FixedTolerance, PlanTolerance


@dataclass
class SegmentSamples:
    """One open segment's samples: its states, gradients and retreat statistics so far. A learner that
    pools several arms keeps one per arm and sets it as the check's ``segment`` before each sample."""

    states: list[np.ndarray] = field(default_factory=list)
    grads: list[np.ndarray] = field(default_factory=list)
    trace: list[float] = field(default_factory=list)
    snapshot: tuple[np.ndarray, np.ndarray, float] | None = None  # ``smoothed``: G_0 at the opening


RetreatMode = Literal["local", "plan", "smoothed", "literal", "off"]
MODES: tuple[str, ...] = get_args(RetreatMode)


def rkhs_inner(
    kernel: GaussianKernel, sa: np.ndarray, ga: np.ndarray, sb: np.ndarray, gb: np.ndarray
) -> float:
    """``⟨Σ_a k(s_a,·)g_a, Σ_b k(s_b,·)g_b⟩_H`` in closed form."""
    return float(np.sum(kernel(sa, sb) * (ga @ gb.T)))


def default_threshold(mode: str, kernel: GaussianKernel, epsilon: float) -> float:
    if mode == "literal":
        return kernel.normaliser_z * epsilon / 2.0
    if mode in ("local", "plan"):
        return min(kernel.normaliser_z / 2.0, 0.5)
    return 0.5


def plan_statistic(
    field: RKHSFunction, tolerance: PlanTolerance, ahead: int, predicted: np.ndarray, reached: np.ndarray
) -> float | None:
    """Mode ``plan``'s ``k(ŝ,s) G(ŝ)ᵀG(s) / ‖G(ŝ)‖²`` for a state predicted ``ahead`` steps into the plan
    (the tolerance learns the gap afterwards); None while ``G`` is zero where the plan went."""
    dp, dr = field(predicted), field(reached)
    n = float(dp @ dp)
    k = tolerance.value(ahead, predicted, reached)
    tolerance.observe(ahead, predicted, reached)
    if n <= 1e-300:
        return None
    return k * float(dp @ dr) / n


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
        plan_tolerance: PlanTolerance | None = None,
    ):
        if mode not in MODES:
            raise ValueError(f"retreat mode must be one of {MODES}, got {mode!r}")
        if not 0.0 < smoothing <= 1.0:
            raise ValueError(f"retreat smoothing must be in (0, 1], got {smoothing}")
        self.kernel, self.mode, self.threshold, self.smoothing = kernel, mode, threshold, smoothing
        # Compares a plan's predicted state with the reached one.
        self.plan_tolerance = plan_tolerance or FixedTolerance(kernel)
        self.field = RKHSFunction(kernel, 0, budget, ald_threshold)  # out_dim set on first push
        self.segment = SegmentSamples()

    @property
    def states(self) -> list[np.ndarray]:
        return self.segment.states

    @property
    def grads(self) -> list[np.ndarray]:
        return self.segment.grads

    @property
    def trace(self) -> list[float]:
        return self.segment.trace

    def reset(self) -> None:
        """Open a new segment: the current gradient field becomes ``G_0``."""
        self.segment = SegmentSamples()

    def push(
        self,
        s: np.ndarray,
        g: np.ndarray,
        predicted: np.ndarray | None = None,
        reached: np.ndarray | None = None,
        judged: bool = False,
        statistic: float | None = None,
        ahead: int = 0,
    ) -> bool:
        """Record a step; True when the retreat condition fails (statistic below threshold).

        ``predicted``/``reached``: the (normalised) state the running plan predicted after this step and
        the one reached, for mode ``plan``, ``ahead`` steps into the plan. ``judged``: the statistic was
        evaluated where the plan played (an actor's ``statistic``, None: not evaluated); the gradient
        field still learns from ``g`` here.
        """
        self.states.append(s)
        self.grads.append(g)
        if self.mode == "off":
            return False
        if self.field.weights.shape[1] != len(g):  # the field learns its output size from the first g
            self.field.weights = np.zeros((len(self.field), len(g)))
        if judged:
            self._update_field(g, s)
            stat = statistic
        elif self.mode == "literal":
            stat = self._literal()
        elif self.mode == "local":
            stat = self._local(s, g)
        elif self.mode == "plan":
            stat = self._plan(s, g, predicted, reached, ahead)
        else:
            stat = self._smoothed(s, g)
        if stat is None:
            return False
        self.trace.append(stat)
        return stat < self.threshold

    def _literal(self) -> float | None:
        if len(self.states) < 2:
            return None
        return self.kernel.pair(self.states[0], self.states[-1]) * float(self.grads[0] @ self.grads[-1])

    def _update_field(self, g: np.ndarray, s: np.ndarray) -> None:
        field = self.field
        field.scale(1.0 - self.smoothing)
        norm = float(np.linalg.norm(g))
        if norm > 0:  # directions only: heavy-tailed TD errors must not let one sample swing G
            field.add(s, self.smoothing * g / norm)

    def _smoothed(self, s: np.ndarray, g: np.ndarray) -> float | None:
        field, segment = self.field, self.segment
        if segment.snapshot is None:
            segment.snapshot = (field.dictionary.centers.copy(), field.weights.copy(), field.norm2())
        self._update_field(g, s)
        centers0, weights0, norm0 = segment.snapshot
        if norm0 <= 1e-300 or len(centers0) == 0:
            return None  # no gradient history yet: nothing to compare with
        cross = float(np.sum(self.kernel(centers0, field.dictionary.centers) * (weights0 @ field.weights.T)))
        return cross / norm0

    def _local(self, s: np.ndarray, g: np.ndarray) -> float | None:
        self._update_field(g, s)
        d0, di = self.field(self.states[0]), self.field(s)
        n0 = float(d0 @ d0)
        if n0 <= 1e-300:
            return None  # no gradient estimate at s0 yet
        return self.kernel.pair(self.states[0], s) * float(d0 @ di) / n0

    def _plan(
        self,
        s: np.ndarray,
        g: np.ndarray,
        predicted: np.ndarray | None,
        reached: np.ndarray | None,
        ahead: int,
    ) -> float | None:
        self._update_field(g, s)
        if predicted is None or reached is None:
            return None  # no plan running: nothing was assumed
        return plan_statistic(self.field, self.plan_tolerance, ahead, predicted, reached)

    def state_dict(self) -> dict:
        return {
            "field": self.field.state_dict(),
            "snapshot": self.segment.snapshot,
            "states": self.states,
            "grads": self.grads,
            "trace": self.trace,
            "plan_tolerance": getattr(self.plan_tolerance, "state_dict", dict)(),
        }

    def start_from(self, state: dict) -> None:
        """A handoff: another run's gradient field and plan tolerance; no segment of it is open here."""
        self.field.load_state_dict(state["field"])
        if state.get("plan_tolerance") and hasattr(self.plan_tolerance, "load_state_dict"):
            self.plan_tolerance.load_state_dict(state["plan_tolerance"])

    def load_state_dict(self, state: dict) -> None:
        self.start_from(state)
        self.segment = SegmentSamples(
            list(state["states"]), list(state["grads"]), list(state["trace"]), state["snapshot"]
        )
