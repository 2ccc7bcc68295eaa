"""The learner options of issue #15: the bounded mean step, the local (visit-count) step size, the TD
error's state baseline, the state-action (LSTD-Q) critic and the expected (closed-form) policy gradient."""

from __future__ import annotations

import copy

import gymnasium as gym
import numpy as np
import pytest

import sim  # noqa: F401  (registers the environments)
from learner.adaptiveh import AdaptiveH
from learner.config import AdaptiveHConfig
from learner.critic import KLSTDCritic
from learner.kernels import GaussianKernel
from learner.policy import RKHSGaussianPolicy
from learner.replay import Transition, TransitionWindow


def _policy(limit_case_weight: float) -> RKHSGaussianPolicy:
    pol = RKHSGaussianPolicy(GaussianKernel(0.5, 1), np.array([-1.0]), np.array([1.0]), 0.3, 20, 0.01)
    pol.f.add(np.array([0.0]), np.array([limit_case_weight]))
    return pol


# -- bounded mean step -----------------------------------------------------------------------------


def test_bound_gradient_drops_only_the_outward_push_past_the_limit():
    s = np.array([0.0])
    saturated = _policy(5.0)  # f(s) = 5 > 3
    np.testing.assert_array_equal(saturated.bound_gradient(s, np.array([2.0]), 3.0), [0.0])  # outward
    np.testing.assert_array_equal(saturated.bound_gradient(s, np.array([-2.0]), 3.0), [-2.0])  # inward
    np.testing.assert_array_equal(saturated.bound_gradient(s, np.array([2.0]), None), [2.0])  # off
    inside = _policy(1.0)
    np.testing.assert_array_equal(inside.bound_gradient(s, np.array([2.0]), 3.0), [2.0])
    neg = _policy(-4.0)
    np.testing.assert_array_equal(neg.bound_gradient(s, np.array([-1.0]), 3.0), [0.0])
    np.testing.assert_array_equal(neg.bound_gradient(s, np.array([1.0]), 3.0), [1.0])


def _f_at_visited(agent: AdaptiveH, n: int) -> np.ndarray:
    env = gym.make("NSPendulum-v0", preset="stationary", seed=5)
    obs, _ = env.reset(seed=5)
    out = []
    for _ in range(n):
        s = agent.normalize(obs)
        out.append(abs(float(agent.policy.f(s)[0])))
        obs, *_ = env.step(agent.predict(obs, deterministic=False))
    return np.array(out)


def test_mean_limit_stops_the_windup_of_f_that_the_straight_through_step_has():
    """Measured on NS Pendulum (bench/learner_diagnosis.py): unbounded, |f| grows far past saturation."""
    base = {"gamma": 0.95, "bandwidth": 0.35, "policy_budget": 120, "critic_budget": 120}
    runs = {}
    for limit in (None, 3.0):
        agent = AdaptiveH(
            gym.make("NSPendulum-v0", preset="stationary", seed=1),
            AdaptiveHConfig(**base, mean_limit=limit),
            1,
        )
        agent.learn(3000)
        runs[limit] = _f_at_visited(agent, 400)
    step = 0.02 * 100.0  # alpha · max_grad_norm: one sample can overshoot the limit by this much
    assert np.percentile(runs[3.0], 90) <= 3.0 + 2 * step
    assert np.percentile(runs[None], 90) > 3 * np.percentile(runs[3.0], 90)


# -- visit counts and the local step size --------------------------------------------------------------


def _value_critic(**kw) -> KLSTDCritic:
    return KLSTDCritic(GaussianKernel(0.3, 1), 0.9, 30, 0.05, 1.0, 10.0, "value", **kw)


def test_visit_counts_sum_to_the_samples_and_stay_local():
    critic = _value_critic()
    rng = np.random.default_rng(0)
    for _ in range(500):
        s = np.array([rng.normal(-1.0, 0.1)])
        critic.update(s, 0.0, s, terminal=False)
    assert critic.visit_counts.sum() == pytest.approx(500.0)
    assert critic.visits(np.array([-1.0])) > 100.0
    assert critic.visits(np.array([1.0])) < 1.0 or len(critic) == 0


