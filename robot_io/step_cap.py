"""The arm's rule for a Cartesian step: at most ``robot.max_step_m`` long. Robot-io refuses a plan with a
longer step and caps an in-process one; a sender caps its plans before they go out, and the plan model
predicts the capped step: all three with this one function."""

from __future__ import annotations

import numpy as np


def cap_step_length(steps: np.ndarray, max_step: float) -> np.ndarray:
    """``steps`` (one step, or one per row) each scaled down to at most ``max_step`` metres; shorter ones
    unchanged, bit for bit."""
    steps = np.asarray(steps, float)
    norms = np.linalg.norm(steps, axis=-1, keepdims=True)
    return steps * np.minimum(1.0, max_step / np.maximum(norms, 1e-12))
