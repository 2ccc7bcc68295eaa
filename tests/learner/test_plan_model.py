"""The plan model corrected online (learner/plan_model.py): it learns a systematic error and uses it once
it predicts significantly better, leaves an exact model seen through noise alone, and skips what it
cannot learn from."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import tasks  # noqa: F401  (registers NS Reach)
from learner.config import AdaptiveHConfig
from learner.plan_model import CorrectedModel, NominalModel, plan_model
from learner.registry import make_agent

DIM, ACT = 4, 2
B = np.array([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5], [0.0, 0.0]])


def _nominal(obs: np.ndarray, action: np.ndarray) -> np.ndarray:
    return obs + B @ action


def _lagging(obs: np.ndarray, action: np.ndarray) -> np.ndarray:
    """The world: 70 % of the commanded step, plus a carry of a tenth of the state's first coordinate."""
    nxt = obs + 0.7 * (B @ action)
    nxt[0] += 0.1 * obs[0]
    return nxt


def _corrected(memory: int = 1000) -> CorrectedModel:
    return CorrectedModel(_nominal, lambda o: np.asarray(o, float), DIM, ACT, memory=memory)


def _errors(model, world, rng, steps: int, noise: float = 0.0) -> tuple[float, float]:
    """Mean squared one-step error of the nominal and of ``model`` on ``steps`` fresh steps after
    learning from as many."""
    for learn in (True, False):
        err_nom, err_model = [], []
        for _ in range(steps):
            obs, action = rng.normal(size=DIM), rng.normal(size=ACT)
            nxt = world(obs, action) + noise * rng.normal(size=DIM)
            err_nom.append(np.sum((nxt - _nominal(obs, action)) ** 2))
            err_model.append(np.sum((nxt - model(obs, action)) ** 2))
            if learn:
                model.observe(obs, action, nxt)
    return float(np.mean(err_nom)), float(np.mean(err_model))


def test_a_systematic_error_is_learned_and_used_within_ten_steps():
    model = _corrected()
    rng = np.random.default_rng(0)
    used = []
    for _ in range(10):
        obs, action = rng.normal(size=DIM), rng.normal(size=ACT)
        model.observe(obs, action, _lagging(obs, action))
        used.append(model.active)
    assert used[-1], used
    nominal, corrected = _errors(model, _lagging, rng, 500)
    assert corrected < 0.01 * nominal and model.active, (nominal, corrected)


def test_an_exact_model_seen_through_a_noisy_sensor_keeps_the_nominal_model():
    """The states and the next states both read with noise 5 % of the states' spread (NS Pendulum's is
    about that): a fit of the noise predicts the next reading no better, and plans never use it."""
    model = _corrected()
    rng = np.random.default_rng(1)
    used = []
    for _ in range(3000):
        x, action = rng.normal(size=DIM), rng.normal(size=ACT)
        seen, seen_next = x + 0.05 * rng.normal(size=DIM), _nominal(x, action) + 0.05 * rng.normal(size=DIM)
        model.observe(seen, action, seen_next)
        used.append(model.active)
    assert not any(used)
    obs, action = rng.normal(size=DIM), rng.normal(size=ACT)
    np.testing.assert_array_equal(model(obs, action), _nominal(obs, action))
    assert np.abs(model.W).max() < 0.02


def test_a_changed_world_is_forgotten_within_its_memory():
    model = _corrected(memory=200)
    rng = np.random.default_rng(2)
    _errors(model, _lagging, rng, 500)
    nominal, corrected = _errors(model, _nominal, rng, 1000)  # the world back to the nominal
    assert corrected < 0.01 * np.mean((0.3 * B @ rng.normal(size=(ACT, 100))) ** 2), (nominal, corrected)


def test_non_finite_steps_are_skipped_not_learned():
    model = _corrected()
    _errors(model, _lagging, np.random.default_rng(3), 50)
    before, updates = model.W.copy(), model.updates
    model.observe(np.full(DIM, np.nan), np.zeros(ACT), np.zeros(DIM))
    model.observe(np.zeros(DIM), np.zeros(ACT), np.array([0.0, np.inf, 0.0, 0.0]))
    np.testing.assert_array_equal(model.W, before)
    assert model.updates == updates
    with pytest.raises(ValueError, match="memory"):
        _corrected(memory=1)


def test_the_config_chooses_the_model_and_a_plan_run_teaches_it():
    assert isinstance(plan_model("nominal", _nominal, np.asarray, (DIM, ACT), 10), NominalModel)
    assert isinstance(plan_model("corrected", _nominal, np.asarray, (DIM, ACT), 10), CorrectedModel)
    env = gym.make("NSReach-v0", max_episode_steps=40)
    agent = make_agent("adaptiveh", env, 0, {"execution": "plan", "plan_model": "corrected"})
    agent.learn(60)
    assert isinstance(agent.model, CorrectedModel) and agent.model.updates >= 50
    assert np.abs(agent.model.W).max() > 0  # the simulated arm lags the commanded step: there is a residual
    env.close()
    assert AdaptiveHConfig().plan_model == "nominal"
