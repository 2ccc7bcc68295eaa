"""AdaptiveH and RKHSFixedH end to end: segments, checkpoint/resume, NaN guard, config validation."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import sim  # noqa: F401  (registers the environments)
from learner.adaptiveh import AdaptiveH, RKHSFixedH
from learner.config import AdaptiveHConfig
from learner.protocol import Agent
from learner.registry import make_agent
from sim.cartpole import NSCartPoleContinuous

REASONS = {"retreat", "h_max", "episode_end"}
SMALL = {"policy_budget": 150, "critic_budget": 150}  # not reached in these short runs: fast


def _cartpole(preset: str = "fast", seed: int = 0) -> gym.Env:
    return gym.make("NSCartPoleContinuous-v0", preset=preset, seed=seed)


def _arrays(agent: AdaptiveH) -> dict[str, np.ndarray]:
    return {
        "policy.centers": agent.policy.f.dictionary.centers,
        "policy.weights": agent.policy.f.weights,
        "policy.gram": agent.policy.f.dictionary.gram,
        "policy.chol": agent.policy.f.dictionary.chol,
        "critic.centers": agent.critic.dictionary.centers,
        "critic.gram": agent.critic.dictionary.gram,
        "critic.chol": agent.critic.dictionary.chol,
        "critic.theta": agent.critic.theta,
        "critic.P": agent.critic.P,
    }


def _check_segments(agent: AdaptiveH, limit: int) -> None:
    log = agent.log
    assert log.segments
    assert {s.reason for s in log.segments} <= REASONS
    assert all(1 <= s.H <= limit for s in log.segments)
    assert [s.index for s in log.segments] == list(range(len(log.segments)))
    # Every step of the run belongs to exactly one segment (closed, or the one still open).
    assert sum(s.H for s in log.segments) + len(agent.retreat.states) == log.global_step
    # A segment closes at every episode end.
    seg_steps = {s.global_step for s in log.segments}
    assert all(e.global_step in seg_steps for e in log.episodes)
    assert all(
        s.reason != "episode_end" or s.global_step in {e.global_step for e in log.episodes}
        for s in log.segments
    )


def test_adaptiveh_segments_are_recorded_with_reasons_and_bounded_h():
    cfg = AdaptiveHConfig(h_max=20, **SMALL)
    agent = AdaptiveH(_cartpole(), cfg, seed=0)
    assert isinstance(agent, Agent)
    agent.learn(1200)
    _check_segments(agent, cfg.h_max)
    reasons = {s.reason for s in agent.log.segments}
    assert "episode_end" in reasons and "retreat" in reasons
    # The default statistic is recorded for the inner-product trace, against one threshold.
    assert any(s.statistic for s in agent.log.segments)
    assert len({s.threshold for s in agent.log.segments}) == 1
    # Gravity drifts in the env and reaches the episode records through info.
    gravities = [e.info["gravity"] for e in agent.log.episodes]
    assert len(set(gravities)) > 1


def test_h_max_ends_segments_when_the_check_never_fires():
    cfg = AdaptiveHConfig(h_max=7, retreat_threshold=-1e9, **SMALL)  # the statistic can never be below it
    agent = AdaptiveH(_cartpole(), cfg, seed=1)
    agent.learn(600)
    _check_segments(agent, 7)
    reasons = [s.reason for s in agent.log.segments]
    assert "retreat" not in reasons and "h_max" in reasons
    assert all(s.H == 7 for s in agent.log.segments if s.reason == "h_max")


def test_rkhs_fixed_h_never_retreats_and_updates_every_fixed_h_steps():
    cfg = AdaptiveHConfig(fixed_h=8, h_max=50, **SMALL)
    agent = RKHSFixedH(_cartpole(), cfg, seed=0)
    assert agent.config.retreat == "off"
    agent.learn(1000)
    _check_segments(agent, 8)
    assert {s.reason for s in agent.log.segments} == {"h_max", "episode_end"}
    assert all(s.H == 8 for s in agent.log.segments if s.reason == "h_max")
    assert all(not s.statistic for s in agent.log.segments)


def test_retreat_mode_off_never_retreats():
    agent = AdaptiveH(_cartpole(), AdaptiveHConfig(retreat="off", fixed_h=12, **SMALL), seed=0)
    agent.learn(1000)
    assert "retreat" not in {s.reason for s in agent.log.segments}
    assert max(s.H for s in agent.log.segments) <= 12


def test_literal_mode_runs_and_records_its_statistic():
    agent = AdaptiveH(_cartpole(), AdaptiveHConfig(retreat="literal", **SMALL), seed=0)
    agent.learn(800)
    _check_segments(agent, agent.config.h_max)
    thr = agent.log.segments[0].threshold
    assert thr == pytest.approx(agent.kernel.normaliser_z * agent.config.epsilon / 2)
    for s in agent.log.segments:
        if s.reason == "retreat":
            assert s.statistic[-1] < thr


def test_budgets_hold_in_a_run():
    cfg = AdaptiveHConfig(policy_budget=25, critic_budget=20, policy_ald=0.01, critic_ald=0.01)
    agent = AdaptiveH(_cartpole("slow"), cfg, seed=0)
    agent.learn(1000)
    assert len(agent.policy.f) == 25
    assert len(agent.critic) == 20
    assert agent.critic.P.shape == (20, 20)


@pytest.mark.parametrize("cls, preset, n, m", [(AdaptiveH, "fast", 437, 500), (RKHSFixedH, "slow", 601, 300)])
def test_checkpoint_resume_continues_identically(tmp_path, cls, preset, n, m):
    """N steps, save, M more == load the checkpoint into a new agent and a new env, M more."""
    cfg = AdaptiveHConfig(**SMALL)
    path = tmp_path / "agent.pkl"
    first = cls(_cartpole(preset, seed=3), cfg, seed=5)
    first.learn(n)  # stops mid-episode and mid-segment
    assert first._obs is not None
    first.save(path)
    first.learn(m)

    second = cls(_cartpole(preset, seed=3), cfg, seed=5)
    second.load(path)
    assert second.log.global_step == n
    second.learn(m)

    assert second.log.to_dict() == first.log.to_dict()
    assert len(first.log.episodes) > 5
    a, b = _arrays(first), _arrays(second)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert first.policy.f.error_bound == second.policy.f.error_bound
    # The env's hidden clock was restored too.
    assert first.env.unwrapped.gravity == second.env.unwrapped.gravity
    obs = np.array([0.1, -0.2, 0.05, 0.3])
    np.testing.assert_array_equal(first.predict(obs), second.predict(obs))
    # And an uninterrupted run of N+M steps matches: saving does not perturb anything.
    straight = cls(_cartpole(preset, seed=3), cfg, seed=5)
    straight.learn(n + m)
    assert straight.log.to_dict() == first.log.to_dict()


def test_load_rejects_a_checkpoint_of_another_algorithm(tmp_path):
    AdaptiveH(_cartpole(), AdaptiveHConfig(**SMALL), seed=0).save(tmp_path / "a.pkl")
    with pytest.raises(ValueError, match="adaptiveh"):
        RKHSFixedH(_cartpole(), AdaptiveHConfig(**SMALL), seed=0).load(tmp_path / "a.pkl")


class NaNObservations(gym.Wrapper):
    """Replaces the observation (or the reward) by NaN now and then; records every action sent.

    ``sanitize`` models a sensor glitch on a healthy world: a non-finite action is replaced by 0
    before it reaches the env, so the env's own state never turns NaN.
    """

    def __init__(
        self, env: gym.Env, p: float = 0.05, seed: int = 0, what: str = "obs", sanitize: bool = False
    ):
        super().__init__(env)
        self.p, self.what, self.sanitize = p, what, sanitize
        self.rng = np.random.default_rng(seed)
        self.actions: list[np.ndarray] = []

    def step(self, action):
        action = np.array(action, dtype=float)
        self.actions.append(action)
        if self.sanitize:
            action = np.nan_to_num(action, nan=0.0, posinf=0.0, neginf=0.0)
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self.rng.random() < self.p:
            if self.what == "obs":
                obs = np.full_like(obs, np.nan)
            else:
                reward = float("nan")
        return obs, reward, terminated, truncated, info


def _assert_learned_without_nan(agent: AdaptiveH) -> None:
    assert agent.nonfinite_skipped > 0
    for key, arr in _arrays(agent).items():
        assert np.all(np.isfinite(arr)), key
    assert np.all(np.isfinite(agent.retreat.field.weights))
    assert len(agent.policy.f) >= 10 and len(agent.critic) >= 10  # it kept learning
    assert len(agent.log.episodes) > 10


def test_nan_rewards_never_reach_the_dictionaries():
    env = NaNObservations(NSCartPoleContinuous(preset="stationary"), what="reward")
    agent = AdaptiveH(env, AdaptiveHConfig(**SMALL), seed=0)
    agent.learn(1000)
    _assert_learned_without_nan(agent)


def test_nan_observations_never_reach_the_dictionaries():
    """A sensor glitch (NaN observation, healthy world) is skipped: no crash, nothing NaN stored.

    The guard must cover the state the agent acts from, not only the next state: a NaN next state
    that is kept as the current observation otherwise reaches the dictionaries one step later.
    """
    env = NaNObservations(NSCartPoleContinuous(preset="stationary"), sanitize=True)
    agent = AdaptiveH(env, AdaptiveHConfig(**SMALL), seed=0)
    agent.learn(1000)
    _assert_learned_without_nan(agent)


def test_nan_observation_never_reaches_the_policy_or_the_env():
    """A NaN observation must not become the state the agent acts on: every action stays finite.

    Otherwise the NaN action poisons the env (here the cart-pole's physics state turns NaN for the
    rest of the episode) and, on a robot, would be a NaN command.
    """
    env = NaNObservations(NSCartPoleContinuous(preset="stationary"))
    agent = AdaptiveH(env, AdaptiveHConfig(**SMALL), seed=0)
    agent.learn(1000)
    assert agent.nonfinite_skipped > 0
    actions = np.array(env.actions)
    assert np.all(np.isfinite(actions)), f"{np.sum(~np.isfinite(actions))} of {len(actions)} actions are NaN"
    assert len(agent.log.episodes) > 10  # learning goes on: episodes are not stuck at the 500-step cap


@pytest.mark.parametrize(
    "key, value",
    [
        ("alpha", -1.0),
        ("alpha", 0.0),
        ("gamma", 1.0),
        ("gamma", -0.1),
        ("sigma", 0.0),
        ("bandwidth", -0.4),
        ("bandwidth", [0.4, -1.0]),
        ("policy_budget", 0),
        ("critic_budget", 0),
        ("policy_ald", 1.5),
        ("critic_ald", -0.1),
        ("critic", "td"),
        ("action_bandwidth", 0.0),
        ("critic_bandwidth", 0.0),
        ("mean_limit", 0.0),
        ("residual_baseline", 1.0),
        ("policy_gradient", "natural"),
        ("critic_forgetting", 0.0),
        ("critic_forgetting", 1.5),
        ("critic_p0", 0.0),
        ("retreat", "sometimes"),
        ("epsilon", 0.0),
        ("h_max", 0),
        ("fixed_h", 0),
        ("weight_decay", -1.0),
        ("max_grad_norm", 0.0),
    ],
)
def test_bad_config_value_names_its_key(key, value):
    with pytest.raises(ValueError, match=rf"(?m)^{key}\b"):  # the key path heads its error line
        AdaptiveHConfig(**{key: value})


def test_make_agent_builds_both_rkhs_learners_and_rejects_unknown_ones():
    env = _cartpole()
    assert isinstance(make_agent("adaptiveh", env, 0, {"alpha": 0.01}), AdaptiveH)
    rkhs = make_agent("rkhs", env, 0, {})
    assert isinstance(rkhs, RKHSFixedH) and rkhs.name == "rkhs"
    with pytest.raises(ValueError, match="unknown algo"):
        make_agent("a2c", env, 0)
    with pytest.raises(ValueError, match="alpah"):
        make_agent("adaptiveh", env, 0, {"alpah": 0.01})
