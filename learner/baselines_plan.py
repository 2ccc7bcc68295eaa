"""Plan execution for the off-policy stable-baselines3 baselines (TD3, DDPG, SAC): the constraint of the
fixed-H RKHS learner in plan mode (``learner.plans``), met inside SB3's own rollout loop.

With ``plan_h = H > 1`` a segment is a committed plan of ``H`` actions made at the segment's first
state ``s0`` (every ``H`` steps and at each episode start): for ``i = 0..H-1`` the action SB3's
``_sample_action`` would take at the *predicted* observation ``ŝ_i`` — uniform random before
``learning_starts``, else the actor plus its action noise (TD3/DDPG) or a sample of the stochastic
policy (SAC) — then ``ŝ_{i+1} = predict_next(ŝ_i, a_i)`` (the env's nominal model), ``ŝ_0 = s0`` the
real observation. The plan then plays one action per step without consulting the policy again; the
replay buffer stores each *executed* action with the *real* observations around it, so the data stay
correct off-policy transitions and training is SB3's unchanged. The whole plan is sampled with the
networks and the warm-up rule as they are at ``s0`` (SB3 trains TD3/DDPG at episode ends, which also
end plans; SAC trains every step, so its later planned actions come from a slightly older policy, as
an RKHS plan's do). An episode's end drops what is left of the plan (``dropped_planned``, as
``QueuedChannel`` counts a preempted plan's rest); a plan never outlives its episode, so nothing else
preempts it, and the in-process loop has no learner latency. A predicted state that is not finite
ends the plan early (the policy never sees it).

Each finished segment is a ``SegmentRecord`` in the agent's ``RunLog`` as the RKHS plan mode makes
them: ``H`` the actions played, reason ``h_max`` (the plan played out) or ``episode_end``.
``plan_h = 1`` keeps stable-baselines3's own classes (the closed loop, bit for bit, no segments).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from stable_baselines3 import DDPG, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.noise import ActionNoise

from learner.plans import Model

SegmentSink = Callable[[int, str, int], None]  # (H played, reason, global step at its end)


class PlanQueue:
    """The plan an off-policy SB3 model plays: its actions, where they were planned, how far it has played.

    It counts like ``learner.plans.QueuedChannel`` (``dropped_planned``, ``preemptions``, ``latency``)
    so the benches record SB3 plan runs the way they record the RKHS learners' (``agent.channel``).
    """

    def __init__(self, h: int, model: Model, on_segment: SegmentSink) -> None:
        if h < 1:
            raise ValueError(f"plan_h must be >= 1, got {h}")
        self.h = int(h)
        self.model = model
        self.on_segment = on_segment
        self.dropped_planned = 0  # planned actions an episode's end dropped, total
        self.preemptions = 0  # a plan is only ever cut by its episode's end: always 0
        self.latency = 0  # SB3's loop plays a plan the step it is made
        self.plans_made = 0
        self.actions: np.ndarray | None = None  # (n, act_dim) in the env's action units
        self.buffer_actions: np.ndarray | None = None  # the same in SB3's [-1, 1] buffer units
        self.predicted: np.ndarray | None = None  # (n + 1, obs_dim): ŝ_0 = the real s0, then the model's
        self.index = 0  # the next action to play

    @property
    def open(self) -> bool:
        return self.actions is not None

    def start(self, actions: np.ndarray, buffer_actions: np.ndarray, predicted: np.ndarray) -> None:
        self.actions, self.buffer_actions, self.predicted = actions, buffer_actions, predicted
        self.index = 0
        self.plans_made += 1

    def next(self) -> tuple[np.ndarray, np.ndarray]:
        """(env action, buffer action) of the next planned step, each with SB3's env axis."""
        assert self.actions is not None and self.buffer_actions is not None
        i = self.index
        return self.actions[i : i + 1].copy(), self.buffer_actions[i : i + 1].copy()

    def played(self, done: bool, global_step: int) -> None:
        """The planned action ran; close the segment when the plan is played out or the episode ended."""
        if self.actions is None:  # a step with no plan open (never in SB3's loop): nothing to account
            return
        self.index += 1
        left = len(self.actions) - self.index
        if left <= 0:
            self._close("h_max", global_step)
        elif done:
            self.dropped_planned += left
            self._close("episode_end", global_step)

    def clear(self) -> None:
        """Forget the open plan without a record (the agent was restored onto a fresh episode)."""
        self.actions = self.buffer_actions = self.predicted = None
        self.index = 0

    def _close(self, reason: str, global_step: int) -> None:
        played = self.index
        self.clear()
        self.on_segment(played, reason, global_step)


class PlanMixin:
    """Plan execution for an off-policy SB3 algorithm; inert (SB3's own behaviour) while ``plan_queue``
    is None. Mixed in before the algorithm: ``class PlanTD3(PlanMixin, TD3)``."""

    plan_queue: PlanQueue | None = None

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "plan_queue"]  # type: ignore[misc]

    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        queue = self.plan_queue
        if queue is None:
            return super()._sample_action(learning_starts, action_noise, n_envs)  # type: ignore[misc]
        if n_envs != 1:
            raise ValueError(f"plan execution plays one env, got {n_envs}")
        if not queue.open:
            queue.start(*self._make_plan(queue, learning_starts, action_noise))
        return queue.next()

    def _make_plan(
        self, queue: PlanQueue, learning_starts: int, action_noise: ActionNoise | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """SB3's exploratory action at each predicted observation, rolled out through the model."""
        real = self._last_obs  # type: ignore[attr-defined]
        o = np.asarray(real, float).reshape(-1)
        predicted, actions, buffer_actions = [o], [], []
        try:
            for i in range(queue.h):
                if i > 0:  # the policy sees the predicted observation as SB3 would see a real one
                    self._last_obs = o.reshape(np.shape(real)).astype(np.asarray(real).dtype)
                action, buffer_action = super()._sample_action(learning_starts, action_noise, 1)  # type: ignore[misc]
                actions.append(action[0])
                buffer_actions.append(buffer_action[0])
                o = np.asarray(queue.model(o, action[0]), float).reshape(-1)
                predicted.append(o)
                if not np.all(np.isfinite(o)):
                    break  # the model left the state space: plan no further from it
        finally:
            self._last_obs = real
        return np.asarray(actions), np.asarray(buffer_actions), np.asarray(predicted)

    def _store_transition(
        self,
        replay_buffer: Any,
        buffer_action: np.ndarray,
        new_obs: Any,
        reward: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)  # type: ignore[misc]
        if self.plan_queue is not None:
            done = bool(np.asarray(dones).reshape(-1)[0])
            self.plan_queue.played(done, int(self.num_timesteps))  # type: ignore[attr-defined]


class PlanTD3(PlanMixin, TD3):
    """TD3 with plan execution (``learner.baselines_plan``)."""


class PlanDDPG(PlanMixin, DDPG):
    """DDPG with plan execution (``learner.baselines_plan``)."""


class PlanSAC(PlanMixin, SAC):
    """SAC with plan execution (``learner.baselines_plan``)."""


PLAN_CLASSES: dict[str, type[BaseAlgorithm]] = {"td3": PlanTD3, "ddpg": PlanDDPG, "sac": PlanSAC}


def world_model(env: Any) -> Model:
    """The env's nominal model ``predict_next``, as the RKHS plan mode takes it."""
    model = getattr(env.unwrapped, "predict_next", None)
    if model is None:
        name = type(env.unwrapped).__name__
        raise ValueError(
            f"plan_h > 1 (plan execution) needs the env's world model; {name} has no predict_next"
        )
    return model