def test_visit_counts_are_forgotten_and_survive_pruning():
    critic = KLSTDCritic(GaussianKernel(0.2, 1), 0.9, 8, 0.05, 1.0, 10.0, "value", visit_memory=0.99)
    rng = np.random.default_rng(1)
    for _ in range(2000):
        s = rng.uniform(-3, 3, 1)
        critic.update(s, float(rng.normal()), s, terminal=False)
        assert critic.visit_counts.shape == (len(critic),)
    assert len(critic) == 8
    # Forgetting 0.99 per step: the total is bounded by 1/(1-0.99).
    assert critic.visit_counts.sum() <= 100.0 + 1e-6


def test_visit_step_shrinks_the_step_where_samples_pile_up():
    cfg = AdaptiveHConfig(gamma=0.95, bandwidth=0.35, visit_step=10.0, policy_budget=60, critic_budget=60)
    agent = AdaptiveH(gym.make("NSPendulum-v0", preset="stationary", seed=0), cfg, 0)
    agent.learn(1500)
    counts = np.array([agent.critic.visits(c) for c in agent.critic.dictionary.centers])
    assert counts.min() > 5.0  # every center has seen data: the step is well below alpha everywhere
    # The same agent without the local step: the same step taken from the same state differs only by
    # the factor n0 / (n0 + n(s)) (the retreat reads directions, so both close their segments alike).
    plain = cfg.model_copy(update={"visit_step": None})
    checked = 0
    for _ in range(20):
        twin = AdaptiveH(gym.make("NSPendulum-v0", preset="stationary", seed=0), plain, 0)
        twin.load_state_dict(copy.deepcopy(agent.state_dict()))
        closed = None
        while closed is None:  # within one segment both policies are still the same
            closed = agent.step_env()
            twin.step_env()
            if closed is None and np.linalg.norm(twin.retreat.grads[-1]) > 0:
                s = agent.retreat.states[-1]
                factor = 10.0 / (10.0 + agent.critic.visits(s))
                assert factor < 1.0
                np.testing.assert_allclose(
                    agent.retreat.grads[-1], factor * twin.retreat.grads[-1], rtol=1e-9
                )
                checked += 1
        if checked >= 5:
            break
    assert checked >= 5


# -- the residual baseline -----------------------------------------------------------------------------


@pytest.mark.parametrize("fit", ["kernel_mean", "least_squares"])
def test_residual_baseline_removes_the_state_part_of_the_td_error(fit):
    """A critic that cannot learn (tiny P) sees TD errors = rewards; their mean at a state is the state's
    part, the baseline takes it out and leaves the action's part (zero-mean here)."""
    critic = KLSTDCritic(
        GaussianKernel(0.3, 1), 0.9, 30, 0.05, 1.0, 1e-12, "value", residual_memory=0.999, residual_fit=fit
    )
    rng = np.random.default_rng(2)
    advs, tds = [], []
    for t in range(3000):
        s = np.array([rng.choice([-2.0, 2.0])])
        offset = 5.0 if s[0] > 0 else -3.0
        r = offset + rng.normal()
        adv = critic.update(s, r, s, terminal=True)
        if t > 1000:
            advs.append((s[0], adv))
            tds.append((s[0], r))
    for side in (-2.0, 2.0):
        a = np.mean([v for x, v in advs if x == side])
        d = np.mean([v for x, v in tds if x == side])
        assert abs(d) > 2.5  # the raw TD error carries the state's offset
        assert abs(a) < 0.3  # the baseline took it out
    assert critic.residual(np.array([2.0])) == pytest.approx(5.0, abs=0.3)


