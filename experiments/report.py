"""The report of a (possibly partial) plan: ``summary.json`` from the finished run files.

Aggregates are the mean over seeds with a 95% percentile-bootstrap interval; the H statistics of
AdaptiveH, the hidden drift schedule, the verdicts, and which runs are missing, stale or from a
modified tree. ``tables`` writes ``summary.md`` from it and ``figures`` the PNGs.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from experiments.figures import make_figures
from experiments.machines import machines
from experiments.metrics import FINAL_FRACTION, RETURN_WINDOW
from experiments.plan import DRIFT_KEYS, ENVS, SPEED_ENVS, Plan
from experiments.stats import N_BOOT, bootstrap_mean
from experiments.tables import write_markdown
from experiments.verdicts import verdicts
from learner.run_summary import h_stats


def stale_runs(planned: list[Any], runs: dict[str, dict[str, Any]]) -> list[str]:
    """Runs finished under other hyperparameters than the plan's current ones (configs/*.yaml edited
    since): kept, as finished runs are never recomputed, but named so that nobody mistakes them."""
    return [
        r.name
        for r in planned
        if r.name in runs
        and (runs[r.name].get("config"), runs[r.name].get("env_kwargs")) != (r.config, r.env_kwargs)
    ]


def load_runs(plan: Plan, out_dir: Path) -> dict[str, dict[str, Any]]:
    runs = {}
    for spec in plan.runs:
        path = out_dir / "runs" / f"{spec.name}.json"
        if path.is_file():
            runs[spec.name] = json.loads(path.read_text())
    return runs


def _curve_stats(group: list[dict[str, Any]]) -> dict[str, Any]:
    if not group:
        return {"steps": [], "mean": [], "lo": [], "hi": [], "n": 0}
    steps = group[0]["metrics"]["curve_steps"]
    cols = np.array([[np.nan if v is None else v for v in g["metrics"]["curve"]] for g in group], float)
    stats = [bootstrap_mean(cols[:, i], seed=i) for i in range(cols.shape[1])]
    keep = [i for i, s in enumerate(stats) if s["n"] > 0]
    return {
        "steps": [steps[i] for i in keep],
        "mean": [stats[i]["mean"] for i in keep],
        "lo": [stats[i]["lo"] for i in keep],
        "hi": [stats[i]["hi"] for i in keep],
        "n": len(group),
    }


def _h_stats(group: list[dict[str, Any]]) -> dict[str, Any]:
    """Window H of AdaptiveH: per-seed mean/median, pooled distribution, evolution over training."""
    if not group:
        return {"n": 0}
    per_seed = [h_stats(g["segments"]["H"]) for g in group if g["segments"]["H"]]
    per_seed_mean = [s["mean"] for s in per_seed]
    per_seed_median = [s["median"] for s in per_seed]
    retreat_frac = [
        float(np.mean([r == "retreat" for r in g["segments"]["reason"]])) for g in group if g["segments"]["H"]
    ]
    pooled = np.concatenate([np.asarray(g["segments"]["H"], float) for g in group])
    pooled_stats = h_stats(pooled)
    budget = group[0]["steps"]
    edges = np.linspace(0, budget, 21)
    per_bin = []
    for g in group:
        st = np.asarray(g["segments"]["global_step"], float)
        hs = np.asarray(g["segments"]["H"], float)
        idx = np.clip(np.searchsorted(edges, st, side="left") - 1, 0, len(edges) - 2)
        per_bin.append([float(hs[idx == b].mean()) if np.any(idx == b) else np.nan for b in range(20)])
    cols = np.asarray(per_bin, float)
    evo = [bootstrap_mean(cols[:, b], seed=b) for b in range(20)]
    return {
        "n": len(group),
        "segments": int(len(pooled)),
        "mean_H": bootstrap_mean(per_seed_mean),
        "median_H": bootstrap_mean(per_seed_median),
        "retreat_fraction": bootstrap_mean(retreat_frac),
        "per_seed_mean_H": per_seed_mean,
        "per_seed_median_H": per_seed_median,
        "quantiles": {"p10": pooled_stats["p10"], "p50": pooled_stats["median"], "p90": pooled_stats["p90"]},
        "pooled_mean_H": pooled_stats["mean"],
        "histogram": {  # fraction of all segments (all seeds) with each H = 1 .. max
            "H": list(range(1, int(pooled.max()) + 1)),
            "fraction": (
                np.bincount(pooled.astype(int), minlength=int(pooled.max()) + 1)[1:] / len(pooled)
            ).tolist(),
        },
        "evolution": {
            "steps": [float((edges[b] + edges[b + 1]) / 2) for b in range(20) if evo[b]["n"]],
            "mean": [evo[b]["mean"] for b in range(20) if evo[b]["n"]],
            "lo": [evo[b]["lo"] for b in range(20) if evo[b]["n"]],
            "hi": [evo[b]["hi"] for b in range(20) if evo[b]["n"]],
        },
    }


def aggregate(plan: Plan, runs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """What the README quotes: per (env, algo) stats, curves, H statistics, verdicts, missing runs."""
    groups: dict[str, dict[str, Any]] = {}
    for env in plan.envs:
        groups[env] = {}
        for algo in plan.algos:
            g = plan.finished(runs, env, algo)
            m = [x["metrics"] for x in g]
            groups[env][algo] = {
                "n_runs": len(g),
                "seeds": sorted(x["seed"] for x in g),
                "return_mean": bootstrap_mean([x["return_mean"] for x in m]),
                "final_return": bootstrap_mean([x["final_return"] for x in m]),
                "steps_to_threshold": bootstrap_mean([x["steps_to_threshold"] for x in m]),
                "reached_fraction": float(np.mean([x["reached"] for x in m])) if m else None,
                "wall_s": bootstrap_mean([x["wall_s"] for x in g]),
                "steps_per_s": bootstrap_mean([_steps_per_s(x) for x in g]),
                "peak_rss_mb": bootstrap_mean([x["peak_rss_mb"] for x in g]),
                "curve": _curve_stats(g),
            }
    h = {env: _h_stats(plan.finished(runs, env, "adaptiveh")) for env in SPEED_ENVS if env in plan.envs}
    drift = {}
    for env in plan.envs:  # the hidden schedule at each episode end of the first finished run (same per seed)
        key = DRIFT_KEYS.get(ENVS[env].env_id)
        first = next((runs[r.name] for r in plan.runs if r.env == env and r.name in runs), None)
        if key and first and key in first["episodes"]["info"]:
            pairs = [(s, v) for s, v in zip(first["episodes"]["global_step"], first["episodes"]["info"][key],
                                            strict=True) if v is not None]  # fmt: skip
            drift[env] = {"key": key, "run": first["name"], "steps": [p[0] for p in pairs],
                          "values": [p[1] for p in pairs]}  # fmt: skip
    missing = [r.name for r in plan.runs if r.name not in runs]
    stale = stale_runs(plan.runs, runs)
    return {
        "plan": {
            "quick": plan.quick,
            "envs": {k: {**ENVS[k].model_dump(), "steps_used": plan.steps[k]} for k in plan.envs},
            "algos": plan.algos,
            "seeds": plan.seeds,
            "runs_total": len(plan.runs),
            "runs_finished": len(runs),
            "return_window_episodes": RETURN_WINDOW,
            "final_fraction": FINAL_FRACTION,
            "bootstrap_resamples": N_BOOT,
        },
        "groups": groups,
        "H": h,
        "drift": drift,
        "verdicts": verdicts(plan, runs, h),
        "cost": cost(plan, runs),
        "missing_runs": missing,
        "stale_runs": stale,
        # Which code produced the runs: commits (with run counts) and runs made from a modified tree.
        "code_commits": _count([str((r.get("code") or {}).get("commit")) for r in runs.values()]),
        "dirty_runs": sorted(n for n, r in runs.items() if (r.get("code") or {}).get("dirty") is not False),
        "machines": machines(runs),
    }


def _steps_per_s(run: dict[str, Any]) -> float:
    return run["global_step"] / run["wall_s"] if run["wall_s"] > 0 else 0.0


def _cost_of(group: list[dict[str, Any]]) -> dict[str, Any]:
    wall = [r["wall_s"] for r in group]
    rss = [r["peak_rss_mb"] for r in group]
    return {
        "runs": len(group),
        "wall_s_per_run": float(np.mean(wall)) if group else None,
        "wall_s_total": float(np.sum(wall)),
        # throughput over all the runs: env steps learned per second of ``learn`` (time-weighted)
        "steps_per_s": float(sum(r["global_step"] for r in group) / sum(wall)) if sum(wall) > 0 else None,
        "peak_rss_mb": float(np.mean(rss)) if group else None,
        "peak_rss_mb_max": float(np.max(rss)) if group else None,
    }


def cost(plan: Plan, runs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Throughput and memory of each method: wall-clock of ``learn`` per run, env steps per second and
    the run process's peak RSS (interpreter and libraries included), over all its finished runs and per
    setting, with its wall-clock per run relative to TD3's on the same setting (``wall_vs_td3``)."""
    out: dict[str, Any] = {}
    for algo in plan.algos:
        by_env = {env: _cost_of(plan.finished(runs, env, algo)) for env in plan.envs}
        for env, c in by_env.items():
            td3 = _cost_of(plan.finished(runs, env, "td3"))["wall_s_per_run"]
            mine = c["wall_s_per_run"]
            c["wall_vs_td3"] = mine / td3 if mine is not None and td3 else None
        ratios = [c["wall_vs_td3"] for c in by_env.values() if c["wall_vs_td3"] is not None]
        everything = [x for env in plan.envs for x in plan.finished(runs, env, algo)]
        out[algo] = {
            **_cost_of(everything),
            "wall_vs_td3_min": min(ratios) if ratios else None,
            "wall_vs_td3_max": max(ratios) if ratios else None,
            "by_env": by_env,
        }
    return out


