"""Exploration and step-size schedules: linear from ``sigma``/``alpha`` to their finals, then constant;
the score keeps the initial ``Σ⁻¹``."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import sim  # noqa: F401  (registers the environments)
from learner.adaptiveh import AdaptiveH
from learner.config import AdaptiveHConfig


def _agent(**cfg) -> AdaptiveH:
    return AdaptiveH(gym.make("NSCartPoleContinuous-v0"), AdaptiveHConfig(h_max=5, **cfg), seed=0)


@pytest.mark.parametrize("steps", [100, 200, 300])
def test_schedules_are_linear_then_constant(steps):
    agent = _agent(sigma=0.4, sigma_final=0.1, alpha=0.02, alpha_final=0.005, schedule_steps=200)
    agent.learn(steps)
    # The schedule is set at the start of each step, so it reads the step count before the last one.
    frac = min((steps - 1) / 200, 1.0)
    half = agent.policy.half_range
    np.testing.assert_allclose(agent.policy.sigma, (0.4 - 0.3 * frac) * half)
    assert agent.alpha == pytest.approx(0.02 - 0.015 * frac)


def test_without_finals_nothing_moves():
    agent = _agent(sigma=0.4, alpha=0.02)
    agent.learn(150)
    np.testing.assert_allclose(agent.policy.sigma, 0.4 * agent.policy.half_range)
    assert agent.alpha == 0.02


def test_the_score_keeps_the_initial_inverse_covariance():
    agent = _agent(sigma=0.4, sigma_final=0.1, schedule_steps=10)
    policy = agent.policy
    s = np.zeros(len(agent.normalize.centre))
    agent.learn(20)
    assert policy.sigma[0] == pytest.approx(0.1 * policy.half_range[0])
    raw = policy.mean(s) + 0.3
    initial_inv2 = 1.0 / (0.4 * policy.half_range) ** 2
    np.testing.assert_allclose(policy.score(s, raw), policy.half_range * initial_inv2 * 0.3)
