"""Plan execution: a segment is a committed action plan that plays while the learner learns.

At a segment's first state the agent plans up to ``H`` actions with the segment's policy over states
that a model of the world *as believed then* predicts (``env.unwrapped.predict_next``: NS Reach moves
the end effector by the action and the target at its estimated velocity; NS CartPole and NS Pendulum
use their nominal dynamics, default gravity and no noise, never the drift). The plan then plays one
action per control step without waiting for the learner; a newer plan preempts what is left of the
old one. A :class:`PlanChannel` is where plans play: :class:`QueuedChannel` in-process (a queue in
front of a gymnasium env, with an optional learner latency), or a robot over Zenoh
(``deploy.zenoh_env.ZenohReachEnv``), which reports the same way.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from learner.segments import Opening, opening

Model = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass
class Plan:
    """``actions[i]`` (clipped to the action box) was planned at the predicted observation ``predicted[i]``;
    ``predicted[i + 1]`` is where the model expects it to lead. ``raw`` keeps the unclipped samples.

    A plan is one segment's actions: ``segment`` numbers it and ``opened_by`` says why it was made (how
    the plan before it ended: a ``learner.segments.Opening``), so whoever plays it can report a
    retreat's plan as one without a second account of segments."""

    plan_id: int
    actions: np.ndarray
    raw: np.ndarray
    predicted: np.ndarray  # len(actions) + 1 observations
    noise: np.ndarray | None = None  # raw - the mean that drew it, when the planner keeps it (an actor)
    segment: int = 0
    opened_by: Opening = Opening.FIRST

    def __post_init__(self) -> None:
        self.opened_by = Opening(self.opened_by)  # a ValueError naming the value for anything else


@dataclass
class Executed:
    """One control step of a channel: which plan's action ran (``plan_id`` -1: none, the arm held)."""

    plan_id: int
    index: int
    action: np.ndarray
    obs: np.ndarray
    reward: float
    terminated: bool
    truncated: bool
    info: dict[str, Any] = field(default_factory=dict)
    tick: int | None = None  # the channel's tick number (a robot's control tick), when it counts them


@dataclass(frozen=True)
class Played:
    """What a tick played, read against the open segment (``OpenSegment.tick``)."""

    source: Plan | None  # the plan whose action played (this segment's or one before), None for a hold
    current: bool  # it is this segment's plan
    plan_gone: bool  # a hold after this segment's plan had begun: played out, or dropped (e-stop, refusal)

    def raw(self, step: Executed) -> np.ndarray:
        """The unclipped sample of the action that played (a hold's: the action itself)."""
        return self.source.raw[step.index] if self.source is not None else np.asarray(step.action, float)

    def predicted(self, step: Executed) -> np.ndarray | None:
        """Where this segment's plan expected the tick to lead (None for any other plan's, or a hold)."""
        return self.source.predicted[step.index + 1] if self.current else None


class OpenSegment:
    """The one account of the segment in play, for whoever plays plans (``AdaptiveH`` in-process, the
    actor beside the arm): its plan, the plans that may still be playing (a tick can play the tail of the
    one before, or a plan sent late), the ticks since the last one closed, and why the next plan is made."""

    KEEP = 3  # plans by id: the open one and the two before it

    def __init__(self) -> None:
        self.plan: Plan | None = None
        self.opened_by = Opening.FIRST
        self.started = False  # one of its plan's actions has played
        self.ticks = 0
        self._recent: dict[int, Plan] = {}

    def open(self, plan: Plan) -> None:
        self.plan = plan
        self._recent = {k: v for k, v in self._recent.items() if k > plan.plan_id - self.KEEP}
        self._recent[plan.plan_id] = plan

    def tick(self, step: Executed) -> Played:
        """Account for one tick of the channel."""
        current = self.plan is not None and step.plan_id == self.plan.plan_id
        played = Played(self._recent.get(step.plan_id), current, step.plan_id == -1 and self.started)
        self.ticks += 1
        self.started = self.started or current
        return played

    def close(self, end: str) -> None:
        """The segment ended by ``end``: the next tick plans anew, and its plan says why."""
        self.plan, self.opened_by, self.started, self.ticks = None, opening(end), False, 0

    def new_episode(self) -> None:
        self.plan, self.opened_by, self.started, self.ticks = None, Opening.FIRST, False, 0


