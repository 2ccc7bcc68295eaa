"""``bench/pendulum_optimum.py`` on a coarse grid: value iteration finds a policy that swings the pendulum
up and holds it, a longer horizon is worth more on the undiscounted return, and the learner's probe runs."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from pendulum_optimum import (  # noqa: E402
    OptimalAdvantage,
    PendulumGrid,
    TrueStateProbe,
    episode_returns,
    learner_run,
    optimum_run,
)

from experiments.envs import make_env  # noqa: E402
from experiments.plan import ENVS, env_kwargs  # noqa: E402
from learner.registry import make_agent  # noqa: E402

COARSE = (61, 41, 11)


def test_the_optimal_policy_holds_the_top_and_swings_up_from_the_bottom():
    grid = PendulumGrid(*COARSE)
    v, sweeps = grid.value_iteration(0.95)
    assert sweeps < 500 and np.all(np.isfinite(v))
    policy = grid.greedy(grid.value_at(v), 0.95)
    top, bottom = episode_returns(policy, np.array([[0.0, 0.0], [np.pi, 0.0]]))
    assert top > -1.0  # balanced upright: almost no cost
    idle = episode_returns(lambda th, w: 0.0, np.array([[np.pi - 0.01, 0.0]]))[0]
    assert bottom > -450.0 and idle < -1500.0  # hanging still costs ~π² a step; the swing-up pays once


def test_a_myopic_discount_scores_worse_on_the_undiscounted_return():
    short, long = (optimum_run((g, COARSE, 20))["mean_return"] for g in (0.8, 0.97))
    assert long > short + 20.0


def test_the_learner_probe_reports_both_policies():
    out = learner_run((0, 400, COARSE, 2))
    assert out["gamma"] == 0.95 and len(out["mean_policy_returns"]) == 2
    assert np.isfinite(out["mean_policy"]) and np.isfinite(out["critic_greedy"])


def test_the_oracle_hands_the_actor_the_optimal_advantage_on_the_true_states():
    """``OptimalAdvantage`` returns ``r + γV(s') - V(s)`` on the env's true states (not the noisy
    observation the critic sees) and still fits the learner's own critic."""
    spec = ENVS["pendulum_slow"]
    env = TrueStateProbe(make_env(spec.env_id, env_kwargs(spec, 0)))
    agent = make_agent("adaptiveh", env, 0, {})
    critic = agent.critic
    oracle = OptimalAdvantage(critic, env, lambda th, w: 10.0 * th + w, gamma=0.9)
    obs, _ = env.reset(seed=0)
    s = agent.normalize(np.asarray(obs, float))
    obs2, r, *_ = env.step(np.array([1.0], np.float32))
    (th0, w0), (th1, w1) = env.before, env.after
    assert abs(obs2[2] - w1) > 0 or abs(obs2[0] - np.cos(th1)) > 0  # the observation is noisy
    advantage = oracle.update(s, r, agent.normalize(np.asarray(obs2, float)), False)
    assert advantage == pytest.approx(r + 0.9 * (10.0 * th1 + w1) - (10.0 * th0 + w0))
    assert len(critic) == 1 and oracle.visits(s) == critic.visits(s) > 0  # fitted, and delegated
    env.close()


def test_the_learner_probe_runs_with_the_optimal_advantage():
    grid = PendulumGrid(*COARSE)
    v, _ = grid.value_iteration(0.95)
    out = learner_run((0, 400, COARSE, 2, "alpha_0.04", v))
    assert out["oracle"] and out["overrides"] == {"alpha": 0.04} and "critic_greedy" not in out
    assert np.isfinite(out["final_return"]) and np.isfinite(out["mean_policy"])