@pytest.mark.parametrize("fit", ["kernel_mean", "least_squares"])
def test_residual_baseline_leaves_the_action_signal(fit):
    critic = KLSTDCritic(
        GaussianKernel(0.3, 1), 0.9, 30, 0.05, 1.0, 1e-12, "value", residual_memory=0.99, residual_fit=fit
    )
    rng = np.random.default_rng(3)
    xs, ys = [], []
    for _ in range(3000):
        a = rng.normal()
        adv = critic.update(
            np.array([0.0]), 4.0 + 0.5 * a + 0.1 * rng.normal(), np.array([0.0]), terminal=True
        )
        xs.append(a)
        ys.append(adv)
    assert np.corrcoef(xs[500:], ys[500:])[0, 1] > 0.9


# -- GAE(λ) advantages ----------------------------------------------------------------------------------


def test_lambda_advantage_matures_as_the_discounted_sum_of_td_errors():
    cfg = AdaptiveHConfig(gamma=0.9, advantage_lambda=0.5, max_grad_norm=1e9, use_discount_factor=False)
    agent = AdaptiveH(gym.make("NSPendulum-v0", preset="stationary", seed=0), cfg, 0)
    deltas = [1.0, -2.0, 0.5, 3.0, -1.0, 0.25, 2.0, -0.5, 1.5, 0.0, -1.0, 0.75]
    score = np.array([2.0])
    for t, d in enumerate(deltas):
        agent._accrue(np.array([0.0, 0.0, float(t)]), score, d, episode_over=t == len(deltas) - 1)
    assert not agent._pending and len(agent._matured) == len(deltas)  # the episode end matures all
    # Terms weigh (γλ)^m = 0.45^m; those under 1 % (m >= 6) are cut, and so is what lies past the end.
    w = 0.45 ** np.arange(6)
    for k, (s, g) in enumerate(agent._matured):
        assert s[2] == k
        n = min(6, len(deltas) - k)
        expected = float(w[:n] @ np.array(deltas[k : k + n]))
        assert g[0] == pytest.approx(expected * 2.0)


def test_lambda_sample_matures_once_its_weight_is_below_one_percent():
    cfg = AdaptiveHConfig(gamma=0.9, advantage_lambda=0.5)
    agent = AdaptiveH(gym.make("NSPendulum-v0", preset="stationary", seed=0), cfg, 0)
    horizon = int(np.ceil(np.log(0.01) / np.log(0.45)))  # (γλ)^m < 1 % from this m on: 6
    for _ in range(horizon + 3):
        agent._accrue(np.zeros(3), np.ones(1), 1.0, episode_over=False)
    # A sample matures once its next term would weigh under 1 %: the last `horizon - 1` still accrue.
    assert len(agent._pending) == horizon - 1 and len(agent._matured) == 4
    assert agent._matured[0][1][0] > 0 and agent._pending[-1][3] == pytest.approx(0.45)


# -- the state-action critic and the expected gradient ---------------------------------------------------


def _bandit_q_critic() -> KLSTDCritic:
    return KLSTDCritic(GaussianKernel(0.3, 1), 0.5, 200, 0.05, 1.0, 10.0, "q", 1, 0.5)


def test_q_critic_expected_gradient_matches_the_bandit_derivative():
    """r = -(a - s/2)², policy mean 0, σ = 0.3: d/dμ E[r] at μ = 0 is s (the action integral, closed form)."""
    critic = _bandit_q_critic()
    rng = np.random.default_rng(0)
    sig, zero = np.array([0.3]), np.array([0.0])
    for _ in range(5000):
        s = rng.uniform(-1, 1, 1)
        a = np.clip(sig * rng.standard_normal(1), -1, 1)
        s2 = rng.uniform(-1, 1, 1)
        critic.update(s, -float((a[0] - 0.5 * s[0]) ** 2), s2, False, None, a, zero, zero, sig)
    for x in (-0.8, -0.4, 0.4, 0.8):
        d = critic.expected_gradient(np.array([x]), zero, sig)[0]
        assert d == pytest.approx(x, abs=0.15), x
    # V = E_a Q̂ and Q̂ agree: the best action is worth more than the policy's average, a bad one less.
    s = np.array([0.8])
    v = critic.value(s, zero, sig)
    assert critic.q_value(s, np.array([0.4])) > v > critic.q_value(s, np.array([-0.6]))


