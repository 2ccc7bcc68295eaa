"""The plan retreat's learned tolerance (issue #33): calibrated on noise, quick on a changed world.

Stated rates, checked here: with an exact model and a noisy sensor, ``plan_false_alarm`` α = 1 % gives at
most 2 % retreats per judged tick (after 200 plans of warm-up); a jump of the reached state by 6 of its
usual spreads in one dimension is a retreat on the very tick it happens (and, once the tolerance's
memory is full, still after 50 ticks of it).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import sim  # noqa: F401  (registers the NS environments)
from learner.kernels import GaussianKernel
from learner.plan_tolerance import LearnedTolerance
from learner.registry import make_agent
from learner.retreat import RetreatCheck

DIM, H = 6, 10
SPREAD = np.array([0.001, 0.003, 0.01, 0.02, 0.05, 0.1])  # sensor noise per dimension, normalised units


def _check(false_alarm: float = 0.01) -> RetreatCheck:
    tolerance = LearnedTolerance(DIM, H, threshold=0.5, false_alarm=false_alarm)
    return RetreatCheck(GaussianKernel(5.0, DIM), "plan", 0.5, smoothing=1.0, plan_tolerance=tolerance)


def _tick(check: RetreatCheck, ahead: int, gap: np.ndarray) -> bool:
    """One judged tick: the field points one way everywhere (full gradient agreement), so the statistic
    is the tolerance's kernel term alone."""
    predicted = np.zeros(DIM)
    return check.push(predicted + gap, np.ones(DIM), predicted, predicted + gap, ahead=ahead)


def _warm(check: RetreatCheck, rng: np.random.Generator, plans: int = 200) -> None:
    """``plans`` plans of usual gaps, learned by the tolerance (the field needs no more history)."""
    for _ in range(plans):
        for ahead in range(1, H + 1):
            check.plan_tolerance.observe(ahead, np.zeros(DIM), SPREAD * rng.standard_normal(DIM))


def test_an_exact_model_with_a_noisy_sensor_retreats_at_the_stated_rate():
    rng = np.random.default_rng(0)
    check = _check()
    _warm(check, rng)
    fired = [
        _tick(check, ahead, SPREAD * rng.standard_normal(DIM))
        for _ in range(500)
        for ahead in range(1, H + 1)
    ]
    rate = float(np.mean(fired))
    assert rate <= 0.02, rate
    assert rate > 0.001, rate  # calibrated, not blind: the noise's own tail does reach the threshold
    # A fixed kernel as narrow as the stack's (2.5 cm-like on every dimension) fires on this noise at will.
    narrow = RetreatCheck(GaussianKernel(5.0, DIM), "plan", 0.5, smoothing=1.0, plan_tolerance=None)
    narrow.plan_tolerance.kernel = GaussianKernel(0.04, DIM)
    fixed = [_tick(narrow, 1, SPREAD * rng.standard_normal(DIM)) for _ in range(1000)]
    assert np.mean(fixed) > 5 * rate


def test_a_changed_world_is_a_retreat_on_the_tick_it_happens_and_stays_one():
    rng = np.random.default_rng(1)
    check = _check()
    _warm(check, rng, plans=2000)  # the tolerance's memory (2000 gaps a step) is full
    for dim in range(DIM):
        jump = np.zeros(DIM)
        jump[dim] = 6 * SPREAD[dim]
        assert _tick(check, 3, jump), dim
    persistent = np.zeros(DIM)
    persistent[2] = 6 * SPREAD[2]
    fired = [_tick(check, 3, persistent + 0.1 * SPREAD * rng.standard_normal(DIM)) for _ in range(50)]
    assert all(fired)  # the clipped update does not teach the tolerance to ignore a changed world


def test_nan_and_missing_states_are_refused_or_skipped_not_retreated_on():
    check = _check()
    tolerance = check.plan_tolerance
    _warm(check, np.random.default_rng(2), plans=30)
    before = tolerance.state_dict()
    bad = np.full(DIM, np.nan)
    with pytest.raises(ValueError, match="finite"):
        tolerance.value(2, np.zeros(DIM), bad)
    with pytest.raises(ValueError, match="finite"):
        tolerance.observe(2, np.zeros(DIM), bad)
    np.testing.assert_array_equal(tolerance.state_dict()["mean_square"], before["mean_square"])
    n = len(check.trace)
    assert not check.push(np.zeros(DIM), np.ones(DIM), None, None, ahead=2)  # no plan: nothing judged
    assert len(check.trace) == n


def test_before_any_history_only_the_gradients_judge_and_the_estimate_survives_a_checkpoint():
    check = _check()
    assert check.plan_tolerance.value(1, np.zeros(DIM), np.full(DIM, 10.0)) == 1.0  # nothing learned yet
    _warm(check, np.random.default_rng(3), plans=30)
    restored = _check()
    restored.load_state_dict(check.state_dict())
    gap = 3 * SPREAD
    assert restored.plan_tolerance.value(4, np.zeros(DIM), gap) == check.plan_tolerance.value(
        4, np.zeros(DIM), gap
    )
    # A step with too few samples borrows the nearest shorter one's spread, grown like a random walk.
    short = LearnedTolerance(DIM, H, threshold=0.5)
    for _ in range(20):
        short.observe(2, np.zeros(DIM), SPREAD)
    np.testing.assert_allclose(short.spread2(6), SPREAD**2 * 3)


def test_the_config_chooses_the_tolerance():
    env = gym.make("NSCartPoleContinuous-v0", preset="stationary")
    agent = make_agent("adaptiveh", env, 0, {"execution": "plan", "plan_tolerance": "learned", "h_max": 30})
    assert isinstance(agent.retreat.plan_tolerance, LearnedTolerance)
    assert agent.retreat.plan_tolerance.horizon == 30
    with pytest.raises(ValueError, match="plan_false_alarm"):
        make_agent(
            "adaptiveh", env, 0, {"execution": "plan", "plan_tolerance": "learned", "plan_false_alarm": 0.7}
        )
