"""The TD3/DDPG adapter honours the agent protocol: exact budgets, RunLog, save/load with replay buffer."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

pytest.importorskip("stable_baselines3")

import sim  # noqa: E402,F401
from learner.baselines import SB3Agent, SB3Config  # noqa: E402
from learner.protocol import Agent, RunLog  # noqa: E402
from learner.registry import make_agent  # noqa: E402

SMALL = {"net_arch": [32, 32], "learning_starts": 50, "batch_size": 32}


def _cartpole(seed: int = 0) -> gym.Env:
    return gym.make("NSCartPoleContinuous-v0", preset="fast", seed=seed)


@pytest.mark.parametrize("algo", ["td3", "ddpg"])
def test_learn_runs_exact_budget_and_records_episodes(algo: str) -> None:
    agent = make_agent(algo, _cartpole(), 0, SMALL)
    assert isinstance(agent, Agent)
    calls: list[int] = []
    log = agent.learn(333, callback=lambda step, lg: calls.append(step))
    assert isinstance(log, RunLog)
    # SB3 with train_freq=(1, "episode") would overshoot to the episode's end; the adapter must not.
    assert log.global_step == 333 == agent.model.num_timesteps
    assert calls == list(range(1, 334))
    assert agent.model.replay_buffer.size() == 333  # the last transition is stored too
    eps = log.episodes
    assert len(eps) >= 3
    assert [e.episode for e in eps] == list(range(len(eps)))
    assert all(a.global_step < b.global_step for a, b in zip(eps, eps[1:], strict=False))
    assert sum(e.length for e in eps) <= 333
    assert eps[-1].global_step == sum(e.length for e in eps)
    for e in eps:
        assert e.ret == pytest.approx(float(e.length))  # NS CartPole pays +1 per step
        assert 0.5 * 9.8 <= e.info["gravity"] <= 1.5 * 9.8
    agent.learn(17)
    assert agent.log.global_step == 350


def test_callback_false_stops_learning() -> None:
    agent = SB3Agent("td3", _cartpole(), SMALL, seed=1)
    agent.learn(500, callback=lambda step, lg: step < 40)
    assert agent.log.global_step == 40
    assert agent.model.replay_buffer.size() == 40


def test_training_changes_the_policy_after_learning_starts() -> None:
    agent = SB3Agent("ddpg", _cartpole(), SMALL, seed=0)
    before = [p.detach().clone() for p in agent.model.actor.parameters()]
    agent.learn(49)  # below learning_starts: no gradient step yet
    assert all(torch.equal(a, b) for a, b in zip(before, agent.model.actor.parameters(), strict=True))
    agent.learn(60)
    assert not all(torch.equal(a, b) for a, b in zip(before, agent.model.actor.parameters(), strict=True))


@pytest.mark.parametrize("algo", ["td3", "ddpg"])
def test_save_load_roundtrip_resumes(tmp_path: Path, algo: str) -> None:
    agent = SB3Agent(algo, _cartpole(3), SMALL, seed=3)
    agent.learn(210)
    path = tmp_path / "agent.zip"
    agent.save(path)
    assert path.is_file() and not list(tmp_path.glob("*.tmp"))

    clone = SB3Agent(algo, _cartpole(99), None, seed=99)  # different seed/config: load must override
    clone.load(path)
    assert clone.config == agent.config and clone.seed == 3
    assert clone.log.to_dict() == agent.log.to_dict()
    assert clone.model.num_timesteps == 210
    assert clone.model.replay_buffer.size() == 210
    np.testing.assert_array_equal(
        clone.model.replay_buffer.observations[:210], agent.model.replay_buffer.observations[:210]
    )
    # The drift clock travels with the agent: the fresh env continues the saved env's schedule.
    assert clone.env.unwrapped.gravity_schedule.t == agent.env.unwrapped.gravity_schedule.t == 210
    rng = np.random.default_rng(0)
    for obs in rng.uniform(-0.2, 0.2, size=(5, 4)).astype(np.float32):
        np.testing.assert_allclose(clone.predict(obs), agent.predict(obs), rtol=0, atol=1e-6)
    clone.learn(90)
    assert clone.log.global_step == 300 and clone.model.replay_buffer.size() == 300
    assert len(clone.log.episodes) >= len(agent.log.episodes)


def test_load_rejects_other_algorithm(tmp_path: Path) -> None:
    agent = SB3Agent("td3", _cartpole(), SMALL, seed=0)
    agent.learn(5)
    agent.save(tmp_path / "td3.zip")
    with pytest.raises(ValueError, match="not a saved ddpg agent"):
        SB3Agent("ddpg", _cartpole(), SMALL, seed=0).load(tmp_path / "td3.zip")


def test_defaults_are_the_zoo_pendulum_values_with_stated_change() -> None:
    cfg = SB3Config()
    assert (cfg.gamma, cfg.buffer_size, cfg.noise_std, cfg.learning_rate, cfg.net_arch) == (
        0.98,
        200_000,
        0.1,
        1e-3,
        [400, 300],
    )
    assert cfg.learning_starts == 1_000  # zoo: 10 000, lowered for non-stationarity (module docstring)
    model = SB3Agent("td3", gym.make("Pendulum-v1"), None, seed=0).model
    assert model.gamma == 0.98 and model.learning_starts == 1_000
    assert model.train_freq.frequency == 1 and model.train_freq.unit.value == "episode"
    assert model.gradient_steps == -1 and model.policy_kwargs["net_arch"] == [400, 300]
    assert torch.get_num_threads() == 1


@pytest.mark.parametrize(
    "bad",
    [{"gamma": 1.0}, {"buffer_size": 0}, {"gradient_steps": 0}, {"net_arch": []}, {"noise_std": -0.1}],
)
def test_config_validation(bad: dict) -> None:
    with pytest.raises(ValueError):
        SB3Config(**bad)


def test_rejects_unknown_algo_and_discrete_actions() -> None:
    with pytest.raises(ValueError, match="algo must be one of"):
        SB3Agent("a2c", _cartpole(), SMALL)  # sac and ppo are adapted too (the paper bench runs them)
    with pytest.raises(ValueError, match="continuous"):
        SB3Agent("td3", gym.make("CartPole-v1"), SMALL)
