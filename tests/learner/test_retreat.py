"""The retreat check: the closed-form RKHS inner product and the statistics built on it."""

from __future__ import annotations

import numpy as np
import pytest

from learner.kernels import GaussianKernel
from learner.retreat import MODES, RetreatCheck, default_threshold, rkhs_inner


def _gram_inner(kernel: GaussianKernel, sa, ga, sb, gb) -> float:
    """⟨Σ_a k(s_a,·)g_a, Σ_b k(s_b,·)g_b⟩ as uᵀ K v over the joint Gram matrix of all points."""
    points = np.vstack([sa, sb])
    u = np.vstack([ga, np.zeros_like(gb)])
    v = np.vstack([np.zeros_like(ga), gb])
    return float(np.einsum("id,ij,jd->", u, kernel(points, points), v))


def test_closed_form_inner_product_equals_the_gram_one():
    rng = np.random.default_rng(0)
    kernel = GaussianKernel(np.array([0.3, 0.8, 0.5]), 3)
    for _ in range(20):
        s0, si = rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3)
        g0, gi = rng.normal(size=2), rng.normal(size=2)
        closed = kernel.pair(s0, si) * float(g0 @ gi)
        assert rkhs_inner(kernel, s0[None], g0[None], si[None], gi[None]) == pytest.approx(closed, rel=1e-12)
        assert _gram_inner(kernel, s0[None], g0[None], si[None], gi[None]) == pytest.approx(
            closed, rel=1e-10, abs=1e-14
        )
    # Sums of several kernel sections (the segment-averaged gradients of the cosine mode).
    sa, ga = rng.uniform(-1, 1, (4, 3)), rng.normal(size=(4, 2))
    sb, gb = rng.uniform(-1, 1, (5, 3)), rng.normal(size=(5, 2))
    assert rkhs_inner(kernel, sa, ga, sb, gb) == pytest.approx(_gram_inner(kernel, sa, ga, sb, gb), rel=1e-10)
    # Symmetric and positive on the diagonal.
    assert rkhs_inner(kernel, sa, ga, sb, gb) == pytest.approx(rkhs_inner(kernel, sb, gb, sa, ga), rel=1e-12)
    assert rkhs_inner(kernel, sa, ga, sa, ga) > 0


def test_literal_statistic_is_k_s0_si_g0_gi_and_retreats_below_threshold():
    rng = np.random.default_rng(1)
    kernel = GaussianKernel(0.5, 2)
    threshold = default_threshold("literal", kernel, epsilon=1.0)
    assert threshold == pytest.approx(kernel.normaliser_z / 2.0)
    check = RetreatCheck(kernel, "literal", threshold)
    s0, g0 = rng.uniform(-1, 1, 2), rng.normal(size=1)
    assert check.push(s0, g0) is False  # no pair yet
    assert check.trace == []
    for _ in range(30):
        si, gi = rng.uniform(-1, 1, 2), rng.normal(size=1)
        fired = check.push(si, gi)
        stat = check.trace[-1]
        expected = _gram_inner(kernel, s0[None], g0[None], si[None], gi[None])
        assert stat == pytest.approx(expected, rel=1e-10, abs=1e-14)
        assert fired == (stat < threshold)
    # Gradients aligned with g0 at s0 itself: the statistic is |g0|², no retreat above the threshold.
    check.reset()
    big = np.array([10.0])
    check.push(s0, big)
    assert check.push(s0, big) is False
    assert check.trace[-1] == pytest.approx(100.0)
    assert check.push(s0, -big) is True  # the opposite direction is a retreat


class _ExactField:
    """The smoothed gradient field ``G ← (1-λ)G + λ k(s,·) g/|g|`` kept exactly (no sparsification)."""

    def __init__(self, kernel: GaussianKernel, lam: float):
        self.kernel, self.lam = kernel, lam
        self.s: list[np.ndarray] = []
        self.w: list[np.ndarray] = []

    def push(self, s: np.ndarray, g: np.ndarray) -> None:
        self.w = [(1 - self.lam) * w for w in self.w]
        self.s.append(s)
        self.w.append(self.lam * g / np.linalg.norm(g))

    def copy(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.s), np.array(self.w)


def test_smoothed_statistic_is_the_projection_ratio_of_the_gradient_field():
    """``⟨G_0, G_i⟩_H / ‖G_0‖²_H`` with ``G_0`` the field when the segment opened (exact field here)."""
    rng = np.random.default_rng(2)
    kernel = GaussianKernel(0.4, 2)
    lam = 0.2
    check = RetreatCheck(
        kernel,
        "smoothed",
        default_threshold("smoothed", kernel, 1.0),
        smoothing=lam,
        budget=10_000,
        ald_threshold=0.0,
    )
    scaled = RetreatCheck(
        kernel, "smoothed", check.threshold, smoothing=lam, budget=10_000, ald_threshold=0.0
    )
    assert check.threshold == 0.5
    exact = _ExactField(kernel, lam)
    snapshot = None
    n_stats = 0
    for t in range(60):
        if t % 15 == 0:  # segments of 15 steps
            check.reset()
            scaled.reset()
            snapshot = exact.copy() if exact.s else None
        s, g = rng.uniform(-1, 1, 2), rng.normal(size=1) + 0.3
        before = len(check.trace)
        fired = check.push(s, g)
        scaled.push(s, 1e3 * g)
        exact.push(s, g)
        if snapshot is None:
            assert len(check.trace) == before and fired is False  # no gradient history yet
            continue
        s0, w0 = snapshot
        si, wi = exact.copy()
        expected = _gram_inner(kernel, s0, w0, si, wi) / _gram_inner(kernel, s0, w0, s0, w0)
        assert check.trace[-1] == pytest.approx(expected, rel=1e-6, abs=1e-9)
        assert fired == (check.trace[-1] < check.threshold)
        n_stats += 1
    assert n_stats == 45
    # Each gradient enters as a unit vector: the statistic does not depend on the TD errors' scale.
    np.testing.assert_allclose(scaled.trace, check.trace, rtol=1e-9, atol=1e-12)


