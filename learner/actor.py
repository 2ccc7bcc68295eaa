"""The actor: AdaptiveH's planning and retreat test, held beside the robot, from a policy snapshot.

It plans a segment from the current state with the snapshot's policy over the states the world model
predicts (``learner.acting.PolicyPlanner``), and at every executed tick evaluates the paper's retreat
test where plan and world can disagree (mode ``plan``: the inner product of the gradient field at the
predicted and the reached state). Learning (critic, field, policy update) is the learner's, from the
transitions the actor streams; a new snapshot takes effect at the next segment. Kernels, bounds, model
and thresholds come from the same config and env as the learner's, so the snapshot carries only what
learning changes.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from learner.acting import PolicyPlanner
from learner.config import AdaptiveHConfig
from learner.dictionary import RKHSFunction
from learner.normalizer import StateNormalizer
from learner.parts import FIELD_BUDGET, initial_policy, kernels, retreat_threshold, segment_limit
from learner.plan_model import plan_model
from learner.plans import Executed, Played
from learner.retreat import plan_statistic
from learner.snapshot import PolicySnapshot


class Actor(PolicyPlanner):
    """Plans and judges plans with the newest accepted snapshot (``version`` -1: the initial policy)."""

    def __init__(self, env: gym.Env, config: AdaptiveHConfig, seed: int = 0) -> None:
        nominal = getattr(env.unwrapped, "predict_next", None)
        if nominal is None:
            raise ValueError(f"an actor needs the env's world model; {type(env.unwrapped).__name__} has none")
        normalize = StateNormalizer.for_env(env)
        self.state_dim = len(normalize.centre)
        self.kernel, self.plan_tolerance = kernels(config, self.state_dim)
        policy = initial_policy(config, env, self.kernel)
        self.action_dim = len(policy.low)
        dims = (self.state_dim, self.action_dim)
        model = plan_model(config.plan_model, nominal, normalize, dims, config.plan_model_memory)
        super().__init__(policy, normalize, model, segment_limit(config), np.random.default_rng([seed, 2]))
        self.config = config
        self.field = RKHSFunction(self.kernel, self.action_dim, FIELD_BUDGET, config.policy_ald)
        self.threshold = retreat_threshold(config, self.kernel)
        self.retreats_on = config.retreat_mode != "off"
        self.max_centers = max(config.policy_budget, FIELD_BUDGET)
        self.version = -1

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

    def statistic(self, ahead: int, predicted: np.ndarray, reached: np.ndarray) -> float | None:
        """The retreat statistic of a plan that predicted ``predicted`` ``ahead`` steps in and reached
        ``reached`` (observations); None where the field has no estimate yet (or the retreat is off)."""
        if not self.retreats_on:
            return None
        predicted, reached = self.normalize(predicted), self.normalize(reached)
        return plan_statistic(self.field, self.plan_tolerance, ahead, predicted, reached)

    def retreats(self, stat: float | None) -> bool:
        return stat is not None and stat < self.threshold

    def judge(self, obs: np.ndarray, step: Executed, played: Played) -> tuple[float | None, bool]:
        """The segment loop's judge (``learner.acting.Judge``): a tick of this segment's plan is judged by
        the snapshot's field; any other tick (a hold, the tail of the plan before) is not."""
        if not played.current:
            return None, False
        stat = self.statistic(step.index + 1, played.predicted(step), step.obs)
        return stat, self.retreats(stat)
