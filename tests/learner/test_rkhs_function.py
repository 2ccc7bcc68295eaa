"""The kernel, the kernel dictionary and the RKHS function: reproducing property, Cholesky, sparsification."""

from __future__ import annotations

import numpy as np
import pytest

from learner.dictionary import KernelDictionary, RKHSFunction
from learner.kernels import GaussianKernel
from learner.retreat import rkhs_inner


def _rkhs_norm2(kernel: GaussianKernel, points: np.ndarray, weights: np.ndarray) -> float:
    """‖Σ_i k(p_i,·) w_i‖²_H from the full Gram matrix of ``points``."""
    gram = kernel(points, points)
    return float(np.einsum("id,ij,jd->", weights, gram, weights))


def test_kernel_is_the_gaussian_with_per_dimension_bandwidths():
    rng = np.random.default_rng(0)
    bw = np.array([0.3, 1.5, 0.7])
    k = GaussianKernel(bw, 3)
    x, y = rng.normal(size=(5, 3)), rng.normal(size=(4, 3))
    expected = np.array([[np.exp(-0.5 * np.sum(((xi - yj) / bw) ** 2)) for yj in y] for xi in x])
    np.testing.assert_allclose(k(x, y), expected, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(k.vector(y, x[0]), expected[0], rtol=1e-12, atol=1e-14)
    assert k.pair(x[1], y[2]) == pytest.approx(expected[1, 2], rel=1e-12)
    assert k.normaliser_z == pytest.approx(np.sqrt(2 * np.pi * np.prod(bw**2)))
    with pytest.raises(ValueError, match="bandwidth"):
        GaussianKernel(np.array([0.3, -1.0, 0.7]), 3)


def _random_function(
    rng: np.random.Generator, kernel: GaussianKernel, n_adds: int, out_dim: int
) -> RKHSFunction:
    f = RKHSFunction(kernel, out_dim, budget=1000, ald_threshold=0.01)
    for _ in range(n_adds):
        f.add(rng.uniform(-1, 1, kernel.dim), rng.normal(size=out_dim))
    return f


def test_reproducing_property_through_weights_and_gram():
    """⟨f, k(s,·)a⟩_H = f(s)ᵀa, with the left side from the weights and the Gram matrix alone."""
    rng = np.random.default_rng(1)
    kernel = GaussianKernel(np.array([0.4, 0.6]), 2)
    f = _random_function(rng, kernel, 40, out_dim=3)
    centers, weights = f.dictionary.centers, f.weights
    assert len(f) > 5
    # The dictionary's own Gram is the kernel's Gram of its centers.
    np.testing.assert_allclose(f.dictionary.gram, kernel(centers, centers), atol=1e-12)
    for _ in range(20):
        s, a = rng.uniform(-1.5, 1.5, 2), rng.normal(size=3)
        # f and k(s,·)a as one function over the points [centers, s]: weights [W; 0] and [0; a].
        points = np.vstack([centers, s])
        wf = np.vstack([weights, np.zeros((1, 3))])
        wk = np.vstack([np.zeros_like(weights), a[None, :]])
        inner = float(np.einsum("id,ij,jd->", wf, kernel(points, points), wk))
        assert inner == pytest.approx(float(f(s) @ a), rel=1e-10, abs=1e-12)
        # The closed form agrees too.
        assert rkhs_inner(kernel, centers, weights, s[None], a[None]) == pytest.approx(
            inner, rel=1e-10, abs=1e-12
        )
    # ‖f‖² = ⟨f, f⟩ = Σ_j w_jᵀ f(c_j).
    fc = np.array([f(c) for c in centers])
    assert f.norm2() == pytest.approx(float(np.sum(weights * fc)), rel=1e-10)


def test_dictionary_cholesky_matches_numpy_after_appends_and_removals():
    rng = np.random.default_rng(2)
    kernel = GaussianKernel(0.5, 3)
    d = KernelDictionary(kernel)

    def check():
        m = len(d)
        np.testing.assert_allclose(d.gram, kernel(d.centers, d.centers), atol=1e-12)
        expected = np.linalg.cholesky(d.gram + d.jitter * np.eye(m))
        np.testing.assert_allclose(d.chol, expected, atol=1e-8)
        np.testing.assert_allclose(np.tril(d.chol), d.chol)  # lower triangular
        b = rng.normal(size=m)
        np.testing.assert_allclose((d.gram + d.jitter * np.eye(m)) @ d.solve(b), b, atol=1e-6)

    for i in range(40):
        d.append(rng.uniform(-1, 1, 3))
        if i % 7 == 6:
            check()
    for j in (0, 17, -1, 5):
        d.remove(j % len(d))
        check()
    assert len(d) == 36
    # A near-duplicate center keeps the factor valid (block update or jittered refactor).
    d.append(d.centers[3] + 1e-9)
    check()
    # The ALD residual is the squared RKHS distance of k(s,·) from the span of the dictionary.
    s = rng.uniform(-1, 1, 3)
    kvec, coeffs, delta = d.ald(s)
    resid = np.concatenate([[1.0], -coeffs])
    exact = float(resid @ kernel(np.vstack([s, d.centers]), np.vstack([s, d.centers])) @ resid)
    assert delta == pytest.approx(exact, abs=1e-6)
    # A center's removal residual is its own ALD residual against the others.
    j = 11
    others = KernelDictionary(kernel)
    for c in np.delete(d.centers, j, axis=0):
        others.append(c)
    assert d.removal_residuals()[j] == pytest.approx(others.ald(d.centers[j])[2], rel=1e-4, abs=1e-8)


@pytest.mark.parametrize("budget, ald, n_adds", [(25, 0.05, 2000), (20, 0.0, 1200)])
def test_sparsification_respects_budget_and_error_bound(budget, ald, n_adds):
    """After thousands of adds the size stays ≤ budget, and ‖f_exact - f‖_H ≤ error_bound."""
    rng = np.random.default_rng(3)
    kernel = GaussianKernel(np.array([0.3, 0.5]), 2)
    f = RKHSFunction(kernel, 1, budget=budget, ald_threshold=ald)
    all_s, all_g = [], []
    shapes = set()
    for t in range(n_adds):
        s, g = rng.uniform(-1, 1, 2), rng.normal(size=1)
        f.add(s, g)
        all_s.append(s)
        all_g.append(g)
        assert len(f) <= budget
        if t > n_adds // 3:
            shapes.add(
                (
                    f.weights.shape,
                    f.dictionary.gram.shape,
                    f.dictionary.chol.shape,
                    f.dictionary.centers.shape,
                )
            )
        if t in (199, n_adds // 2, n_adds - 1):
            # The exact function Σ_t k(s_t,·) g_t minus the sparse one, over all points' Gram matrix.
            points = np.vstack([np.array(all_s), f.dictionary.centers])
            weights = np.vstack([np.array(all_g), -f.weights])
            err = np.sqrt(max(_rkhs_norm2(kernel, points, weights), 0.0))
            assert err <= f.error_bound + 1e-6, (t, err, f.error_bound)
    assert len(f) == budget  # the budget is reached and held
    # Memory stops growing: every array has one fixed shape once the budget is full.
    assert len(shapes) == 1
    ((w_shape, gram_shape, chol_shape, c_shape),) = shapes
    assert w_shape == (budget, 1) and gram_shape == chol_shape == (budget, budget) and c_shape == (budget, 2)
    # The bound is not vacuous: the sparse function is still close relative to the exact one's size.
    points = np.vstack([np.array(all_s), f.dictionary.centers])
    assert f.error_bound > 0
    exact_norm = np.sqrt(_rkhs_norm2(kernel, np.array(all_s), np.array(all_g)))
    err = np.sqrt(max(_rkhs_norm2(kernel, points, np.vstack([np.array(all_g), -f.weights])), 0.0))
    assert err < exact_norm


@pytest.mark.parametrize("budget, ald", [(15, 0.05), (12, 0.0)])
def test_each_approximation_adds_its_own_rkhs_error_to_the_bound(budget, ald):
    """Per add: ‖(f_before + k(s,·)g) - f_after‖_H equals the increment of ``error_bound``.

    Covers both approximations: the ALD projection (error √δ‖g‖) and the pruning (error ‖w_j‖√δ_j).
    """
    rng = np.random.default_rng(6)
    kernel = GaussianKernel(np.array([0.3, 0.5]), 2)
    f = RKHSFunction(kernel, 1, budget=budget, ald_threshold=ald)
    projections = prunes = 0
    for _ in range(400):
        s, g = rng.uniform(-1, 1, 2), rng.normal(size=1)
        c0, w0, b0, n0 = f.dictionary.centers.copy(), f.weights.copy(), f.error_bound, len(f)
        f.add(s, g)
        points = np.vstack([c0, s, f.dictionary.centers])
        weights = np.vstack([w0, g[None], -f.weights])
        err = np.sqrt(max(_rkhs_norm2(kernel, points, weights), 0.0))
        step = f.error_bound - b0
        assert err <= step * 1.01 + 1e-7, (err, step)
        assert err >= step * 0.99 - 1e-7, (err, step)
        unchanged = c0.shape == f.dictionary.centers.shape and np.array_equal(c0, f.dictionary.centers)
        projections += unchanged
        prunes += n0 == budget and not unchanged
    assert prunes > 50
    if ald > 0:
        assert projections > 10


def test_error_bound_holds_with_scaling_like_weight_decay():
    """Scaling by a factor ≤ 1 (the policy's weight decay) keeps the bound valid."""
    rng = np.random.default_rng(4)
    kernel = GaussianKernel(0.4, 2)
    f = RKHSFunction(kernel, 2, budget=30, ald_threshold=0.05)
    all_s, all_g = [], []
    for t in range(1500):
        if t % 10 == 0:
            f.scale(0.97)
            all_g = [0.97 * g for g in all_g]
        s, g = rng.uniform(-1, 1, 2), rng.normal(size=2)
        f.add(s, g)
        all_s.append(s)
        all_g.append(g)
    points = np.vstack([np.array(all_s), f.dictionary.centers])
    err = np.sqrt(max(_rkhs_norm2(kernel, points, np.vstack([np.array(all_g), -f.weights])), 0.0))
    assert len(f) <= 30
    assert err <= f.error_bound + 1e-6


def test_rkhs_function_state_round_trip():
    rng = np.random.default_rng(5)
    kernel = GaussianKernel(0.4, 2)
    f = _random_function(rng, kernel, 30, out_dim=1)
    g = RKHSFunction(kernel, 1, budget=1000, ald_threshold=0.01)
    g.load_state_dict(f.state_dict())
    for _ in range(5):
        s = rng.uniform(-1, 1, 2)
        np.testing.assert_array_equal(f(s), g(s))
    assert g.error_bound == f.error_bound
    with pytest.raises(ValueError, match="budget"):
        RKHSFunction(kernel, 1, budget=0, ald_threshold=0.1)


def test_dictionary_solves_give_scipys_numbers_and_name_a_singular_factor():
    """The dictionary calls LAPACK directly (scipy's wrappers cost more than the solve): the same numbers
    as ``solve_triangular`` / ``cho_solve``, bit for bit, and a singular factor is an error, not garbage."""
    from scipy.linalg import cho_solve, solve_triangular

    from learner.dictionary import _cholesky_solve, _triangular_solve

    rng = np.random.default_rng(4)
    a = rng.normal(size=(40, 40))
    chol = np.linalg.cholesky(a @ a.T + 40 * np.eye(40))
    b = rng.normal(size=40)
    half = _triangular_solve(chol, b)
    assert np.array_equal(half, solve_triangular(chol, b, lower=True))
    back = solve_triangular(chol.T, half, lower=False)
    assert np.array_equal(_triangular_solve(chol, half, transposed=True), back)
    assert np.array_equal(_cholesky_solve(chol, b), cho_solve((chol, True), b))
    assert np.array_equal(_cholesky_solve(chol, np.eye(40)), cho_solve((chol, True), np.eye(40)))
    singular = chol.copy()
    singular[7, 7] = 0.0
    with pytest.raises(np.linalg.LinAlgError, match="zero pivot at 7"):
        _triangular_solve(singular, b)


def test_the_one_solve_ald_test_and_its_reuse_give_the_two_solve_numbers():
    """``residual`` (one triangular solve), ``coefficients`` from its half, and ``append`` taking that half
    give exactly what ``ald`` and ``append`` compute on their own; ``refresh`` reproduces a refactor."""
    rng = np.random.default_rng(6)
    kernel = GaussianKernel(np.array([0.4, 0.6, 0.5]), 3)
    a, b = KernelDictionary(kernel), KernelDictionary(kernel)
    for _ in range(60):
        s = rng.uniform(-1, 1, 3)
        kvec, coeffs, delta = a.ald(s)
        k2, half, d2 = b.residual(s)
        assert np.array_equal(kvec, k2) and delta == d2
        assert np.array_equal(coeffs, b.coefficients(half))
        if delta > 0.05:
            a.append(s, kvec)
            b.append(s, k2, half)
            assert not b.fresh
    assert np.array_equal(a.chol, b.chol) and len(a) > 10
    b.refresh()
    assert b.fresh and np.array_equal(b.chol, np.linalg.cholesky(b.gram + b.jitter * np.eye(len(b))))
    before = b.chol
    b.refresh()  # already from scratch: left as it is
    assert b.chol is before
    a.remove(len(a) - 1)
    assert a.fresh