def test_q_critic_recovers_the_values_of_a_deterministic_ring():
    """Expected SARSA on a ring whose policy is a point mass (σ tiny): Q(s_i, a) = V(s_i) = (I-γP)⁻¹r."""
    n, gamma = 4, 0.8
    r = np.array([1.0, -1.0, 2.0, 0.0])
    v_true = np.linalg.solve(np.eye(n) - gamma * np.roll(np.eye(n), 1, axis=1), r)
    critic = KLSTDCritic(GaussianKernel(1.0, 1), gamma, 20, 0.1, 1.0, 100.0, "q", 1, 0.5)
    a, sig = np.array([0.0]), np.array([1e-3])
    for t in range(4000):
        i = t % n
        critic.update(np.array([10.0 * i]), r[i], np.array([10.0 * ((i + 1) % n)]), False, None, a, a, a, sig)
    v_hat = np.array([critic.value(np.array([10.0 * i]), a, sig) for i in range(n)])
    np.testing.assert_allclose(v_hat, v_true, atol=0.05 * np.abs(v_true).max())


def test_compatible_expected_gradient_is_the_advantage_weight_over_sigma_squared():
    critic = KLSTDCritic(GaussianKernel(0.5, 1), 0.5, 20, 0.05, 1.0, 10.0, "compatible", 1)
    critic.update(np.array([0.0]), 0.0, np.array([0.0]), True, score=np.array([1.0]))
    critic.theta = np.array([0.3, 2.0])  # value weight, advantage weight of the one center
    sig = np.array([0.5])
    s = np.array([0.2])
    k = float(np.exp(-0.5 * (0.2 / 0.5) ** 2))
    assert critic.expected_gradient(s, None, sig)[0] == pytest.approx(2.0 * k / 0.25)
    # It is E[Â score | s]: the advantage is w(s)·score, averaged against score over score's law.
    rng = np.random.default_rng(0)
    scores = (sig * rng.standard_normal(200_000)) / sig**2
    mc = np.mean([critic.advantage(s, np.array([x])) * x for x in scores[:20_000]])
    assert mc == pytest.approx(critic.expected_gradient(s, None, sig)[0], rel=0.05)


@pytest.mark.parametrize(
    "options",
    [
        {"critic": "q", "policy_gradient": "expected", "critic_budget": 80},
        {"critic": "q", "critic_budget": 80},
        {"critic": "compatible", "policy_gradient": "expected"},
        {"residual_baseline": 0.99, "visit_step": 20.0, "mean_limit": 3.0},
        {"replay_window": 200, "replay_batch": 8, "residual_baseline": 0.99},
        {"critic_lambda": 0.5},
    ],
)
def test_each_option_runs_resumes_and_stays_finite(tmp_path, options):
    cfg = AdaptiveHConfig(policy_budget=60, critic_budget=options.pop("critic_budget", 60), **options)
    agent = AdaptiveH(gym.make("NSPendulum-v0", preset="slow", seed=0), cfg, 0)
    agent.learn(600)
    agent.save(tmp_path / "a.pkl")
    twin = AdaptiveH(gym.make("NSPendulum-v0", preset="slow", seed=0), cfg, 0)
    twin.load(tmp_path / "a.pkl")
    agent.learn(300)
    twin.learn(300)
    assert np.all(np.isfinite(agent.critic.theta)) and np.all(np.isfinite(agent.policy.f.weights))
    np.testing.assert_array_equal(agent.policy.f.weights, twin.policy.f.weights)
    np.testing.assert_array_equal(agent.critic.theta, twin.critic.theta)
    assert [e.ret for e in agent.log.episodes] == [e.ret for e in twin.log.episodes]


