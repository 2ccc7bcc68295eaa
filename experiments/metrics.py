"""Per-run numbers of the paper bench, from the episodes the agent played while learning (as in the paper).

* ``return_mean``: mean return of all episodes of the run (the paper's "cumulative average return");
* ``final_return``: mean return of the episodes that ended in the last 10% of the steps;
* ``steps_to_threshold``: first step at which the mean of the last 5 episode returns reaches the
  environment's stated threshold (``reached`` false and the budget recorded when it never does);
* ``curve``: that trailing mean on a grid of ``CURVE_POINTS`` steps (the learning curve).
"""

from __future__ import annotations

from typing import Any

import numpy as np

CURVE_POINTS = 50
RETURN_WINDOW = 5  # episodes in the trailing mean used by curves and steps-to-threshold
FINAL_FRACTION = 0.1


def trailing_mean(steps: np.ndarray, returns: np.ndarray, at: np.ndarray, window: int) -> np.ndarray:
    """Mean of the last ``window`` episode returns ended at or before each step in ``at`` (NaN before)."""
    out = np.full(len(at), np.nan)
    csum = np.concatenate([[0.0], np.cumsum(returns)])
    for i, x in enumerate(at):
        n = int(np.searchsorted(steps, x, side="right"))
        if n:
            lo = max(0, n - window)
            out[i] = (csum[n] - csum[lo]) / (n - lo)
    return out


def run_metrics(
    ep_steps: list[int], ep_returns: list[float], budget: int, threshold: float
) -> dict[str, Any]:
    """The per-run numbers of the module docstring, from the episode list alone."""
    steps = np.asarray(ep_steps, float)
    rets = np.asarray(ep_returns, float)
    grid = np.linspace(budget / CURVE_POINTS, budget, CURVE_POINTS)
    if len(rets) == 0:
        return {
            "episodes": 0,
            "return_mean": None,
            "final_return": None,
            "steps_to_threshold": budget,
            "reached": False,
            "curve_steps": grid.tolist(),
            "curve": [None] * CURVE_POINTS,
        }
    final_mask = steps > budget * (1.0 - FINAL_FRACTION)
    final = float(rets[final_mask].mean()) if final_mask.any() else float(rets[-1])
    moving = trailing_mean(steps, rets, steps, RETURN_WINDOW)
    hit = np.nonzero(moving >= threshold)[0]
    curve = trailing_mean(steps, rets, grid, RETURN_WINDOW)
    return {
        "episodes": len(rets),
        "return_mean": float(rets.mean()),
        "final_return": final,
        "steps_to_threshold": int(steps[hit[0]]) if len(hit) else int(budget),
        "reached": bool(len(hit)),
        "curve_steps": grid.tolist(),
        "curve": [None if not np.isfinite(v) else float(v) for v in curve],
    }
