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
from learner.plan_tolerance import FixedTolerance, LearnedTolerance, NoiseFloorTolerance, narrowest_scale
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


# The noise-floor tolerance (the default). Stated rates, checked below: a plan of a world at rest seen
# through a noisy sensor (the model exact, the gap the sensor's noise now minus its noise when the plan
# was made) retreats on at most 2 % of judged ticks with α = 1 % once 50 pairs of gap increments are
# known, where the bare fixed kernel fires on most of them; a jump of the world in one dimension by twice
# the widened width (``sqrt(w² + 2κ²σ̂²)``) is a retreat on the tick it happens; a world drifting at a
# constant rate is one within ``ceil(sqrt(2 ln(1/τ) (w² + 2κ²σ̂²)) / rate) + 1`` ticks (where it crosses
# the widened kernel).
WIDTH = 0.04  # the fixed kernel's width on every dimension (the stack's 2.5 cm-like tolerance)


def _floor_check(width: float = WIDTH) -> RetreatCheck:
    tolerance = NoiseFloorTolerance(np.full(DIM, width), threshold=0.5, false_alarm=0.01)
    return RetreatCheck(GaussianKernel(5.0, DIM), "plan", 0.5, smoothing=1.0, plan_tolerance=tolerance)


def _noisy_plan(
    check: RetreatCheck, rng: np.random.Generator, world=lambda i: np.zeros(DIM), spread: np.ndarray = SPREAD
) -> list[bool]:
    """One plan of H ticks through a noisy sensor: the model predicts the world as seen when the plan was
    made; ``world(i)`` is where the world really is ``i`` ticks in (at rest: zero)."""
    seen_at_start = spread * rng.standard_normal(DIM)
    fired = []
    for ahead in range(1, H + 1):
        reached = world(ahead) + spread * rng.standard_normal(DIM)
        fired.append(check.push(reached, np.ones(DIM), seen_at_start, reached, ahead=ahead))
    return fired


def test_noise_floor_an_exact_model_with_a_noisy_sensor_retreats_at_the_stated_rate():
    rng = np.random.default_rng(4)
    fixed = RetreatCheck(GaussianKernel(5.0, DIM), "plan", 0.5, smoothing=1.0, plan_tolerance=None)
    fixed.plan_tolerance = FixedTolerance(GaussianKernel(WIDTH, DIM))
    bare = np.mean([f for _ in range(200) for f in _noisy_plan(fixed, rng)])
    assert bare > 0.5, bare  # the noise alone is far outside the fixed kernel
    check = _floor_check()
    for _ in range(7):  # 56 pairs of increments: the noise is known
        _noisy_plan(check, rng)
    rate = float(np.mean([f for _ in range(1000) for f in _noisy_plan(check, rng)]))
    assert rate <= 0.02, rate
    np.testing.assert_allclose(np.sqrt(check.plan_tolerance.noise2()), SPREAD, rtol=0.15)
    # Calibrated, not blind: with (almost) no fixed width the noise's own tail reaches the threshold.
    bare_floor = _floor_check(1e-6)
    for _ in range(7):
        _noisy_plan(bare_floor, rng)
    rate = float(np.mean([f for _ in range(1000) for f in _noisy_plan(bare_floor, rng)]))
    assert 0.002 < rate <= 0.02, rate


def test_noise_floor_is_the_fixed_kernel_while_the_sensor_is_quiet():
    check = _floor_check()
    rng = np.random.default_rng(5)
    for _ in range(50):  # plans of a world at rest, seen exactly
        _noisy_plan(check, rng, spread=np.zeros(DIM))
    drift = np.full(DIM, 0.002)  # and plans whose model errs the same way every tick: not noise either
    for _ in range(50):
        _noisy_plan(check, rng, world=lambda i: drift * i, spread=np.zeros(DIM))
    np.testing.assert_array_equal(check.plan_tolerance.noise2(), np.zeros(DIM))
    gap = np.full(DIM, 0.03)
    expected = GaussianKernel(WIDTH, DIM).pair(np.zeros(DIM), gap)
    assert check.plan_tolerance.value(3, np.zeros(DIM), gap) == pytest.approx(expected)