@pytest.mark.parametrize(
    "options, match",
    [
        ({"policy_gradient": "expected"}, "needs critic"),
        ({"critic": "q", "residual_baseline": 0.99}, "residual_baseline"),
        ({"critic": "q", "visit_step": 10.0}, "visit_step"),
        ({"critic": "q", "replay_window": 100}, "replay_window"),
        ({"execution": "plan", "replay_window": 100}, "closed_loop"),
        ({"advantage_lambda": 0.5, "replay_window": 100}, "advantage_lambda"),
    ],
)
def test_option_combinations_that_cannot_work_are_refused(options, match):
    with pytest.raises(ValueError, match=match):
        AdaptiveHConfig(**options)


# -- the critic's own kernel width ---------------------------------------------------------------------


def test_critic_bandwidth_gives_the_critic_its_own_kernel_and_leaves_the_policys():
    env = gym.make("NSPendulum-v0", preset="stationary", seed=2)
    agent = AdaptiveH(env, AdaptiveHConfig(bandwidth=0.35, critic_bandwidth=[0.2, 0.2, 0.1]), 2)
    np.testing.assert_allclose(agent.critic.state_kernel.bandwidth, [0.2, 0.2, 0.1])
    np.testing.assert_allclose(agent.kernel.bandwidth, [0.35] * 3)
    np.testing.assert_allclose(agent.policy.f.dictionary.kernel.bandwidth, [0.35] * 3)
    agent.learn(600)  # the narrower critic admits more centres from the same states than the policy's width
    shared = AdaptiveH(
        gym.make("NSPendulum-v0", preset="stationary", seed=2), AdaptiveHConfig(bandwidth=0.35), 2
    )
    shared.learn(600)
    assert shared.critic.state_kernel is shared.kernel
    assert len(agent.critic) > len(shared.critic)
    with pytest.raises(ValueError, match="critic_bandwidth: expected 1 or 3 values"):
        AdaptiveH(env, AdaptiveHConfig(critic_bandwidth=[0.2, 0.2]), 2)


# -- re-used samples ---------------------------------------------------------------------------------


def test_transition_window_keeps_the_newest_and_samples_without_replacement():
    window = TransitionWindow(5)
    for i in range(8):
        window.push(Transition(np.array([float(i)]), np.zeros(1), 0.0, np.zeros(1), False, 0.0))
    assert len(window) == 5 and [t.s[0] for t in window.items] == [3.0, 4.0, 5.0, 6.0, 7.0]
    drawn = window.sample(4, np.random.default_rng(0))
    assert len({t.s[0] for t in drawn}) == 4
    assert len(window.sample(50, np.random.default_rng(0))) == 5
    with pytest.raises(ValueError, match="at least 1"):
        TransitionWindow(0)


def test_td_error_rescores_a_transition_without_fitting():
    critic = KLSTDCritic(GaussianKernel(0.5, 1), 0.9, 50, 0.05, 0.999, 10.0, "value", residual_memory=0.99)
    rng = np.random.default_rng(3)
    for _ in range(300):
        x = rng.uniform(-1, 1, 1)
        critic.update(x, float(x[0]), np.clip(x + 0.1, -1, 1), False)
    s, s2 = np.array([0.2]), np.array([0.3])
    theta = critic.theta.copy()
    expected = 0.5 + 0.9 * critic.value(s2) - critic.value(s) - critic.residual(s)
    assert critic.td_error(s, 0.5, s2, False) == pytest.approx(expected)
    assert critic.td_error(s, 0.5, s2, True) == pytest.approx(0.5 - critic.value(s) - critic.residual(s))
    np.testing.assert_array_equal(critic.theta, theta)  # nothing was fitted
    # What update() hands the actor is the same TD error, taken before the fit.
    assert critic.update(s, 0.5, s2, False) == pytest.approx(expected)


