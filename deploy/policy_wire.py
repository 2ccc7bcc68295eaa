"""A policy snapshot (``learner.snapshot``) on the wire (``bus.messages.PolicySnapshot``) and back."""

from __future__ import annotations

import numpy as np

from bus import messages as m
from learner.snapshot import PolicySnapshot, SnapshotError


def snapshot_message(snap: PolicySnapshot) -> m.PolicySnapshot:
    return m.PolicySnapshot(
        version=snap.version,
        state_dim=snap.policy_centers.shape[1],
        action_dim=snap.policy_weights.shape[1],
        policy_centers=snap.policy_centers.ravel().tolist(),
        policy_weights=snap.policy_weights.ravel().tolist(),
        field_centers=snap.field_centers.ravel().tolist(),
        field_weights=snap.field_weights.ravel().tolist(),
        sigma=snap.sigma.tolist(),
    )


def _matrix(values: list[float], columns: int, name: str) -> np.ndarray:
    a = np.asarray(values, float)
    if columns < 1 or len(a) % columns:
        raise SnapshotError(f"{name}: {len(a)} values do not make rows of {columns}")
    return a.reshape(-1, columns)


def snapshot_from_message(msg: m.PolicySnapshot) -> PolicySnapshot:
    """The snapshot a message carries (``SnapshotError`` when its arrays do not make its shapes); the
    actor then checks it against its own dimensions (``PolicySnapshot.check``)."""
    s, a = msg.state_dim, msg.action_dim
    return PolicySnapshot(
        version=msg.version,
        policy_centers=_matrix(msg.policy_centers, s, "policy_centers"),
        policy_weights=_matrix(msg.policy_weights, a, "policy_weights"),
        field_centers=_matrix(msg.field_centers, s, "field_centers"),
        field_weights=_matrix(msg.field_weights, a, "field_weights"),
        sigma=np.asarray(msg.sigma, float),
    )