def _warmed(seed: int, plans: int) -> tuple[np.random.Generator, RetreatCheck]:
    """A noise-floor check that has seen ``plans`` plans of a world at rest through the noisy sensor."""
    rng = np.random.default_rng(seed)
    check = _floor_check()
    for _ in range(plans):
        _noisy_plan(check, rng)
    return rng, check


def test_noise_floor_a_changed_world_is_a_retreat_within_the_stated_ticks():
    rng, check = _warmed(6, 200)
    tolerance = check.plan_tolerance
    width = np.sqrt(tolerance.width2())
    for dim in range(DIM):
        jump = np.zeros(DIM)
        jump[dim] = 2 * width[dim]
        fired = _noisy_plan(check, rng, world=lambda i, jump=jump: jump * (i >= 3))
        assert fired[2], (dim, fired)  # the tick it happened
    rate = np.zeros(DIM)
    rate[4] = 0.02  # per tick, in dimension 4 (noise 0.05)
    bound = int(np.ceil(np.sqrt(2 * np.log(2) * tolerance.width2()[4]) / rate[4])) + 1
    assert bound < 50, (bound, width)
    long_check = _floor_check()
    long_check.plan_tolerance.load_state_dict(tolerance.state_dict())
    start = SPREAD * rng.standard_normal(DIM)
    for ahead in range(1, bound + 1):
        reached = rate * ahead + SPREAD * rng.standard_normal(DIM)
        if long_check.push(reached, np.ones(DIM), start, reached, ahead=ahead):
            break
    else:
        pytest.fail(f"a world drifting {rate[4]} a tick was not a retreat within {bound} ticks")


def test_noise_floor_nan_and_missing_states_are_refused_not_learned_nor_retreated_on():
    rng, check = _warmed(7, 30)
    tolerance = check.plan_tolerance
    before = tolerance.state_dict()
    bad = np.full(DIM, np.nan)
    for ahead in (1, 4):
        with pytest.raises(ValueError, match="finite"):
            tolerance.value(ahead, np.zeros(DIM), bad)
        with pytest.raises(ValueError, match="finite"):
            check.push(bad, np.ones(DIM), np.zeros(DIM), bad, ahead=ahead)
    with pytest.raises(ValueError, match="6 finite values"):
        tolerance.observe(1, np.zeros(DIM), np.zeros(3))
    np.testing.assert_array_equal(tolerance.state_dict()["lag_product"], before["lag_product"])
    assert tolerance.state_dict()["count"] == before["count"]
    n = len(check.trace)
    assert not check.push(np.zeros(DIM), np.ones(DIM), None, None, ahead=2)  # no plan: nothing judged
    assert len(check.trace) == n
    assert np.mean([f for _ in range(300) for f in _noisy_plan(check, rng)]) <= 0.02  # no storm after


def test_the_plan_kernel_narrows_where_the_policy_kernel_is_narrowest():
    np.testing.assert_allclose(narrowest_scale(np.array([5.0, 5.0, 0.3, 0.3]), 0.15), [1, 1, 0.15, 0.15])
    np.testing.assert_allclose(narrowest_scale(np.full(3, 0.4), 0.15), [0.15] * 3)
    np.testing.assert_allclose(narrowest_scale(np.array([5.0, 0.3]), [0.5, 0.2]), [0.5, 0.2])


def test_noise_floor_is_chosen_by_the_config_with_the_policy_kernel_narrowed():
    env = gym.make("NSCartPoleContinuous-v0", preset="stationary")
    agent = make_agent(
        "adaptiveh", env, 0, {"execution": "plan", "plan_tolerance": "noise_floor", "plan_kernel_scale": 0.15}
    )
    tolerance = agent.retreat.plan_tolerance
    assert isinstance(tolerance, NoiseFloorTolerance)
    np.testing.assert_allclose(tolerance.width2(), (agent.kernel.bandwidth * 0.15) ** 2)
    restored = NoiseFloorTolerance(np.sqrt(tolerance.widths2), 0.5)
    for ahead in (1, 2, 3):
        tolerance.observe(ahead, np.zeros(tolerance.dim), np.full(tolerance.dim, 0.01 * (-1) ** ahead))
    restored.load_state_dict(tolerance.state_dict())
    assert restored.count == 1
    np.testing.assert_array_equal(restored.lag_product, tolerance.lag_product)
