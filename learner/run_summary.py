"""Headline numbers of a ``RunLog``: the one summary that ``train``, the learner node and the reports share.

``h_stats`` is the one place the window-length statistics are computed, so a run's result.json, the
stack's summary and the paper's report cannot disagree on what "median H" means.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from learner.protocol import RunLog
from learner.segments import CLOSED


def h_stats(H: Sequence[float] | np.ndarray) -> dict[str, float]:
    """Mean, median and 10th/90th percentiles of segment lengths (``H`` must not be empty)."""
    h = np.asarray(H, float)
    return {
        "mean": float(h.mean()),
        "median": float(np.median(h)),
        "p10": float(np.percentile(h, 10)),
        "p90": float(np.percentile(h, 90)),
    }


def summarize(log: RunLog) -> dict[str, Any]:
    """Returns, segment lengths, why segments ended, the retreat-statistic trace and the success rate."""
    rets = np.array([e.ret for e in log.episodes], float)
    stats = np.array([x for s in log.segments for x in s.statistic], float)
    tenth = max(1, len(rets) // 10)
    out: dict[str, Any] = {
        "episodes": len(rets),
        "mean_return": float(rets.mean()) if len(rets) else None,
        "final_return": float(rets[-tenth:].mean()) if len(rets) else None,
        "best_return": float(rets.max()) if len(rets) else None,
        "segments": len(log.segments),
        "reasons": {r.value: sum(1 for s in log.segments if s.reason == r) for r in CLOSED},
    }
    if log.segments:
        out["H"] = h_stats([s.H for s in log.segments])
    if len(stats):
        out["statistic"] = {
            "count": int(len(stats)),
            "mean": float(stats.mean()),
            "p10": float(np.percentile(stats, 10)),
            "p50": float(np.median(stats)),
            "p90": float(np.percentile(stats, 90)),
            "threshold": float(log.segments[0].threshold),
        }
    successes = [e.success for e in log.episodes if e.success is not None]
    if successes:
        out["success_rate"] = float(np.mean(successes))
    return out
