"""The recursive kernel LSTD critic recovers known values and keeps its dictionary under budget."""

from __future__ import annotations

import numpy as np
import pytest

from learner.critic import KLSTDCritic
from learner.kernels import GaussianKernel

SPACING = 10.0  # states far apart relative to the bandwidth (1.0): the kernel features are one-hot


def _state(i: int) -> np.ndarray:
    return np.array([SPACING * i])


def _critic(gamma: float, budget: int = 50) -> KLSTDCritic:
    return KLSTDCritic(
        GaussianKernel(1.0, 1), gamma, budget, ald_threshold=0.1, forgetting=1.0, p0=100.0, mode="value"
    )


def test_klstd_recovers_the_values_of_a_deterministic_ring():
    """Ring 0→1→…→n-1→0 with rewards r: V = (I - γP)⁻¹ r."""
    n, gamma = 5, 0.9
    r = np.array([1.0, 0.0, -2.0, 0.5, 3.0])
    P = np.roll(np.eye(n), 1, axis=1)
    v_true = np.linalg.solve(np.eye(n) - gamma * P, r)
    critic = _critic(gamma)
    for t in range(3000):
        i = t % n
        critic.update(_state(i), r[i], _state((i + 1) % n), terminal=False)
    assert len(critic) == n
    v_hat = np.array([critic.value(_state(i)) for i in range(n)])
    np.testing.assert_allclose(v_hat, v_true, atol=0.05 * np.abs(v_true).max())
    # The TD error (the actor's advantage) has vanished at the fixed point.
    assert abs(critic.update(_state(2), r[2], _state(3), terminal=False)) < 0.05


def test_klstd_recovers_the_values_of_a_stochastic_chain_with_a_terminal_state():
    """A random-walk chain: step right w.p. 0.7 else left (reflecting at 0); leaving state n-1 ends it."""
    n, gamma, p_right = 4, 0.95, 0.7
    r = np.array([-1.0, -1.0, -1.0, 10.0])  # the reward of the transition out of each state
    P = np.zeros((n, n))
    for i in range(n):
        if i < n - 1:
            P[i, i + 1] += p_right
        P[i, max(i - 1, 0)] += 1 - p_right
    P[n - 1] = 0.0
    P[n - 1, n - 2] = 1 - p_right  # from the last state: terminate w.p. p_right, else step back
    v_true = np.linalg.solve(np.eye(n) - gamma * P, r)
    rng = np.random.default_rng(0)
    critic = _critic(gamma)
    i = 0
    for _ in range(6000):
        right = rng.random() < p_right
        if i == n - 1 and right:
            critic.update(_state(i), r[i], _state(i), terminal=True)
            i = 0
            continue
        j = min(i + 1, n - 1) if right else max(i - 1, 0)
        critic.update(_state(i), r[i], _state(j), terminal=False)
        i = j
    v_hat = np.array([critic.value(_state(k)) for k in range(n)])
    # Sampled transitions: LSTD converges to the empirical model's values; a few percent of the range.
    np.testing.assert_allclose(v_hat, v_true, atol=0.06 * np.abs(v_true).max())
    assert np.all(np.diff(v_hat) > 0)  # ordering: closer to the goal is worth more


def test_klstd_with_smooth_features_fits_a_continuous_value_function():
    """Overlapping kernels: a 1-D deterministic drift x → x + 0.05 with r(x) = x, γ = 0.5 on [0, 1]:
    V(x) = Σ_k γ^k (x + 0.05k) = x/(1-γ) + 0.05γ/(1-γ)² away from the end."""
    gamma = 0.5
    critic = KLSTDCritic(
        GaussianKernel(0.2, 1), gamma, budget=30, ald_threshold=0.01, forgetting=1.0, p0=100.0
    )
    rng = np.random.default_rng(1)
    for _ in range(4000):
        x = rng.uniform(0.0, 1.0)
        critic.update(np.array([x]), x, np.array([x + 0.05]), terminal=False)
    for x in (0.2, 0.4, 0.6, 0.8):
        expected = x / (1 - gamma) + 0.05 * gamma / (1 - gamma) ** 2
        assert critic.value(np.array([x])) == pytest.approx(expected, abs=0.05)


@pytest.mark.parametrize("mode", ["value", "compatible"])
def test_critic_dictionary_stays_under_budget_with_bounded_arrays(mode):
    rng = np.random.default_rng(2)
    budget = 15
    critic = KLSTDCritic(
        GaussianKernel(0.3, 2), 0.9, budget, ald_threshold=0.01, forgetting=0.99, mode=mode, action_dim=1
    )
    block = 1 if mode == "value" else 2
    for t in range(1500):
        s, s2 = rng.uniform(-1, 1, 2), rng.uniform(-1, 1, 2)
        score = rng.normal(size=1) if mode == "compatible" else None
        adv = critic.update(s, float(rng.normal()), s2, terminal=bool(t % 50 == 49), score=score)
        assert np.isfinite(adv)
        assert len(critic) <= budget
        assert critic.theta.shape == (len(critic) * block,)
        assert critic.P.shape == (len(critic) * block,) * 2
    assert len(critic) == budget
    assert np.all(np.isfinite(critic.theta)) and np.all(np.isfinite(critic.P))
    # P stays capped at its initial scale (no wind-up in unvisited regions).
    assert np.max(np.abs(np.diag(critic.P))) <= critic.p0 * (1 + 1e-9)


def test_critic_rejects_an_unknown_mode():
    with pytest.raises(ValueError, match="mode"):
        KLSTDCritic(GaussianKernel(0.3, 1), 0.9, 10, 0.1, mode="bogus")
