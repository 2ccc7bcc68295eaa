"""Plan execution in-process: the queue plays plans like the robot does, a new plan preempts the rest
(late by the configured latency), fixed H = 1 in plan mode is the closed-loop learner, and a plan that
goes stale is cut by the ``plan`` retreat statistic."""

import gymnasium as gym
import numpy as np
import pytest

import sim  # noqa: F401  (registers the NS environments)
from learner.plans import Plan, QueuedChannel, rollout
from learner.registry import make_agent


def _plan(plan_id: int, values: list[float]) -> Plan:
    actions = np.asarray(values, float).reshape(-1, 1)
    return Plan(plan_id, actions, actions.copy(), np.zeros((len(values) + 1, 4)))


def _cartpole() -> gym.Env:
    return gym.make("NSCartPoleContinuous-v0", preset="stationary")


def test_queue_plays_plans_in_order_and_a_new_plan_preempts_the_rest():
    channel = QueuedChannel(_cartpole())
    channel.reset(seed=0)
    channel.send(_plan(0, [0.1, 0.2, 0.3, 0.4]))
    ran = [channel.advance() for _ in range(2)]
    assert [(s.plan_id, s.index, float(s.action[0])) for s in ran] == [(0, 0, 0.1), (0, 1, 0.2)]
    channel.send(_plan(1, [-0.5, -0.6]))
    assert channel.dropped_planned == 2 and channel.preemptions == 1  # 0.3 and 0.4 never play
    ran = [channel.advance() for _ in range(3)]
    assert [(s.plan_id, s.index) for s in ran] == [(1, 0), (1, 1), (-1, -1)]  # then the arm holds
    assert float(ran[2].action[0]) == 0.0


def test_latency_keeps_the_old_plan_playing_until_the_new_one_lands():
    channel = QueuedChannel(_cartpole(), latency=2)
    channel.reset(seed=0)
    channel.send(_plan(0, [0.1, 0.2, 0.3, 0.4, 0.5]))
    assert channel.advance().plan_id == -1 and channel.advance().plan_id == -1  # not there yet
    assert [channel.advance().index for _ in range(2)] == [0, 1]
    channel.send(_plan(1, [-0.7, -0.8]))
    np.testing.assert_allclose(channel.queued(4).ravel(), [0.3, 0.4, -0.7, -0.8])  # what will play
    assert [(s.plan_id, s.index) for s in (channel.advance() for _ in range(3))] == [(0, 2), (0, 3), (1, 0)]
    assert channel.dropped_planned == 1  # 0.5 was still queued when plan 1 landed


def test_models_predict_their_envs_nominal_dynamics():
    env = gym.make("NSCartPoleContinuous-v0", preset="stationary")
    obs, _ = env.reset(seed=1)
    actions = np.full((5, 1), 0.3)
    predicted = rollout(env.unwrapped.predict_next, obs, actions)
    for a in actions:
        obs, *_ = env.step(a)
    np.testing.assert_allclose(predicted, obs, atol=1e-5)  # stationary gravity: the model is exact
    pend = gym.make("NSPendulum-v0", preset="stationary")
    obs, _ = pend.reset(seed=2)
    predicted = pend.unwrapped.predict_next(obs, np.array([1.0]))
    np.testing.assert_allclose(predicted, pend.step(np.array([1.0]))[0], atol=1e-5)


def test_fixed_h_1_in_plan_mode_is_the_closed_loop_learner():
    cfg = {"fixed_h": 1}
    closed = make_agent("rkhs", _cartpole(), 3, cfg)
    planned = make_agent("rkhs", _cartpole(), 3, {**cfg, "execution": "plan"})
    closed.learn(1500)
    planned.learn(1500)
    assert [e.ret for e in closed.log.episodes] == [e.ret for e in planned.log.episodes]
    assert planned.channel.dropped_planned == 0


