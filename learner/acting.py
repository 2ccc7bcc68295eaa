"""The one segment loop: plan from a policy, send the plan to a channel, advance tick by tick, judge the
retreat, close the segment by the paper's rules (``learner.segments.segment_end``).

Both ways the product acts run it. The actor beside the arm (``deploy.actor_node``) runs it on robot-io's
channel (``deploy.zenoh_env``) and judges with the gradient field of its newest policy snapshot
(``learner.actor.Actor``). AdaptiveH's in-process plan execution runs it on a queue in front of a
gymnasium env (``learner.plans.QueuedChannel``), with the learner as its own actor: it plans with the
live policy and judges with the live field, after learning from the tick (no snapshot, no wire).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from learner.normalizer import StateNormalizer
from learner.plan_model import CorrectedModel, NominalModel
from learner.plans import (
    Executed,
    OpenSegment,
    Plan,
    PlanChannel,
    Played,
    predicted_states,
    rollout,
    sample_plan,
)
from learner.policy import RKHSGaussianPolicy
from learner.segments import Opening, SegmentEnd, segment_end

Judge = Callable[[np.ndarray, Executed, Played], tuple[float | None, bool]]
"""``(obs, step, played) -> (retreat statistic or None, retreat?)`` for one tick acted from ``obs``."""


class PolicyPlanner:
    """Plans a segment's actions with a policy over the states a world model predicts."""

    def __init__(
        self,
        policy: RKHSGaussianPolicy,
        normalize: StateNormalizer,
        model: NominalModel | CorrectedModel,
        segment_limit: int,
        rng: np.random.Generator,
        lookahead: int = 0,
    ) -> None:
        self.policy, self.normalize, self.model, self.rng = policy, normalize, model, rng
        self.segment_limit = segment_limit
        self.lookahead = lookahead  # ticks between the state a plan is made from and its first action
        self._next_plan_id = 0

    def plan(self, obs: np.ndarray, segment: int, opened_by: Opening) -> Plan:
        """Segment ``segment``'s plan of ``segment_limit`` actions from ``obs`` (``opened_by``: how the
        segment before it ended). Each action keeps the exploration noise that drew it: a learner whose
        mean has moved on since scores it by that noise."""
        noise: list[np.ndarray] = []

        def draw(o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            action, raw, n = self.policy.draw(self.normalize(o), self.rng)
            noise.append(n)
            return action, raw

        plan = sample_plan(self._next_plan_id, obs, self.segment_limit, self.model, draw, segment, opened_by)
        plan.noise = np.asarray(noise)
        self._next_plan_id += 1
        return plan

    def anchor(self, plan: Plan, obs: np.ndarray) -> None:
        """``plan``'s first action met ``obs``, not the state it was made for (it began ticks late, after
        the plan before's tail or a hold): its predictions are re-made from there, so the retreat judges
        what the world did to the plan, not when it began."""
        plan.predicted = predicted_states(self.model, obs, plan.actions)


class Planner(Protocol):
    model: NominalModel | CorrectedModel
    segment_limit: int
    lookahead: int

    def plan(self, obs: np.ndarray, segment: int, opened_by: Opening) -> Plan: ...

    def anchor(self, plan: Plan, obs: np.ndarray) -> None: ...


@dataclass(frozen=True)
class Tick:
    """One tick of the loop: acted from ``obs``, what played, the retreat statistic and how the segment
    (number ``segment``) stands after it."""

    obs: np.ndarray
    step: Executed
    played: Played
    statistic: float | None
    end: SegmentEnd
    segment: int

    @property
    def episode_over(self) -> bool:
        return bool(self.step.terminated or self.step.truncated)


def _never() -> None:
    return None


def _always() -> bool:
    return True


class SegmentLoop:
    """Plays segments on ``channel``: a plan when none is open (and ``ready()``: a channel with ticks
    still to read plans from the newest only), ``before_plan()`` first (take a new snapshot, move a
    schedule on). ``segments``, ``ends`` and ``starts`` count what it did."""

    def __init__(
        self,
        planner: Planner,
        channel: PlanChannel,
        judge: Judge,
        ready: Callable[[], bool] = _always,
        before_plan: Callable[[], None] = _never,
    ) -> None:
        self.planner, self.channel, self.judge = planner, channel, judge
        self.ready, self.before_plan = ready, before_plan
        self.segment = OpenSegment()
        self.segments = 0  # closed so far: the number of the segment in play
        self.ends: Counter[SegmentEnd] = Counter()
        # Plans whose first action played, those that began ticks after the state they were made for, and
        # those ticks in all.
        self.starts = {"plan_starts": 0, "plan_starts_late": 0, "late_ticks": 0}
        self.obs: np.ndarray | None = None  # the state the next tick acts from
        self._tick: int | None = None  # the robot tick ``obs`` is from
        self._planned_for: int | None = None  # the tick the open plan was made for

    def reset(self, seed: int | None) -> tuple[np.ndarray, dict]:
        """A new episode on the channel."""
        obs, info = self.channel.reset(seed=seed)
        self.begin(obs, info.get("tick", 0))
        return obs, info

    def begin(self, obs: np.ndarray, tick: int | None = 0) -> None:
        """Act from ``obs`` (of robot tick ``tick``) with no segment open: an episode's start."""
        self.obs, self._tick = np.asarray(obs, float), tick
        self.segment.new_episode()

    def tick(self) -> Tick:
        """Plan if due, play one tick, judge it, close the segment when a rule says so."""
        seg = self.segment
        if seg.plan is None and self.ready():
            self._open()
        step = self.channel.advance()
        if step.plan_id != -1 and self._follows(step):
            self.planner.model.observe(self.obs, step.action, step.obs)  # what the world did with it
        played = seg.tick(step)
        if played.current and step.index == 0:
            self._plan_started(played.source, step.tick)
        statistic, retreat = self.judge(self.obs, step, played)
        over = step.terminated or step.truncated
        end = segment_end(retreat, seg.ticks, self.planner.segment_limit, over, played.plan_gone)
        tick = Tick(self.obs, step, played, statistic, end, self.segments)
        if end != SegmentEnd.OPEN:
            seg.close(end)
            self.segments += 1
            self.ends[end] += 1
        self._tick = step.tick
        if np.all(np.isfinite(step.obs)):  # else act on from the last finite state: NaN never plans
            self.obs = np.asarray(step.obs, float)
        return tick

    def _open(self) -> None:
        self.before_plan()
        ahead = self.planner.lookahead
        start = rollout(self.planner.model, self.obs, self.channel.queued(ahead)) if ahead else self.obs
        plan = self.planner.plan(start, self.segments, self.segment.opened_by)
        self.segment.open(plan)
        self._planned_for = None if self._tick is None else self._tick + ahead
        self.channel.send(plan)

    def _follows(self, step: Executed) -> bool:
        """``step`` is the tick right after ``obs``'s: the plan model learns from consecutive ticks only."""
        return step.tick is not None and self._tick is not None and step.tick == self._tick + 1

    def _plan_started(self, plan: Plan, tick: int | None) -> None:
        """``plan``'s first action played at ``tick``; when ticks played between the state it was made for
        and it, it is re-anchored at ``obs``, the state that action met (consecutive ticks only)."""
        if tick is None or self._planned_for is None:
            return
        late = tick - self._planned_for - 1
        self.starts["plan_starts"] += 1
        if late > 0:
            self.starts["plan_starts_late"] += 1
            self.starts["late_ticks"] += late
            if self._tick == tick - 1:
                self.planner.anchor(plan, self.obs)
