"""``AdaptiveH.frozen_gradient``, what the diagnosis bench probes: the gradient and advantage the learner's
own step forms for a transition, without fitting anything (each critic, at a state its dictionary
already holds, where the step's fit adds no center before it scores)."""

from __future__ import annotations

import copy

import gymnasium as gym
import numpy as np
import pytest

import sim  # noqa: F401  (registers the environments)
from learner.adaptiveh import AdaptiveH
from learner.config import AdaptiveHConfig

CRITICS = {
    "value": {"residual_baseline": 0.999},
    "compatible": {"critic": "compatible"},
    "q": {"critic": "q"},
}


def _trained(options: dict) -> AdaptiveH:
    cfg = AdaptiveHConfig(gamma=0.95, bandwidth=0.35, policy_budget=60, critic_budget=60, **options)
    agent = AdaptiveH(gym.make("NSPendulum-v0", preset="stationary", seed=0), cfg, 0)
    agent.learn(300)
    return agent


@pytest.mark.parametrize("critic", sorted(CRITICS))
def test_it_is_the_learners_own_step_without_the_fit(critic: str) -> None:
    agent = _trained(CRITICS[critic])
    centers, dim = agent.critic.dictionary.centers, len(agent.normalize.centre)
    s, s_next = centers[3][:dim], centers[7][:dim]
    pol = agent.policy
    # a q critic's centers are (state, scaled action) pairs: take the action it holds with the state
    raw = (
        pol.centre + pol.half_range * centers[3][dim:] if critic == "q" else pol.centre + 0.4 * pol.half_range
    )
    theta, size = agent.critic.theta.copy(), len(agent.critic)

    g, advantage = agent.frozen_gradient(s, raw, 0.3, s_next)
    np.testing.assert_array_equal(agent.critic.theta, theta)  # nothing fitted
    assert len(agent.critic) == size and np.all(np.isfinite(g)) and np.linalg.norm(g) > 0

    twin = copy.deepcopy(agent)
    g_step, adv_step = twin._gradient(s, raw, pol.score(s, raw), 0.3, s_next, False)
    assert len(twin.critic) == size  # the step added no center: the two see the same critic
    assert advantage == pytest.approx(adv_step, rel=1e-9, abs=1e-12)
    np.testing.assert_allclose(g, g_step, rtol=1e-9, atol=1e-12)