def test_smoothed_check_holds_for_a_steady_gradient_and_retreats_when_it_turns():
    rng = np.random.default_rng(3)
    kernel = GaussianKernel(0.4, 2)
    check = RetreatCheck(kernel, "smoothed", 0.5, smoothing=0.1)
    states = rng.uniform(-1, 1, (8, 2))
    for t in range(100):  # build a field of a steady gradient direction
        check.push(states[t % 8], np.array([1.0]))
    check.reset()
    steady = [check.push(states[t % 8], np.array([1.0])) for t in range(50)]
    assert not any(steady)
    assert min(check.trace) > 0.9
    check.reset()
    turned = [check.push(states[t % 8], np.array([-1.0])) for t in range(50)]
    assert any(turned)
    first = turned.index(True)
    assert 0 < first < 20
    assert check.trace[first] < 0.5 <= check.trace[first - 1]


def test_mode_off_never_retreats_and_records_everything():
    rng = np.random.default_rng(4)
    kernel = GaussianKernel(0.4, 2)
    check = RetreatCheck(kernel, "off", 0.5)
    for t in range(200):
        # Alternating gradients: the worst case for the other modes.
        assert check.push(rng.uniform(-1, 1, 2), np.array([(-1.0) ** t * 50.0])) is False
    assert len(check.states) == len(check.grads) == 200
    assert check.trace == []
    # The same stream retreats under both other modes.
    for mode in ("literal", "smoothed"):
        other = RetreatCheck(kernel, mode, default_threshold(mode, kernel, 1.0), smoothing=0.5)
        s = np.zeros(2)
        fired = []
        for _ in range(4):
            other.reset()
            fired += [other.push(s, np.array([(-1.0) ** t * 50.0])) for t in range(6)]
        assert any(fired), mode
    with pytest.raises(ValueError, match="retreat mode"):
        RetreatCheck(kernel, "sometimes", 0.5)
    assert "off" in MODES and "literal" in MODES


def _field_at(kernel: GaussianKernel, field: _ExactField, s: np.ndarray) -> np.ndarray:
    centers, weights = field.copy()
    return kernel(s[None, :], centers)[0] @ weights


def test_local_statistic_is_the_theorems_inner_product_of_the_smoothed_gradients():
    """``k(s0,si) G(s0)ᵀG(si) / ‖G(s0)‖²`` with G the current field (exact here), threshold Z/2."""
    rng = np.random.default_rng(5)
    kernel = GaussianKernel(0.4, 2)
    lam = 0.2
    threshold = default_threshold("local", kernel, 1.0)
    assert threshold == pytest.approx(min(kernel.normaliser_z / 2, 0.5))
    check = RetreatCheck(kernel, "local", threshold, smoothing=lam, budget=10_000, ald_threshold=0.0)
    exact = _ExactField(kernel, lam)
    s0 = None
    for t in range(60):
        if t % 15 == 0:
            check.reset()
        s, g = rng.uniform(-1, 1, 2), rng.normal(size=2)
        fired = check.push(s, g)
        exact.push(s, g)
        s0 = s if t % 15 == 0 else s0
        d0, di = _field_at(kernel, exact, s0), _field_at(kernel, exact, s)
        expected = kernel.pair(s0, s) * float(d0 @ di) / float(d0 @ d0)
        assert check.trace[-1] == pytest.approx(expected, rel=1e-6, abs=1e-9)
        assert fired == (expected < threshold)


def test_local_check_holds_near_s0_for_a_steady_gradient_and_retreats_on_disagreement_or_leaving():
    kernel = GaussianKernel(0.4, 2)
    check = RetreatCheck(kernel, "local", 0.05, smoothing=0.1)
    s0 = np.zeros(2)
    near = [s0 + 0.05 * np.array([np.cos(t), np.sin(t)]) for t in range(40)]
    for s in near:  # a steady ascent direction around s0
        check.push(s, np.array([1.0]))
    check.reset()
    assert not any(check.push(s, np.array([1.0])) for s in near)
    assert min(check.trace) > 0.9
    # The segment starts at s0; nearby, at si, the gradients turn: G(si) and G(s0) come to disagree.
    check.reset()
    si = np.array([0.5, 0.0])
    disagree = [check.push(s0 if t == 0 else si, np.array([1.0 if t == 0 else -1.0])) for t in range(40)]
    assert any(disagree)
    first = disagree.index(True)
    assert check.trace[first] < 0.05 and float(check.field(si)[0]) < 0
    # A steady gradient, but the state leaves the kernel's reach of s0.
    check.reset()
    far = [check.push(np.array([0.1 * t, 0.0]), np.array([1.0])) for t in range(40)]
    assert any(far)