def _count(items: list[str]) -> dict[str, int]:
    return {k: items.count(k) for k in sorted(set(items))}


def report(plan: Plan, out_dir: Path) -> dict[str, Any]:
    """Build ``summary.json`` and the figures from the finished runs (a partial set is fine)."""
    runs = load_runs(plan, out_dir)
    summary = aggregate(plan, runs)
    summary["figures"] = [p.name for p in make_figures(plan, summary, out_dir)]
    summary["tables"] = write_markdown(summary, out_dir).name
    summary["per_run"] = {
        name: {
            "wall_s": r["wall_s"],
            "steps_per_s": _steps_per_s(r),
            "peak_rss_mb": r["peak_rss_mb"],
            "executor": r.get("executor", "local"),
            **{k: r["metrics"][k] for k in ("return_mean", "final_return", "steps_to_threshold", "reached")},
        }
        for name, r in sorted(runs.items())
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False))
    return summary


def finite_leaves(obj: Any, path: str = "") -> list[str]:
    """Paths of numeric leaves that are not finite (NaN/inf): the report must have none."""
    bad = []
    if isinstance(obj, dict):
        for k, v in obj.items():
            bad += finite_leaves(v, f"{path}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            bad += finite_leaves(v, f"{path}[{i}]")
    elif isinstance(obj, float) and not math.isfinite(obj):
        bad.append(path)
    return bad
