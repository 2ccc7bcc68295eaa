"""The non-stationarity: bounded, seeded, on a global clock that episodes do not reset, hidden in info."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import sim  # noqa: F401  (registers the environments)
from sim.cartpole import GRAVITY_PRESETS, NSCartPoleContinuous
from sim.pendulum import NOISE_PRESETS, NSPendulum
from sim.schedules import DriftConfig, DriftSchedule

PRESETS = [("gravity", name, cfg) for name, cfg in GRAVITY_PRESETS.items()] + [
    ("noise", name, cfg) for name, cfg in NOISE_PRESETS.items()
]
TICKS = 200_000


def _trace(config: DriftConfig, seed: int, ticks: int) -> tuple[np.ndarray, np.ndarray]:
    """(value, walk) at every tick of the clock.

    ``value`` costs ~15 µs (scalar numpy), so it is read every 20th tick and the other ticks are
    rebuilt from the schedule's own (t, walk, jump) with the documented formula, which must agree
    with ``value`` wherever both exist.
    """
    sched = DriftSchedule(config, seed)
    walks, jumps = np.empty(ticks), np.empty(ticks)
    read = {}
    for t in range(ticks):
        sched.advance()
        walks[t], jumps[t] = sched.walk, sched.jump
        if t % 20 == 0 or t == ticks - 1:
            read[t] = sched.value
    assert sched.t == ticks
    clock = np.arange(1, ticks + 1)
    wave = config.amplitude * np.sin(2 * np.pi * clock / config.period + sched.phase)
    values = np.clip(config.base + wave + walks + jumps, config.low, config.high)
    idx = np.array(sorted(read))
    np.testing.assert_allclose(values[idx], [read[i] for i in idx], rtol=1e-12, atol=1e-12)
    return values, walks


@pytest.fixture(scope="module")
def traces() -> dict[str, np.ndarray]:
    """Each preset over 200k ticks, computed once for the module."""
    return {f"{kind}:{name}": _trace(cfg, seed=11, ticks=TICKS) for kind, name, cfg in PRESETS}


@pytest.mark.parametrize("kind, name, config", PRESETS, ids=[f"{k}:{n}" for k, n, _ in PRESETS])
def test_schedules_stay_in_bounds_over_200k_ticks(traces, kind, name, config):
    values, walks = traces[f"{kind}:{name}"]
    assert np.all(np.isfinite(values))
    assert values.min() >= config.low and values.max() <= config.high
    # The reflected walk stays inside the band on its own, not only through the final clip.
    assert np.all(np.abs(walks) <= (config.high - config.low) / 2 + 1e-12)
    if name == "stationary":
        assert np.all(values == config.base)
    else:
        # A drifting preset really drifts: it sweeps much of its band and is not stuck at a bound.
        assert values.max() - values.min() > 0.5 * (config.high - config.low)
        at_bound = np.mean((values == config.low) | (values == config.high))
        assert at_bound < 0.5, at_bound


def test_fast_presets_change_faster_than_slow_ones(traces):
    for kind in ("gravity", "noise"):
        slow = np.abs(np.diff(traces[f"{kind}:slow"][0])).mean()
        fast = np.abs(np.diff(traces[f"{kind}:fast"][0])).mean()
        assert fast > 3 * slow, (kind, slow, fast)


@pytest.mark.parametrize("kind, name, config", PRESETS, ids=[f"{k}:{n}" for k, n, _ in PRESETS])
def test_schedules_are_reproducible_by_seed(kind, name, config):
    a, _ = _trace(config, seed=5, ticks=3000)
    b, _ = _trace(config, seed=5, ticks=3000)
    c, _ = _trace(config, seed=6, ticks=3000)
    np.testing.assert_array_equal(a, b)
    if name == "stationary":
        np.testing.assert_array_equal(a, c)
    else:
        assert not np.array_equal(a, c)


def test_schedule_state_round_trip_continues_identically():
    cfg = GRAVITY_PRESETS["fast"]
    a = DriftSchedule(cfg, 3)
    for _ in range(1234):
        a.advance()
    b = DriftSchedule(cfg, 99)
    b.set_state(a.get_state())
    for _ in range(2500):
        a.advance()
        b.advance()
        assert a.value == b.value


def test_drift_config_rejects_bad_values():
    with pytest.raises(ValueError, match="base"):
        DriftConfig(base=20.0, low=0.0, high=10.0)
    with pytest.raises(ValueError, match="period"):
        DriftConfig(base=1.0, low=0.0, high=2.0, period=0)
    with pytest.raises(ValueError, match="amplitude"):
        DriftConfig(base=1.0, low=0.0, high=2.0, amplitude=-1.0)


@pytest.mark.parametrize(
    "env_id, key, presets",
    [
        ("NSCartPoleContinuous-v0", "gravity", GRAVITY_PRESETS),
        ("NSPendulum-v0", "noise_bound", NOISE_PRESETS),
    ],
)
def test_global_clock_does_not_reset_with_episodes(env_id, key, presets):
    """After several resets, the value at global step t equals a fresh schedule advanced t times."""
    env = gym.make(env_id, preset="fast", seed=4)
    reference = DriftSchedule(presets["fast"], 4)
    rng = np.random.default_rng(0)
    obs, info = env.reset(seed=0)
    assert info[key] == reference.value
    resets = 0
    for t in range(1, 2001):
        obs, _, terminated, truncated, info = env.step(env.action_space.sample())
        reference.advance()
        assert info[key] == reference.value, t
        if terminated or truncated or rng.random() < 0.02:  # also resets mid-episode
            obs, info = env.reset(seed=int(rng.integers(1000)))
            resets += 1
            assert info[key] == reference.value, t  # a reset does not touch the clock
    assert resets > 10
    assert len({reference.value, DriftSchedule(presets["fast"], 4).value}) == 2  # it moved


def test_gravity_is_in_info_not_in_the_observation():
    """Same state, different gravity: identical observation; the gravity only shows in info."""
    low_g = NSCartPoleContinuous(drift=DriftConfig(base=5.0, low=5.0, high=5.0))
    high_g = NSCartPoleContinuous(drift=DriftConfig(base=15.0, low=15.0, high=15.0))
    obs_a, info_a = low_g.reset(seed=1)
    obs_b, info_b = high_g.reset(seed=1)
    np.testing.assert_array_equal(obs_a, obs_b)
    assert obs_a.shape == low_g.observation_space.shape == (4,)
    assert (info_a["gravity"], info_b["gravity"]) == (5.0, 15.0)
    np.testing.assert_array_equal(obs_a, low_g.state.astype(np.float32))  # [x, ẋ, θ, θ̇] only
    # The gravity acts on the dynamics all the same: a tilted pole falls faster under more gravity.
    for env in (low_g, high_g):
        env.state = np.array([0.0, 0.0, 0.1, 0.0])
    a, *_ = low_g.step(np.array([0.0]))
    b, *_ = high_g.step(np.array([0.0]))
    for _ in range(5):
        a, *_ = low_g.step(np.array([0.0]))
        b, *_ = high_g.step(np.array([0.0]))
    assert b[3] > a[3] > 0


def test_pendulum_noise_is_bounded_by_the_drifting_bound_and_only_in_info():
    env = NSPendulum(preset="fast", seed=2)
    obs, info = env.reset(seed=0)
    assert obs.shape == env.observation_space.shape == (3,)
    seen = []
    for _ in range(3000):
        obs, _, _, truncated, info = env.step(env.action_space.sample())
        th, thdot = env.state
        clean = np.array([np.cos(th), np.sin(th), thdot])
        b = info["noise_bound"]
        assert np.all(np.abs(obs - clean) <= b + 1e-6)
        assert env.observation_space.contains(obs)
        seen.append(np.abs(obs - clean).max() / b if b > 0.01 else np.nan)
        if truncated:
            env.reset()
    # The noise fills its bound (uniform in [-b, b]), it is not a token perturbation.
    assert np.nanmax(seen) > 0.9
