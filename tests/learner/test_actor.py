"""The actor (``learner.actor``) plans and judges plans as the learner would, from the learner's snapshot;
a snapshot that does not fit is refused whole; the learner learns from an actor's ticks
(``AdaptiveH.learn_transition``) with the segments the actor decided."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest

import sim  # noqa: F401  (registers the NS environments)
from learner.actor import Actor
from learner.adaptiveh import AdaptiveH
from learner.config import AdaptiveHConfig
from learner.plans import rollout
from learner.retreat import plan_statistic
from learner.snapshot import SnapshotError

CONFIG = AdaptiveHConfig(execution="plan", h_max=20, policy_budget=40, critic_budget=40)


@pytest.fixture(scope="module")
def trained():
    env = gym.make("NSCartPoleContinuous-v0")
    agent = AdaptiveH(env, CONFIG, seed=1)
    agent.learn(600)
    assert len(agent.policy.f) > 0 and len(agent.retreat.field) > 0
    return env, agent


def test_an_actor_with_the_learners_snapshot_plans_and_judges_as_the_learner(trained):
    env, agent = trained
    actor = Actor(env, CONFIG, seed=0)
    actor.load(agent.snapshot())
    assert actor.version == agent.log.global_step
    rng = np.random.default_rng(0)
    lo, hi = agent.normalize.centre - agent.normalize.scale, agent.normalize.centre + agent.normalize.scale
    for _ in range(20):
        obs, reached = rng.uniform(lo, hi), rng.uniform(lo, hi)
        np.testing.assert_allclose(
            actor.policy.mean(actor.normalize(obs)), agent.policy.mean(agent.normalize(obs))
        )
        ours = actor.statistic(3, obs, reached)
        theirs = plan_statistic(
            agent.retreat.field,
            agent.retreat.plan_tolerance,
            3,
            agent.normalize(obs),
            agent.normalize(reached),
        )
        assert ours == pytest.approx(theirs)
    plan = actor.plan(obs, segment=3, opened_by="retreat")
    assert plan.actions.shape == (CONFIG.h_max, 1) and len(plan.predicted) == CONFIG.h_max + 1
    assert (plan.segment, plan.opened_by) == (3, "retreat")  # the plan says which segment and why
    np.testing.assert_allclose(plan.predicted[-1], rollout(actor.model, obs, plan.actions))
    np.testing.assert_allclose(plan.actions, np.clip(plan.raw, -1, 1))


@pytest.mark.parametrize(
    "change, complaint",
    [
        (lambda s: {"policy_centers": s.policy_centers[:, :2]}, "policy centres"),
        (lambda s: {"field_weights": s.field_weights[:-1]}, "field weights"),
        (lambda s: {"policy_weights": np.full_like(s.policy_weights, np.nan)}, "finite"),
        (lambda s: {"sigma": -s.sigma}, "sigma"),
        (
            lambda s: {
                "policy_centers": np.zeros((500, s.policy_centers.shape[1])),
                "policy_weights": np.zeros((500, 1)),
            },
            "budget",
        ),
    ],
)
def test_a_snapshot_that_does_not_fit_is_refused_naming_what_is_wrong(trained, change, complaint):
    """The actor node checks each snapshot where it arrives (tests/deploy/test_actor_node.py: the old
    policy keeps running); the check names what does not fit."""
    env, agent = trained
    actor = Actor(env, CONFIG, seed=0)
    good = agent.snapshot()
    actor.check(good)
    bad = dataclasses.replace(good, version=good.version + 1, **change(good))
    with pytest.raises(SnapshotError, match=complaint):
        actor.check(bad)


def test_the_learner_closes_segments_where_the_actor_says():
    env = gym.make("NSCartPoleContinuous-v0")
    agent = AdaptiveH(env, CONFIG, seed=0)
    obs, _ = env.reset(seed=0)
    ends = ["open", "open", "retreat", "open", "h_max", "open", "open", "open", "episode_end"]
    stats = [0.9, None, 0.1, 0.8, 0.7, None, None, 0.6, 0.5]
    records = []
    for i, (end, stat) in enumerate(zip(ends, stats, strict=True)):
        raw = np.array([0.3])
        nxt, reward, _, _, _ = env.step(raw)
        last = i == len(ends) - 1
        records.append(agent.learn_transition(obs, raw, reward, nxt, False, last, {}, nxt + 0.01, end, stat))
        obs = nxt
    closed = [r for r in records if r is not None]
    assert [(r.reason, r.H) for r in closed] == [("retreat", 3), ("h_max", 2), ("episode_end", 4)]
    assert closed[0].statistic == [0.9, 0.1]  # the actor's statistic, where it evaluated one
    assert agent.log.global_step == 9 and agent.log.episode_count == 1
    assert agent.log.episodes[0].length == 9
    assert agent.snapshot().version == 9


def test_a_plan_that_began_late_is_judged_from_the_state_its_first_action_met(trained):
    env, agent = trained
    actor = Actor(env, CONFIG, seed=0)
    actor.load(agent.snapshot())
    planned_from = np.array([0.0, 0.0, 0.02, 0.0])
    plan = actor.plan(planned_from, segment=0, opened_by="first")
    met = planned_from
    for _ in range(3):  # three ticks of the plan before played first, pushing the cart right
        met = actor.model(met, np.ones(1))
    reached = actor.model(met, plan.actions[0])  # the world as the model says: no surprise
    assert actor.retreats(actor.statistic(1, plan.predicted[1], reached))  # judged from where it was made
    actor.anchor(plan, met)
    np.testing.assert_allclose(plan.predicted[0], met)
    np.testing.assert_allclose(plan.predicted[-1], rollout(actor.model, met, plan.actions))
    assert actor.statistic(1, plan.predicted[1], reached) == pytest.approx(1.0)
    assert not actor.retreats(actor.statistic(1, plan.predicted[1], reached))


def test_pooled_arms_segments_and_episodes_stay_their_own_and_a_gone_arm_closes_its_open_segment():
    """Two arms' ticks interleave at the learner (a fleet): each segment holds its own arm's samples,
    each episode its own arm's return and length, and an arm that goes has its open segment closed as its
    plan is gone (h_max), while the other's stays open."""
    env = gym.make("NSCartPoleContinuous-v0")
    agent = AdaptiveH(env, CONFIG, seed=0)
    obs, _ = env.reset(seed=0)
    ticks = [  # (arm, end, episode over, reward)
        ("a", "open", False, 1.0),
        ("b", "open", False, 10.0),
        ("a", "open", False, 1.0),
        ("b", "open", False, 10.0),
        ("a", "retreat", False, 1.0),
        ("b", "open", False, 10.0),
        ("a", "episode_end", True, 1.0),
        ("b", "open", False, 10.0),
    ]
    closed = []
    for arm, end, over, reward in ticks:
        raw = np.array([0.3])
        nxt, _, _, _, _ = env.step(raw)
        record = agent.learn_transition(
            obs, raw, reward, nxt, False, over, {}, None, end, 0.9, stream=f"s-{arm}", arm=arm
        )
        closed += [record] if record is not None else []
        obs = nxt
    assert [(r.arm, r.reason, r.H) for r in closed] == [("a", "retreat", 3), ("a", "episode_end", 1)]
    (episode,) = agent.log.episodes
    assert (episode.arm, episode.length, episode.ret) == ("a", 4, 4.0)
    assert len(agent.streams["s-b"].segment.states) == 4  # b's segment is still open, with b's ticks only
    (gone,) = agent.close_arm("b")
    assert (gone.arm, gone.reason, gone.H) == ("b", "h_max", 4)
    assert "s-b" not in agent.streams and agent.log.global_step == 8


def test_a_restarted_actors_new_stream_closes_its_old_streams_open_segment():
    env = gym.make("NSCartPoleContinuous-v0")
    agent = AdaptiveH(env, CONFIG, seed=0)
    obs, _ = env.reset(seed=0)
    for stream in ("old", "old", "new"):
        raw = np.array([0.3])
        nxt, reward, _, _, _ = env.step(raw)
        agent.learn_transition(obs, raw, reward, nxt, False, False, {}, None, "open", 0.9, stream=stream)
        obs = nxt
    assert [(r.reason, r.H) for r in agent.log.segments] == [("h_max", 2)]
    assert list(agent.streams) == ["new"]
