"""``bench/pendulum_optimum.py`` on a coarse grid: value iteration finds a policy that swings the pendulum
up and holds it, a longer horizon is worth more on the undiscounted return, and the learner's probe runs."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from pendulum_optimum import PendulumGrid, episode_returns, learner_run, optimum_run  # noqa: E402

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
