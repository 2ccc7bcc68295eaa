"""The RKHS learner's parts built from its config: the kernels, the policy before any update, the retreat's
threshold and the longest segment. The learner (``learner.adaptiveh``) and the actor beside the arm
(``learner.actor``) build theirs from the same config with these, so a snapshot carries only what
learning changes."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from learner.config import AdaptiveHConfig
from learner.kernels import GaussianKernel
from learner.plan_tolerance import (
    FixedTolerance,
    LearnedTolerance,
    NoiseFloorTolerance,
    PlanTolerance,
    narrowest_scale,
)
from learner.policy import RKHSGaussianPolicy
from learner.retreat import default_threshold


def kernels(cfg: AdaptiveHConfig, dim: int) -> tuple[GaussianKernel, PlanTolerance]:
    """(the policy's kernel, the plan tolerance that compares a plan's predicted state with the reached
    one: the policy's kernel narrowed by ``plan_kernel_scale``, widened by the measured sensor noise or
    not, or learned from the plan's own gaps; only the plan retreat reads it)."""
    for key in ("bandwidth", "plan_kernel_scale", "critic_bandwidth"):
        n = np.size(getattr(cfg, key))
        if getattr(cfg, key) is not None and n not in (1, dim):
            raise ValueError(f"{key}: expected 1 or {dim} values (one per state dimension), got {n}")
    kernel = GaussianKernel(np.asarray(cfg.bandwidth, float), dim)
    widths = kernel.bandwidth * narrowest_scale(kernel.bandwidth, cfg.plan_kernel_scale)
    if cfg.retreat_mode != "plan" or cfg.plan_tolerance == "fixed":
        return kernel, FixedTolerance(GaussianKernel(widths, dim))
    if cfg.plan_tolerance == "learned":
        threshold = retreat_threshold(cfg, kernel)
        return kernel, LearnedTolerance(dim, cfg.h_max, threshold, cfg.plan_false_alarm)
    return kernel, NoiseFloorTolerance(widths, retreat_threshold(cfg, kernel), cfg.plan_false_alarm)


def initial_policy(cfg: AdaptiveHConfig, env: gym.Env, kernel: GaussianKernel) -> RKHSGaussianPolicy:
    """The policy before any update: mean at the action box's centre, std ``sigma`` of its half-range."""
    low, high = env.action_space.low.astype(float), env.action_space.high.astype(float)
    return RKHSGaussianPolicy(
        kernel, low, high, cfg.sigma * (high - low) / 2.0, cfg.policy_budget, cfg.policy_ald
    )


def retreat_threshold(cfg: AdaptiveHConfig, kernel: GaussianKernel) -> float:
    if cfg.retreat_threshold is not None:
        return cfg.retreat_threshold
    return default_threshold(cfg.retreat_mode, kernel, cfg.epsilon)


def segment_limit(cfg: AdaptiveHConfig) -> int:
    """The longest segment: ``h_max`` with a retreat test, ``fixed_h`` without."""
    return cfg.h_max if cfg.retreat_mode != "off" else cfg.fixed_h


FIELD_BUDGET = 100  # the retreat's gradient field G: at most this many centres (and the policy budget)
