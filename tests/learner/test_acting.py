"""The one segment loop (``learner.acting``): in-process plan execution (the learner judging with its live
field) and the actor (judging with the learner's snapshot) run it on one scripted world, and their
segments end at the same ticks for the same reasons: a retreat where the world leaves the plan, H_max,
the episode's end, and a plan gone when the channel drops it."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np

from learner.acting import SegmentLoop
from learner.actor import Actor
from learner.adaptiveh import AdaptiveH
from learner.config import AdaptiveHConfig
from learner.plans import Executed, QueuedChannel
from learner.segments import Opening, SegmentEnd

JUMPS = (7, 19)  # ticks of an episode after which the world throws the state out of the plan's reach
EPISODE = 30
CONFIG = AdaptiveHConfig(
    execution="plan",
    retreat="plan",
    plan_tolerance="fixed",
    h_max=10,
    policy_budget=60,
    critic_budget=60,
)


class JumpWorld(gym.Env):
    """A point moved by its action, exactly as its model says, except at the ``JUMPS`` ticks."""

    observation_space = gym.spaces.Box(-6.0, 6.0, shape=(2,))
    action_space = gym.spaces.Box(-0.2, 0.2, shape=(2,))

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        self.x, self.t = np.zeros(2), 0
        return self.x.copy(), {}

    def predict_next(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        return np.clip(obs + np.clip(action, -0.2, 0.2), -6.0, 6.0)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.t += 1
        self.x = self.predict_next(self.x, action) + (np.array([4.0, 0.0]) if self.t in JUMPS else 0.0)
        return self.x.copy(), -float(np.linalg.norm(self.x)), False, self.t >= EPISODE, {}


def _ends(loop: SegmentLoop, episodes: int) -> list[list[tuple[int, str]]]:
    """(tick of the episode, how the segment ended) for every segment of ``episodes`` episodes the loop
    plays."""
    out = []
    for episode in range(episodes):
        loop.reset(seed=episode)
        ends, t = [], 0
        while True:
            tick = loop.tick()
            t += 1
            if tick.end != SegmentEnd.OPEN:
                ends.append((t, str(tick.end)))
            if tick.episode_over:
                break
        out.append(ends)
    return out


def test_in_process_plans_and_the_actor_end_segments_alike_on_one_scripted_world():
    learner = AdaptiveH(JumpWorld(), CONFIG, seed=0)
    learner.learn(6 * EPISODE)  # a gradient field where the plans go
    actor = Actor(JumpWorld(), CONFIG, seed=1)
    actor.load(learner.snapshot())
    as_actor = SegmentLoop(actor, QueuedChannel(JumpWorld()), actor.judge)
    beside_the_arm = _ends(as_actor, 3)
    start, before = learner.log.global_step, len(learner.log.segments)
    learner.learn(3 * EPISODE)  # in-process: the learner's own loop, learning and closing as it goes
    in_process = [[] for _ in range(3)]
    for record in learner.log.segments[before:]:
        episode, tick = divmod(record.global_step - start - 1, EPISODE)
        in_process[episode].append((tick + 1, record.reason))
    expected = [(7, "retreat"), (17, "h_max"), (19, "retreat"), (29, "h_max"), (30, "episode_end")]
    assert in_process == beside_the_arm == [expected] * 3
    assert learner.acting.ends[SegmentEnd.RETREAT] == 2 * 9  # six episodes of warm-up and three more
    assert as_actor.ends == {SegmentEnd.RETREAT: 6, SegmentEnd.H_MAX: 6, SegmentEnd.EPISODE_END: 3}


class DroppingChannel(QueuedChannel):
    """A channel that drops what is left of a plan after its third action (as an e-stop would)."""

    def advance(self) -> Executed:
        step = super().advance()
        if step.index == 2:
            self._queue.clear()
        return step


def test_a_plan_the_channel_drops_ends_its_segment_as_h_max_and_the_next_plan_says_so():
    actor = Actor(JumpWorld(), CONFIG.model_copy(update={"retreat": "off"}), seed=0)
    loop = SegmentLoop(actor, DroppingChannel(JumpWorld()), actor.judge)
    loop.reset(seed=0)
    ticks = [loop.tick() for _ in range(4)]
    assert [t.end for t in ticks] == ["open", "open", "open", "h_max"]  # the 4th tick held: plan gone
    assert ticks[3].step.plan_id == -1 and ticks[3].played.plan_gone
    loop.tick()
    assert loop.segment.plan.opened_by == Opening.H_MAX and loop.segments == 1


class GappyChannel(QueuedChannel):
    """Tick numbers as a robot's with an outage: five ticks go missing after the fourth."""

    def advance(self) -> Executed:
        step = super().advance()
        return dataclasses.replace(step, tick=step.tick + (5 if step.tick > 4 else 0))


def test_the_plan_model_learns_from_consecutive_ticks_only_an_episodes_first_from_the_reset():
    actor = Actor(JumpWorld(), CONFIG.model_copy(update={"plan_model": "corrected"}), seed=0)
    loop = SegmentLoop(actor, GappyChannel(JumpWorld()), actor.judge)
    loop.reset(seed=0)
    for _ in range(8):
        loop.tick()
    assert actor.model.updates == 7  # ticks 1-4 and 6-8 of the episode; not the 5th, after the gap
