"""The actor: AdaptiveH's planning and retreat test, held beside the robot, from a policy snapshot.

It plans a segment from the current state with the snapshot's policy over the states the world model
predicts, and at every executed tick evaluates the paper's retreat test where plan and world can
disagree (mode ``plan``: the inner product of the gradient field at the predicted and the reached
state). Learning (critic, field, policy update) is the learner's, from the transitions the actor
streams; a new snapshot takes effect at the next segment. Kernels, bounds, model and thresholds come
from the same config and env as the learner's, so the snapshot carries only what learning changes.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from learner.config import AdaptiveHConfig
from learner.dictionary import RKHSFunction
from learner.normalizer import StateNormalizer
from learner.parts import FIELD_BUDGET, initial_policy, kernels, retreat_threshold, segment_limit
from learner.plan_model import plan_model
from learner.plans import Plan, predicted_states, sample_plan
from learner.retreat import plan_statistic
from learner.snapshot import PolicySnapshot


class Actor:
    """Plans and judges plans with the newest accepted snapshot (``version`` -1: the initial policy)."""

    def __init__(self, env: gym.Env, config: AdaptiveHConfig, seed: int = 0) -> None:
        model = getattr(env.unwrapped, "predict_next", None)
        if model is None:
            raise ValueError(f"an actor needs the env's world model; {type(env.unwrapped).__name__} has none")
        self.config = config
        self.normalize = StateNormalizer.for_env(env)
        self.state_dim = len(self.normalize.centre)
        self.kernel, self.plan_tolerance = kernels(config, self.state_dim)
        self.policy = initial_policy(config, env, self.kernel)
        self.action_dim = len(self.policy.low)
        dims = (self.state_dim, self.action_dim)
        self.model = plan_model(config.plan_model, model, self.normalize, dims, config.plan_model_memory)
        self.field = RKHSFunction(self.kernel, self.action_dim, FIELD_BUDGET, config.policy_ald)
        self.threshold = retreat_threshold(config, self.kernel)
        self.retreats_on = config.retreat_mode != "off"
        self.segment_limit = segment_limit(config)
        self.max_centers = max(config.policy_budget, FIELD_BUDGET)
        self.version = -1
        self.rng = np.random.default_rng([seed, 2])
        self._next_plan_id = 0

    def check(self, snap: PolicySnapshot) -> None:
        """Raise ``SnapshotError`` unless ``snap`` fits this actor (dimensions, budget, finite values)."""
        snap.check(self.state_dim, self.action_dim, self.max_centers)

    def load(self, snap: PolicySnapshot) -> None:
        """Take ``snap``, which passed :meth:`check` where it arrived."""
        self.policy.f.dictionary.centers = snap.policy_centers
        self.policy.f.weights = snap.policy_weights
        self.field.dictionary.centers = snap.field_centers
        self.field.weights = snap.field_weights
        self.policy.explore(snap.sigma)
        self.version = snap.version

    def plan(self, obs: np.ndarray, segment: int, opened_by: str) -> Plan:
        """Segment ``segment``'s plan from ``obs``: ``segment_limit`` actions along the model's predicted
        states (``opened_by``: how the segment before it ended, ``learner.plans.opening``)."""
        noise: list[np.ndarray] = []

        def draw(o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            action, raw, n = self.policy.draw(self.normalize(o), self.rng)
            noise.append(n)
            return action, raw

        plan = sample_plan(self._next_plan_id, obs, self.segment_limit, self.model, draw, segment, opened_by)
        plan.noise = np.asarray(noise)  # the learner scores each action by it (its mean moves on meanwhile)
        self._next_plan_id += 1
        return plan

    def anchor(self, plan: Plan, obs: np.ndarray) -> None:
        """``plan``'s first action met ``obs``, not the state the plan was made from (it began ticks late,
        after the plan before's tail or a hold): its predictions are re-made from there, so the retreat
        judges what the world did to the plan, not when it began."""
        plan.predicted = predicted_states(self.model, obs, plan.actions)

    def statistic(self, ahead: int, predicted: np.ndarray, reached: np.ndarray) -> float | None:
        """The retreat statistic of a plan that predicted ``predicted`` ``ahead`` steps in and reached
        ``reached`` (observations); None where the field has no estimate yet (or the retreat is off)."""
        if not self.retreats_on:
            return None
        predicted, reached = self.normalize(predicted), self.normalize(reached)
        return plan_statistic(self.field, self.plan_tolerance, ahead, predicted, reached)

    def retreats(self, stat: float | None) -> bool:
        return stat is not None and stat < self.threshold
