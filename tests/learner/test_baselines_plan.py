"""TD3/DDPG/SAC in plan mode (``plan_h``): plan_h 1 is SB3's closed loop bit for bit, and so is the plan
machinery at H = 1; with H > 1 every segment's actions are the policy's over the model's predictions
from the segment's first observation, re-planned every H steps and at episode starts, the replay buffer
holds what was executed, and an episode's end drops (and counts) the rest of the plan."""

from __future__ import annotations

import copy
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

pytest.importorskip("stable_baselines3")

import sim  # noqa: E402,F401
from learner.baselines import SB3Agent  # noqa: E402
from learner.baselines_plan import PlanQueue, PlanSAC, PlanTD3  # noqa: E402
from learner.config import PPOConfig, SACConfig, SB3Config  # noqa: E402
from learner.registry import make_agent  # noqa: E402

SMALL = {"net_arch": [32, 32], "learning_starts": 50, "batch_size": 32}


class Recorder(gym.Wrapper):
    """Keeps every action the env is stepped with (what was executed)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.actions: list[np.ndarray] = []

    def step(self, action):
        self.actions.append(np.array(action, dtype=float).reshape(-1))
        return self.env.step(action)


def _cartpole(preset: str = "fast", seed: int = 0) -> Recorder:
    return Recorder(gym.make("NSCartPoleContinuous-v0", preset=preset, seed=seed))


def _buffer(agent: SB3Agent, n: int) -> tuple[np.ndarray, np.ndarray]:
    rb = agent.model.replay_buffer
    return rb.observations[:n, 0].copy(), rb.actions[:n, 0].copy()


def _returns(agent: SB3Agent) -> list[tuple[int, float]]:
    return [(e.global_step, e.ret) for e in agent.log.episodes]


@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_plan_h_1_is_the_closed_loop_bit_for_bit(algo: str) -> None:
    """plan_h 1 builds SB3's own class; the plan machinery forced to H = 1 replays the same run."""

    def run(config: dict, h: int | None = None) -> SB3Agent:
        agent = make_agent(algo, _cartpole(), 4, config)  # SB3 seeds the global RNGs: build, then learn
        if h is not None:
            agent.channel.h = h  # plan one action at the real observation: the closed loop, via plans
        agent.learn(250)
        return agent

    default = run(SMALL)
    explicit = run({**SMALL, "plan_h": 1})
    machinery = run({**SMALL, "plan_h": 2}, h=1)
    assert type(explicit.model) is type(default.model) and explicit.channel is None
    assert isinstance(machinery.model, PlanTD3 if algo == "td3" else PlanSAC)
    obs, act = _buffer(default, 250)
    for other in (explicit, machinery):
        o, a = _buffer(other, 250)
        np.testing.assert_array_equal(o, obs)
        np.testing.assert_array_equal(a, act)
        np.testing.assert_array_equal(np.asarray(other.env.actions), np.asarray(default.env.actions))
        assert _returns(other) == _returns(default) and len(default.log.episodes) >= 3
    assert default.log.segments == [] == explicit.log.segments  # the closed loop records no segments
    assert [s.H for s in machinery.log.segments] == [1] * 250
    assert machinery.channel.dropped_planned == 0