def test_scored_by_its_noise_a_one_action_plan_is_the_closed_loop_up_to_rounding():
    """A one-action plan from the state itself: the sample's noise is ``a - h(s)``, the closed loop's
    score, up to the rounding of recomputing the mean (which the chaotic task grows later on)."""
    cfg = {"fixed_h": 1}
    closed = make_agent("rkhs", _cartpole(), 3, cfg)
    planned = make_agent("rkhs", _cartpole(), 3, {**cfg, "execution": "plan", "plan_score": "noise"})
    closed.learn(500)
    planned.learn(500)
    assert [e.ret for e in closed.log.episodes] == [e.ret for e in planned.log.episodes]
    np.testing.assert_allclose(planned.policy.f.weights, closed.policy.f.weights, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(planned.critic.theta, closed.critic.theta)
    assert not np.array_equal(planned.policy.f.weights, closed.policy.f.weights)  # another computation


def test_plans_play_open_loop_and_segments_end_at_h():
    agent = make_agent("rkhs", _cartpole(), 0, {"fixed_h": 8, "execution": "plan"})
    agent.learn(400)
    full = [s for s in agent.log.segments if s.reason == "h_max"]
    assert full and all(s.H == 8 for s in full)
    assert agent.channel.dropped_planned == 0  # fixed H: every plan plays to its end


def test_plan_statistic_cuts_a_plan_only_when_the_world_leaves_the_model():
    """Stationary CartPole: the nominal model is exact, what the plan predicted is what happens, and the
    plan statistic never retreats. Drifting gravity ('fast'): it retreats and drops planned actions."""

    def run(preset: str):
        env = gym.make("NSCartPoleContinuous-v0", preset=preset)
        cfg = {"execution": "plan", "retreat": "plan", "retreat_threshold": 0.9, "h_max": 50}
        agent = make_agent("adaptiveh", env, 1, cfg)
        agent.learn(3000)
        return agent

    exact, drifting = run("stationary"), run("fast")
    assert "retreat" not in [s.reason for s in exact.log.segments] and exact.channel.dropped_planned == 0
    retreats = [s for s in drifting.log.segments if s.reason == "retreat"]
    assert len(retreats) > 10 and drifting.channel.dropped_planned > 0
    assert all(s.statistic[-1] < 0.9 for s in retreats)  # each cut where the statistic fell below


def test_plan_mode_needs_a_world_model():
    class NoModel(gym.Wrapper):
        """CartPole seen through a wrapper that hides the world model."""

        obs_bounds = _cartpole().unwrapped.obs_bounds

        @property
        def unwrapped(self):
            return self

    with pytest.raises(ValueError, match="has no predict_next"):
        make_agent("adaptiveh", NoModel(_cartpole()), 0, {"execution": "plan"})


def test_plan_tolerance_sets_how_far_a_plan_may_drift_before_the_retreat():
    """The same 5 cm-like deviation (0.1 in normalised units) is invisible to a 0.5-wide policy kernel and
    fails a 0.05-wide plan tolerance; the gradient field is the same in both."""
    from learner.kernels import GaussianKernel
    from learner.plan_tolerance import FixedTolerance
    from learner.retreat import RetreatCheck

    wide = GaussianKernel(0.5, 2)

    def statistic(plan_kernel):
        tolerance = FixedTolerance(plan_kernel) if plan_kernel is not None else None
        check = RetreatCheck(wide, "plan", 0.5, smoothing=1.0, plan_tolerance=tolerance)
        predicted, reached = np.zeros(2), np.array([0.1, 0.0])
        fired = check.push(reached, np.array([1.0, 0.0]), predicted, reached)
        return fired, check.trace[-1]

    fired_wide, stat_wide = statistic(None)
    fired_narrow, stat_narrow = statistic(GaussianKernel(0.05, 2))
    assert not fired_wide and fired_narrow
    # G is one sample at s: G(ŝ) = k(s,ŝ)·g, so G(ŝ)ᵀG(s)/‖G(ŝ)‖² = 1/k(s,ŝ), times the plan kernel's k(ŝ,s)
    k_wide, k_narrow = np.exp(-0.5 * (0.1 / 0.5) ** 2), np.exp(-0.5 * (0.1 / 0.05) ** 2)
    assert stat_wide == pytest.approx(1.0, rel=1e-9)
    assert stat_narrow == pytest.approx(k_narrow / k_wide, rel=1e-9)


def test_the_retreat_follows_the_execution_unless_set():
    closed = make_agent("adaptiveh", _cartpole(), 0, {})
    planned = make_agent("adaptiveh", _cartpole(), 0, {"execution": "plan"})
    assert (closed.retreat.mode, planned.retreat.mode) == ("local", "plan")
    pinned = make_agent("adaptiveh", _cartpole(), 0, {"execution": "plan", "retreat": "local"})
    assert pinned.retreat.mode == "local"
    narrow = make_agent(
        "adaptiveh",
        _cartpole(),
        0,
        {"execution": "plan", "plan_kernel_scale": 0.1, "plan_tolerance": "fixed"},
    )
    np.testing.assert_allclose(narrow.retreat.plan_tolerance.kernel.bandwidth, narrow.kernel.bandwidth * 0.1)
    default = planned.retreat.plan_tolerance  # the noise floor over 0.15 of the policy's kernel
    np.testing.assert_allclose(default.width2(), (planned.kernel.bandwidth * 0.15) ** 2)
    with pytest.raises(ValueError, match="plan_kernel_scale"):
        make_agent("adaptiveh", _cartpole(), 0, {"execution": "plan", "plan_kernel_scale": 2.0})
    with pytest.raises(ValueError, match="plan_kernel_scale: expected 1 or 4 values"):
        make_agent("adaptiveh", _cartpole(), 0, {"execution": "plan", "plan_kernel_scale": [0.1, 0.1]})
