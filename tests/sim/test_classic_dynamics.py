"""At constant gravity / zero noise the NS envs are gymnasium's classic ones, step for step."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.classic_control.cartpole import CartPoleEnv
from gymnasium.utils import env_checker as ec
from gymnasium.utils.env_checker import check_env

import sim  # noqa: F401  (registers the environments)
from sim.cartpole import NSCartPoleContinuous
from sim.pendulum import NSPendulum


def _balance(obs: np.ndarray, rng: np.random.Generator, noise: float) -> int:
    """A bang-bang balancer with some randomness: keeps episodes long enough to reach the 500 cap."""
    x, x_dot, theta, theta_dot = obs
    push_right = theta + 0.5 * theta_dot + 0.01 * x + 0.05 * x_dot > 0
    if rng.random() < noise:
        push_right = not push_right
    return int(push_right)


@pytest.mark.parametrize("noise", [0.5, 0.1, 0.0])
def test_stationary_cartpole_matches_gymnasium_cartpole_step_for_step(noise):
    """a = ±1 on NSCartPoleContinuous equals actions 1/0 on CartPoleEnv from the same state, incl. flags."""
    rng = np.random.default_rng(0)
    ours = NSCartPoleContinuous(preset="stationary", seed=0)
    ref = CartPoleEnv()
    ref.reset(seed=0)
    steps = episodes = 0
    ended = {"terminated": 0, "truncated": 0}
    while steps < 600:
        obs, info = ours.reset(seed=episodes)
        assert info["gravity"] == 9.8
        ref.reset(seed=episodes)
        ref.state = np.array(ours.state, dtype=np.float64)
        ref.steps_beyond_terminated = None
        episodes += 1
        for t in range(1, 501):
            action = _balance(obs, rng, noise)
            obs, reward, terminated, truncated, info = ours.step(
                np.array([1.0 if action else -1.0], np.float32)
            )
            ref_obs, ref_reward, ref_terminated, _, _ = ref.step(action)
            steps += 1
            np.testing.assert_allclose(ours.state, ref.state, rtol=0, atol=1e-12)
            np.testing.assert_array_equal(obs, ref_obs)
            assert reward == ref_reward == 1.0
            assert terminated == ref_terminated
            assert info["gravity"] == 9.8
            # CartPole-v1's TimeLimit: truncated at step 500 unless it terminated there.
            assert truncated == (t == 500 and not ref_terminated)
            if terminated or truncated:
                ended["terminated" if terminated else "truncated"] += 1
                break
    if noise == 0.5:
        assert ended["terminated"] > 3  # terminations were compared
    if noise == 0.0:
        assert ended["truncated"] >= 1  # the 500-step cap was reached


def test_cartpole_action_in_between_scales_the_force():
    """a ∈ [-1, 1] scales force_mag; a = 0 is no force (the classic env cannot do this)."""
    env = NSCartPoleContinuous(preset="stationary", force_mag=10.0)
    env.reset(seed=0)
    start = np.array([0.0, 0.0, 0.0, 0.0])
    env.state = start.copy()
    env.step(np.array([0.0]))
    np.testing.assert_array_equal(env.state, start)  # upright, at rest, no force: stays put
    env.state = start.copy()
    env.step(np.array([0.5]))
    half = env.state.copy()
    env.state = start.copy()
    env.step(np.array([1.0]))
    np.testing.assert_allclose(env.state[3], 2 * half[3], rtol=1e-12)  # linear in the force here
    env.state = start.copy()
    env.step(np.array([7.0]))  # out-of-range actions are clipped to the box
    np.testing.assert_allclose(env.state[3], 2 * half[3], rtol=1e-12)


def test_stationary_pendulum_matches_gymnasium_pendulum_step_for_step():
    rng = np.random.default_rng(1)
    ours = NSPendulum(preset="stationary", seed=0)
    ref = gym.make("Pendulum-v1")  # with its 200-step TimeLimit
    for episode in range(3):
        obs, info = ours.reset(seed=episode)
        assert info["noise_bound"] == 0.0
        ref_obs, _ = ref.reset(seed=episode)
        ref.unwrapped.state = ours.state.copy()
        np.testing.assert_allclose(obs, ref.unwrapped._get_obs(), atol=1e-7)
        for t in range(1, 201):
            # Some torques beyond the limit. float64: gymnasium's step keeps the torque's dtype, so a
            # float32 torque would make it compute the torque term in float32 (1e-9 differences).
            u = rng.uniform(-2.5, 2.5, 1)
            obs, reward, terminated, truncated, info = ours.step(u)
            ref_obs, ref_reward, ref_terminated, ref_truncated, _ = ref.step(u)
            np.testing.assert_allclose(ours.state, ref.unwrapped.state, rtol=1e-13, atol=1e-13)
            np.testing.assert_array_equal(obs, ref_obs)
            assert reward == pytest.approx(float(ref_reward), rel=1e-12, abs=1e-12)
            assert terminated is False and ref_terminated is False
            assert truncated == ref_truncated == (t == 200)
            assert info["noise_bound"] == 0.0


def test_pendulum_transition_on_arrays_is_the_envs_step_row_by_row():
    """The benches' batched rollouts (``NSPendulum.transition``, ``observation``) replay the env exactly."""
    rng = np.random.default_rng(2)
    env = NSPendulum(preset="stationary", seed=0)
    starts = rng.uniform([-np.pi, -8.0], [np.pi, 8.0], (16, 2))
    torques = rng.uniform(-2.0, 2.0, 16)
    th, w, r = NSPendulum.transition(starts[:, 0], starts[:, 1], torques)
    rows = NSPendulum.observation(th, w)
    assert rows.shape == (16, 3)
    for i in range(16):
        env.reset(seed=i)
        env.state = starts[i].copy()
        obs, reward, *_ = env.step(torques[i : i + 1])
        assert (th[i], w[i], r[i]) == (*env.state, reward)
        np.testing.assert_array_equal(rows[i].astype(np.float32), obs)


