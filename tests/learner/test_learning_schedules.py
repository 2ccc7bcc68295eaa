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


def _episodes(agent: AdaptiveH, successes: list[bool], length: int = 10) -> None:
    for success in successes:
        agent.log.global_step += length
        agent._finish_episode({"success": float(success)}, -1.0, length)


def test_a_gated_schedule_runs_only_through_episodes_that_end_with_the_gate_open():
    agent = _agent(sigma=0.4, sigma_final=0.1, schedule_steps=200, schedule_gate=0.5)
    _episodes(agent, [True] * 19)  # no full window of 20 episodes yet
    _episodes(agent, [False] * 20)  # 19 of the last 20 succeeded, 18, ..., 10 (open), then 9 ... 0: shut
    assert agent.gated_steps == 100
    _episodes(agent, [True] * 12)  # 1 ... 9 of 20: shut; 10, 11, 12: open
    assert agent.gated_steps == 130 and agent.schedule_clock() == 130 and agent.log.global_step == 510
    agent._schedule()
    np.testing.assert_allclose(agent.policy.sigma, (0.4 - 0.3 * 130 / 200) * agent.policy.half_range)


def test_without_a_gate_the_schedule_runs_through_every_step():
    agent = _agent(sigma=0.4, sigma_final=0.1, schedule_steps=100)
    _episodes(agent, [False] * 3)
    assert agent.schedule_clock() == 30 and agent.gated_steps == 0


def test_the_gated_clock_is_checkpointed_and_carries_a_handoff_on(tmp_path):
    agent = _agent(sigma=0.4, sigma_final=0.1, schedule_steps=100, schedule_gate=0.5)
    _episodes(agent, [True] * 22)
    agent.save(tmp_path / "checkpoint.pkl")
    resumed = _agent(sigma=0.4, sigma_final=0.1, schedule_steps=100, schedule_gate=0.5)
    resumed.load(tmp_path / "checkpoint.pkl")
    assert resumed.schedule_clock() == 30
    handed = _agent(sigma=0.4, sigma_final=0.1, schedule_steps=100)
    came = handed.start_from(tmp_path / "checkpoint.pkl")
    assert came["steps"] == 220 and handed.schedule_offset == 30  # trained 220 steps, 30 of them gated


def test_a_gate_on_an_env_without_success_is_an_error():
    agent = _agent(sigma=0.4, sigma_final=0.1, schedule_gate=0.5)  # NS CartPole reports no success
    with pytest.raises(ValueError, match="report no success"):
        agent.learn(600)