class PlanChannel(Protocol):
    """Where plans play. ``send`` never blocks; ``advance`` returns the next executed step."""

    dropped_planned: int  # planned actions dropped by a newer plan, total

    def reset(self, seed: int | None = None) -> tuple[np.ndarray, dict]: ...

    def send(self, plan: Plan) -> None: ...

    def queued(self, n: int) -> np.ndarray:
        """The actions that will play in the next ``n`` steps if nothing new arrives (for planning ahead)."""
        ...

    def advance(self) -> Executed: ...


def rollout(model: Model, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """The observation the model predicts after playing ``actions`` from ``obs``."""
    return predicted_states(model, obs, actions)[-1]


def predicted_states(model: Model, obs: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """``obs`` and the ``len(actions)`` observations the model predicts as ``actions`` play from it."""
    states = [np.asarray(obs, float)]
    for a in actions:
        states.append(model(states[-1], a))
    return np.asarray(states)


def sample_plan(
    plan_id: int,
    obs: np.ndarray,
    n: int,
    model: Model,
    sample: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    segment: int = 0,
    opened_by: Opening = Opening.FIRST,
) -> Plan:
    """``n`` actions drawn by ``sample(obs) -> (clipped, raw)`` along the states ``model`` predicts from
    ``obs``: segment ``segment``'s plan, made wherever the policy is held (the learner, or an actor)."""
    o = np.asarray(obs, float)
    predicted, actions, raws = [o], [], []
    for _ in range(n):
        a, raw = sample(o)
        o = model(o, a)
        actions.append(a)
        raws.append(raw)
        predicted.append(o)
    return Plan(
        plan_id,
        np.asarray(actions),
        np.asarray(raws),
        np.asarray(predicted),
        segment=segment,
        opened_by=opened_by,
    )


class QueuedChannel:
    """A gymnasium env behind a plan queue, as a robot plays it: one queued action per ``advance``.

    A plan sent now takes effect ``latency`` steps later (the learner's thinking time); until then the
    old plan keeps playing. With nothing queued the env gets ``hold`` (zero by default: no force, no
    torque, no displacement) and the step is reported with ``plan_id`` -1.
    """

    def __init__(self, env: gym.Env, latency: int = 0, hold: np.ndarray | None = None) -> None:
        if latency < 0:
            raise ValueError(f"latency must be >= 0 steps, got {latency}")
        self.env = env
        self.latency = latency
        shape = env.action_space.shape
        self.hold = np.zeros(shape) if hold is None else np.asarray(hold, float).reshape(shape)
        self.dropped_planned = 0
        self.preemptions = 0
        self._queue: deque[tuple[int, int, np.ndarray]] = deque()  # (plan_id, index, action)
        self._pending: deque[tuple[int, Plan]] = deque()  # (steps until it takes effect, plan)
        self._tick = 0  # steps since the episode began

    def reset(self, seed: int | None = None) -> tuple[np.ndarray, dict]:
        self._queue.clear()
        self._pending.clear()
        self._tick = 0
        return self.env.reset(seed=seed)

    def send(self, plan: Plan) -> None:
        self._pending.append((self.latency, plan))
        self._deliver()

    def queued(self, n: int) -> np.ndarray:
        """The next ``n`` actions as they will play: the queue, replaced by pending plans as they land."""
        queue, pending, out = list(self._queue), list(self._pending), []
        for t in range(n):
            for left, plan in pending:
                if left == t:
                    queue = [(plan.plan_id, i, a) for i, a in enumerate(plan.actions)]
            out.append(queue.pop(0)[2] if queue else self.hold)
        return np.asarray(out).reshape(-1, *self.hold.shape)

    def _deliver(self) -> None:
        while self._pending and self._pending[0][0] <= 0:
            _, plan = self._pending.popleft()
            if self._queue:
                self.preemptions += 1
                self.dropped_planned += len(self._queue)
            self._queue = deque((plan.plan_id, i, a) for i, a in enumerate(plan.actions))

    def advance(self) -> Executed:
        plan_id, index, action = self._queue.popleft() if self._queue else (-1, -1, self.hold)
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._pending = deque((left - 1, plan) for left, plan in self._pending)
        self._deliver()
        self._tick += 1
        action = np.asarray(action)
        return Executed(plan_id, index, action, obs, float(reward), terminated, truncated, info, self._tick)
