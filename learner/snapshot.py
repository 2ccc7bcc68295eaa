"""A policy snapshot: what an actor beside the robot needs of the learner to plan and judge its plans.

The RKHS policy mean (centres and weights), the retreat's gradient field ``G`` (centres and weights) and
the exploration std now. Everything else (kernels, state bounds, the world model, thresholds) both sides
build from the same config, so a snapshot is a few kB. ``version`` is the learner's step count: a
learner resumed from its checkpoint goes on counting, so newer is always larger.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.errors import AdaptiveHError


class SnapshotError(AdaptiveHError, ValueError):
    """A snapshot that does not fit the actor's policy (its text says which part)."""


@dataclass(frozen=True)
class PolicySnapshot:
    version: int
    policy_centers: np.ndarray  # (M, state_dim), normalised states
    policy_weights: np.ndarray  # (M, action_dim)
    field_centers: np.ndarray  # (K, state_dim)
    field_weights: np.ndarray  # (K, action_dim)
    sigma: np.ndarray  # (action_dim,)

    def check(self, state_dim: int, action_dim: int, max_centers: int) -> None:
        """Raise :class:`SnapshotError` unless the shapes fit the actor's dimensions and budget and every
        value is finite with a positive std."""
        parts = {
            "policy": (self.policy_centers, self.policy_weights),
            "field": (self.field_centers, self.field_weights),
        }
        for name, (centers, weights) in parts.items():
            if centers.ndim != 2 or centers.shape[1] != state_dim:
                raise SnapshotError(f"{name} centres: expected (M, {state_dim}), got {centers.shape}")
            if weights.shape != (len(centers), action_dim):
                raise SnapshotError(
                    f"{name} weights: expected ({len(centers)}, {action_dim}), got {weights.shape}"
                )
            if len(centers) > max_centers:
                raise SnapshotError(f"{name}: {len(centers)} centres, more than the budget {max_centers}")
            if not (np.all(np.isfinite(centers)) and np.all(np.isfinite(weights))):
                raise SnapshotError(f"{name}: values must be finite")
        if (
            self.sigma.shape != (action_dim,)
            or not np.all(self.sigma > 0)
            or not np.all(np.isfinite(self.sigma))
        ):
            raise SnapshotError(f"sigma: expected {action_dim} positive finite values, got {self.sigma}")