def test_replayed_gradient_is_weighted_by_the_truncated_importance_ratio():
    cfg = AdaptiveHConfig(replay_window=10, sigma=0.3)
    agent = AdaptiveH(gym.make("NSPendulum-v0", preset="stationary", seed=0), cfg, 0)
    agent.learn(50)
    s = agent.normalize(np.array([1.0, 0.0, 0.0]))
    raw = agent.policy.mean(s) + 0.2
    now = agent.policy.log_prob(s, raw)
    unweighted = agent.grad_scale * agent.critic.td_error(s, -1.0, s, False) * agent.policy.score(s, raw)
    # Drawn by a policy that found it likelier than the current one does: weight π/μ = e^-1.
    likelier = Transition(s, raw, -1.0, s, False, now + 1.0)
    np.testing.assert_allclose(agent._replayed_gradient(likelier), np.exp(-1.0) * unweighted)
    # Drawn by a policy that found it less likely: the ratio e^2 is truncated at 1.
    rarer = Transition(s, raw, -1.0, s, False, now - 2.0)
    np.testing.assert_allclose(agent._replayed_gradient(rarer), unweighted)


def test_replay_moves_the_policy_more_per_sample_than_the_samples_alone():
    """The same run with and without re-use: equal acting draws until the first update, then more change."""

    def run(window: int) -> AdaptiveH:
        cfg = AdaptiveHConfig(replay_window=window, replay_batch=16, fixed_h=10)
        agent = AdaptiveH(gym.make("NSPendulum-v0", preset="stationary", seed=4), cfg, 4)
        agent.learn(400)
        return agent

    plain, replayed = run(0), run(100)
    assert replayed.replay is not None and len(replayed.replay) == 100 and plain.replay is None
    assert plain.log.segments[0].global_step == replayed.log.segments[0].global_step
    assert replayed.policy.f.norm2() > plain.policy.f.norm2()


# -- the critic's eligibility trace -------------------------------------------------------------------


def test_lstd_lambda_recovers_the_values_of_a_deterministic_ring():
    """LSTD(λ) has the same fixed point as LSTD(0) with one-hot features: V = (I - γP)⁻¹ r."""
    n, gamma = 5, 0.9
    r = np.array([1.0, 0.0, -2.0, 0.5, 3.0])
    v_true = np.linalg.solve(np.eye(n) - gamma * np.roll(np.eye(n), 1, axis=1), r)
    critic = KLSTDCritic(GaussianKernel(1.0, 1), gamma, 50, 0.1, 1.0, 100.0, "value", trace_lambda=0.8)
    for t in range(3000):
        i = t % n
        critic.update(np.array([10.0 * i]), r[i], np.array([10.0 * ((i + 1) % n)]), terminal=False)
    v_hat = np.array([critic.value(np.array([10.0 * i])) for i in range(n)])
    np.testing.assert_allclose(v_hat, v_true, atol=0.05 * np.abs(v_true).max())
    assert np.abs(critic.trace).max() > 1.0  # the trace carries the past states' features
    critic.end_episode()
    np.testing.assert_array_equal(critic.trace, np.zeros(n))


def test_lstd_lambda_moves_the_fixed_point_towards_the_monte_carlo_fit():
    """A chain 0→1→…→4 ending with reward 1, one feature for all states (V̂ a constant c): TD(0)'s fixed point
    solves Σ_t (1 - γ[t<4]) c = 1, c = 1/1.4; the Monte-Carlo fit is the mean return, mean_i γ^(4-i)."""
    gamma = 0.9

    def fit(lam: float) -> float:
        critic = KLSTDCritic(GaussianKernel(1e3, 1), gamma, 5, 0.1, 1.0, 100.0, "value", trace_lambda=lam)
        for _ in range(200):
            for i in range(5):
                critic.update(np.array([float(i)]), float(i == 4), np.array([i + 1.0]), terminal=i == 4)
        assert len(critic) == 1
        return critic.value(np.array([2.0]))

    assert fit(0.0) == pytest.approx(1 / 1.4, rel=1e-3)
    assert fit(0.999) == pytest.approx(np.mean(gamma ** np.arange(5)), rel=1e-2)