def test_pendulum_observation_delay_returns_older_observations():
    delayed = NSPendulum(preset="stationary", obs_delay=2)
    clean = NSPendulum(preset="stationary", obs_delay=0)
    d_obs, _ = delayed.reset(seed=3)
    c_obs, _ = clean.reset(seed=3)
    history = [c_obs]
    np.testing.assert_array_equal(d_obs, c_obs)  # nothing older yet
    for t in range(1, 20):
        u = np.array([np.sin(t)], np.float32)
        d_obs, *_ = delayed.step(u)
        c_obs, *_ = clean.step(u)
        history.append(c_obs)
        np.testing.assert_array_equal(d_obs, history[max(t - 2, 0)])


# The only warnings check_env may raise: unbounded velocities in CartPole's observation space (as in
# gymnasium's own CartPole) and Pendulum's [-2, 2] torque box (as in gymnasium's own Pendulum).
KNOWN_WARNINGS = ("infinity", "symmetric and normalized space")


def _no_unexpected_warnings(record) -> None:
    unexpected = [str(w.message) for w in record if not any(k in str(w.message) for k in KNOWN_WARNINGS)]
    assert not unexpected, unexpected


@pytest.mark.parametrize("env_id", ["NSCartPoleContinuous-v0", "NSPendulum-v0"])
def test_env_checker_passes_on_the_stationary_preset(env_id):
    env = gym.make(env_id, preset="stationary", seed=0).unwrapped
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        check_env(env, skip_render_check=True)
    _no_unexpected_warnings(record)


@pytest.mark.parametrize("env_id", ["NSCartPoleContinuous-v0", "NSPendulum-v0"])
@pytest.mark.parametrize("preset", ["slow", "fast"])
def test_env_checker_passes_on_drifting_presets_except_step_determinism(env_id, preset):
    """Every check of ``check_env`` but ``check_step_determinism``: a reset does not rewind the global
    clock (by design), so the same seed and action a few ticks later meet a different gravity/noise.
    Given the same clock, the step is deterministic (checked below)."""
    env = gym.make(env_id, preset=preset, seed=0).unwrapped
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        ec.check_action_space(env.action_space)
        ec.check_space_limit(env.action_space, "action")
        ec.check_observation_space(env.observation_space)
        ec.check_space_limit(env.observation_space, "observation")
        ec.check_seed_deprecation(env)
        ec.check_reset_return_info_deprecation(env)
        ec.check_reset_return_type(env)
        ec.check_reset_seed_determinism(env)
        ec.check_reset_options(env)
        ec.env_reset_passive_checker(env)
        ec.env_step_passive_checker(env, env.action_space.sample())
        ec.check_returned_data_not_reused(env)
    _no_unexpected_warnings(record)
    # Step determinism with the clock held: same clock state, seed and action -> same everything.
    clock = env.get_state()["schedule"]
    action = env.action_space.sample()
    results = []
    for _ in range(2):
        schedule = env.gravity_schedule if hasattr(env, "gravity_schedule") else env.noise_schedule
        schedule.set_state(clock)
        env.reset(seed=7)
        results.append(env.step(action))
    assert ec.data_equivalence(results[0], results[1])


def test_registered_envs_construct_with_a_clear_error_for_a_bad_preset():
    with pytest.raises(ValueError, match="preset"):
        gym.make("NSCartPoleContinuous-v0", preset="wild")
    with pytest.raises(ValueError, match="preset"):
        gym.make("NSPendulum-v0", preset="wild")
    with pytest.raises(ValueError, match="force_mag"):
        NSCartPoleContinuous(force_mag=0.0)
    with pytest.raises(ValueError, match="obs_delay"):
        NSPendulum(obs_delay=-1)
