"""Aggregates over seeds: means with 95% percentile-bootstrap intervals, and differences of two means."""

from __future__ import annotations

from typing import Any

import numpy as np

N_BOOT = 2000


def bootstrap_mean(values: list[float] | np.ndarray, n_boot: int = N_BOOT, seed: int = 0) -> dict[str, Any]:
    """Mean with a 95% percentile-bootstrap interval over seeds (degenerate interval for one value)."""
    x = np.asarray([v for v in values if v is not None and np.isfinite(v)], float)
    if len(x) == 0:
        return {"mean": None, "lo": None, "hi": None, "n": 0}
    if len(x) == 1:
        return {"mean": float(x[0]), "lo": float(x[0]), "hi": float(x[0]), "n": 1}
    rng = np.random.default_rng(seed)
    boots = x[rng.integers(0, len(x), size=(n_boot, len(x)))].mean(axis=1)
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return {"mean": float(x.mean()), "lo": float(lo), "hi": float(hi), "n": int(len(x))}


def bootstrap_diff(a: list[float], b: list[float], n_boot: int = N_BOOT, seed: int = 0) -> dict[str, Any]:
    """mean(a) - mean(b) with a 95% bootstrap interval, resampling the seeds of each side apart."""
    xa = np.asarray([v for v in a if v is not None], float)
    xb = np.asarray([v for v in b if v is not None], float)
    if len(xa) == 0 or len(xb) == 0:
        return {"diff": None, "lo": None, "hi": None, "n_a": len(xa), "n_b": len(xb)}
    rng = np.random.default_rng(seed)
    da = xa[rng.integers(0, len(xa), size=(n_boot, len(xa)))].mean(axis=1)
    db = xb[rng.integers(0, len(xb), size=(n_boot, len(xb)))].mean(axis=1)
    lo, hi = np.percentile(da - db, [2.5, 97.5])
    return {
        "diff": float(xa.mean() - xb.mean()),
        "lo": float(lo),
        "hi": float(hi),
        "n_a": int(len(xa)),
        "n_b": int(len(xb)),
    }


def bootstrap_paired_diff(
    a: dict[int, float], b: dict[int, float], n_boot: int = N_BOOT, seed: int = 0
) -> dict[str, Any]:
    """Mean over the seeds both sides ran of ``a[seed] - b[seed]``, with a 95% bootstrap interval that
    resamples seeds, not sides: a seed fixes the world (its drift, the episodes' start states) for every
    method, so the per-seed differences are what the methods did differently in the same world.
    ``n_a`` and ``n_b`` are both the number of pairs (what :func:`outcome` reads)."""
    pairs = [a[k] - b[k] for k in sorted(set(a) & set(b)) if a[k] is not None and b[k] is not None]
    m = bootstrap_mean(pairs, n_boot, seed)
    return {"diff": m["mean"], "lo": m["lo"], "hi": m["hi"], "n_a": m["n"], "n_b": m["n"]}


def outcome(d: dict[str, Any], higher_is_better: bool = True) -> str:
    """better / worse / tie for side a, from the bootstrap interval of the difference."""
    if d["diff"] is None:
        return "missing"
    if min(d["n_a"], d["n_b"]) < 2:
        return "too few seeds"  # a one-seed "interval" has width zero and would decide anything
    lo, hi = (d["lo"], d["hi"]) if higher_is_better else (-d["hi"], -d["lo"])
    return "better" if lo > 0 else "worse" if hi < 0 else "tie"


Z95 = 1.959963984540054


def wilson(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson's score interval for a success rate: honest near 0 and 1, where a normal one is not."""
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return float(centre - half), float(centre + half)


def rate_diff(a: tuple[int, int], b: tuple[int, int]) -> dict[str, Any]:
    """``a`` minus ``b`` as success rates, each ``(successes, trials)``, with Newcombe's hybrid score 95%
    interval (from the two Wilson intervals). It takes trials as independent: episodes of one learner are
    not quite, so read the interval as the narrowest the data allow."""
    (sa, na), (sb, nb) = a, b
    pa, pb = sa / na, sb / nb
    (la, ua), (lb, ub) = wilson(sa, na), wilson(sb, nb)
    d = pa - pb
    return {
        "diff": d,
        "lo": d - float(np.hypot(pa - la, ub - pb)),
        "hi": d + float(np.hypot(ua - pa, pb - lb)),
        "n_a": na,
        "n_b": nb,
    }