def test_segment_actions_are_the_actors_over_the_models_predictions() -> None:
    """TD3 without noise and without training while it collects: each executed segment is exactly the
    actor's plan over the model's rollout from the segment's first real observation. The model here is
    deliberately wrong (a bias on the pole's angular velocity), so a policy asked at the real states
    would have acted otherwise."""
    env = _cartpole()
    base = env.unwrapped
    nominal = base.predict_next
    base.predict_next = lambda o, a: nominal(o, a) + np.array([0.0, 0.0, 0.0, 0.3])
    cfg = {**SMALL, "plan_h": 5, "noise_std": 0.0, "learning_starts": 0, "train_freq_episodes": 1000}
    agent = make_agent("td3", env, 1, cfg)
    actor = copy.deepcopy(agent.model.actor)  # no training happens while it collects (train_freq)
    policy = agent.model.policy
    agent.learn(200)
    executed = np.asarray(env.actions)
    obs, _ = _buffer(agent, 200)

    def act(o: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            scaled = actor(torch.as_tensor(o, dtype=torch.float32)[None]).numpy()
        return policy.unscale_action(scaled)[0]

    segments = agent.log.segments
    assert len(segments) >= 30
    differs = 0
    for seg in segments:
        start = seg.global_step - seg.H
        o = obs[start].astype(float)
        for i in range(seg.H):
            planned = act(o.astype(np.float32))
            np.testing.assert_allclose(executed[start + i], planned, rtol=0, atol=1e-5)
            differs += not np.allclose(act(obs[start + i]), planned, atol=1e-3)
            o = base.predict_next(o, planned)
    assert differs > 20  # not the actions of the real states: the policy saw the predictions


@pytest.mark.parametrize("algo", ["td3", "ddpg", "sac"])
def test_replans_every_h_steps_and_at_each_episode_start(algo: str) -> None:
    env = _cartpole(seed=2)
    agent = make_agent(algo, env, 2, {**SMALL, "plan_h": 7})
    agent.learn(300)
    segs, queue = agent.log.segments, agent.channel
    assert isinstance(queue, PlanQueue) and queue.latency == 0 and queue.preemptions == 0
    ends = [s.global_step for s in segs]
    starts = [0, *ends[:-1]]
    assert [s.index for s in segs] == list(range(len(segs)))
    assert all(e - b == s.H for b, e, s in zip(starts, ends, segs, strict=True))  # back to back
    assert all(s.H == 7 for s in segs if s.reason == "h_max")
    assert all(1 <= s.H < 7 for s in segs if s.reason == "episode_end")
    episode_ends = {e.global_step for e in agent.log.episodes}
    assert len(episode_ends) >= 3 and episode_ends <= set(ends)  # a new plan at every episode start
    assert {s.global_step for s in segs if s.reason == "episode_end"} <= episode_ends
    assert queue.dropped_planned == sum(7 - s.H for s in segs if s.reason == "episode_end") > 0
    assert queue.plans_made == len(segs) + queue.open and 300 - ends[-1] == queue.index
    # The replay buffer holds the executed actions (SB3's [-1, 1] scale) with the real observations.
    _, act = _buffer(agent, 300)
    np.testing.assert_allclose(agent.model.policy.scale_action(np.asarray(env.actions)), act, atol=1e-6)


def test_plan_mode_save_load_continues_with_a_fresh_plan(tmp_path: Path) -> None:
    agent = SB3Agent("td3", _cartpole(seed=3), {**SMALL, "plan_h": 6}, seed=3)
    agent.learn(100)
    agent.save(tmp_path / "agent.zip")
    clone = SB3Agent("td3", _cartpole(seed=3), SMALL, seed=3)  # closed loop until the file says otherwise
    clone.load(tmp_path / "agent.zip")
    assert clone.config.plan_h == 6 and isinstance(clone.model, PlanTD3)
    assert clone.channel is not None and clone.model.plan_queue is clone.channel and not clone.channel.open
    n = len(clone.log.segments)
    clone.learn(40)
    new = clone.log.segments[n:]
    assert new and new[0].index == n and new[0].global_step - new[0].H == 100  # a plan from the new episode
    assert all(s.H <= 6 for s in new) and clone.model.replay_buffer.size() == 140


def test_plan_h_is_validated_and_needs_a_world_model() -> None:
    for cls in (SB3Config, SACConfig):
        assert cls().plan_h == 1
        with pytest.raises(ValueError):
            cls(plan_h=0)
    with pytest.raises(ValueError):
        PPOConfig(plan_h=2)  # on-policy PPO has no plan mode
    with pytest.raises(ValueError, match="has no predict_next"):
        SB3Agent("td3", gym.make("Pendulum-v1"), {**SMALL, "plan_h": 3})
    SB3Agent("td3", gym.make("Pendulum-v1"), SMALL)  # the closed loop needs no model
