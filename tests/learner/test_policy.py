"""The RKHS Gaussian policy: its mean stays in the box; the functional-gradient step ascends."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from learner.adaptiveh import AdaptiveH
from learner.config import AdaptiveHConfig
from learner.kernels import GaussianKernel
from learner.policy import RKHSGaussianPolicy


def _policy(rng, low, high, dim=3, budget=60):
    kernel = GaussianKernel(rng.uniform(0.1, 1.0, dim), dim)
    return RKHSGaussianPolicy(
        kernel, np.array(low), np.array(high), sigma=0.3, budget=budget, ald_threshold=0.01
    )


def test_policy_mean_stays_inside_the_action_box_for_any_weights():
    """Property test: random centers, huge random weights, states near and far."""
    rng = np.random.default_rng(0)
    for trial in range(60):
        low = rng.uniform(-5, 0, 2) - 0.01
        high = low + rng.uniform(0.02, 8, 2)
        pol = _policy(rng, low, high)
        scale = 10.0 ** rng.uniform(0, 12)
        for _ in range(30):
            pol.f.add(rng.uniform(-2, 2, 3), rng.normal(size=2) * scale)
        # Arbitrary weights too, not only those reachable through add().
        pol.f.weights = rng.normal(size=pol.f.weights.shape) * scale * rng.choice([-1, 1])
        for _ in range(40):
            s = rng.normal(size=3) * rng.choice([0.1, 1.0, 10.0])
            mu = pol.mean(s)
            assert np.all(np.isfinite(mu)), trial
            # Inside the box up to float rounding of centre ± half_range (tanh saturates to exactly ±1).
            tol = 1e-12 * (high - low)
            assert np.all(mu >= low - tol) and np.all(mu <= high + tol), (trial, mu, low, high)
            executed, raw = pol.sample(s, rng)
            assert np.all(executed >= low) and np.all(executed <= high)
            np.testing.assert_allclose(np.clip(raw, low, high), executed)


def test_one_functional_gradient_step_moves_the_mean_toward_a_better_action():
    """g = A · score(s, a): a positive advantage pulls μ(s) toward a, a negative one pushes it away."""
    rng = np.random.default_rng(1)
    for sign in (+1.0, -1.0):
        pol = _policy(rng, [-1.0], [1.0], dim=2)
        s = np.array([0.2, -0.3])
        a = np.array([0.6])
        before = pol.mean(s).copy()
        grad = sign * 1.0 * pol.score(s, a)
        pol.update([s], [grad], step=0.05, decay=0.0)
        after = pol.mean(s)
        moved_toward = abs(after[0] - a[0]) < abs(before[0] - a[0])
        assert moved_toward == (sign > 0)
        # The step is local: a far-away state is (nearly) unaffected.
        far = s + 10.0
        assert abs(pol.mean(far)[0]) < 1e-6


class OneStepBandit(gym.Env):
    """A contextual bandit: s ~ U[-1,1], one action, reward -(a - a*(s))², episode of one step."""

    def __init__(self, seed: int = 0):
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (1,), dtype=np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
        self._s = np.zeros(1)

    @staticmethod
    def optimum(s: np.ndarray) -> float:
        return 0.5 - 0.25 * float(s[0])  # inside the box, away from its edges: clipping plays no part

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._s = self.np_random.uniform(-1, 1, 1)
        return self._s.copy(), {}

    def step(self, action):
        a = float(np.asarray(action).reshape(-1)[0])
        return self._s.copy(), -((a - self.optimum(self._s)) ** 2), True, False, {}


def _bandit_error(agent: AdaptiveH) -> float:
    grid = np.linspace(-0.9, 0.9, 19)
    return float(
        np.mean([abs(agent.predict(np.array([s]))[0] - OneStepBandit.optimum(np.array([s]))) for s in grid])
    )


def test_functional_gradient_learns_the_bandit_optimum():
    """AdaptiveH's per-sample functional gradient (value critic, TD error as advantage) finds a*(s)."""
    cfg = AdaptiveHConfig(gamma=0.5, alpha=0.01, sigma=0.2, bandwidth=0.5, policy_budget=40, critic_budget=40)
    agent = AdaptiveH(OneStepBandit(), cfg, seed=0)
    start = _bandit_error(agent)
    agent.learn(2500)
    errors = []
    for _ in range(5):  # SGD jitters: average the error over the last 500 steps
        agent.learn(100)
        errors.append(_bandit_error(agent))
    end = float(np.mean(errors))
    assert start == pytest.approx(0.5)
    assert end < start / 5, (start, errors)
    # It learned the context, not just a constant: a*(s) falls with s.
    lo, hi = agent.predict(np.array([-0.8]))[0], agent.predict(np.array([0.8]))[0]
    assert lo - hi == pytest.approx(0.4, abs=0.15)
    # Every episode is one step, so every segment is one step (it may end in a retreat on that step).
    assert all(s.H == 1 and s.reason in ("episode_end", "retreat") for s in agent.log.segments)
    assert len(agent.log.episodes) == len(agent.log.segments) == 3000
