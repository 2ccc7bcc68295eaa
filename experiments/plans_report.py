"""The report of the plans experiment: ``summary.json``, ``summary.md`` and figures from the finished runs.

Per setting: the fixed-H **front** (final return against re-plans per 100 steps, mean over seeds with
95% bootstrap intervals), each AdaptiveH **point** with its interval and its distance to the front —
the front's return interpolated at the point's re-plan rate (linear in log re-plan rate, between the
two fixed-H neighbours; clamped at the front's ends, marked ``extrapolated``), the difference with a
bootstrap interval that resamples the seeds of every group apart —, the **latency** curves, **H under
slow vs fast drift**, the **baselines in plan mode** (TD3/DDPG/SAC re-planning every H steps over the
same model, placed against the front like a point), TD3/DDPG/SAC closed-loop (H = 1) reference points
from the paper bench, verdicts, and which runs are missing.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from experiments.machines import machines
from experiments.plans import (
    DEFAULT_METHOD,
    DRIFT_PAIRS,
    LATENCY_THRESHOLD,
    PLAN_BASELINES,
    SETTINGS,
    PlansPlan,
    baseline_of,
    env_kwargs,
    fixed_method,
    method_label,
    plan_method,
)
from experiments.plans_figures import make_plans_figures
from experiments.plans_tables import write_plans_markdown
from experiments.report import _count, _h_stats, load_runs, stale_runs
from experiments.stats import N_BOOT, bootstrap_diff, bootstrap_mean, bootstrap_paired_diff, outcome
from experiments.verdicts import _overall
from learner.run_summary import h_stats

BASELINES = ("td3", "ddpg", "sac")  # closed-loop reference points taken from the paper bench
POSITION = {"better": "above the front", "worse": "below the front", "tie": "on the front (tie)"}


def closed_loop_baseline(run: dict[str, Any]) -> bool:
    """An SB3 baseline run with ``plan_h`` 1: SB3's closed loop, which records no segments."""
    plan_h = (run.get("config") or {}).get("plan_h", 1)
    return run.get("algo") in PLAN_BASELINES and int(plan_h) == 1


def run_numbers(run: dict[str, Any]) -> dict[str, Any]:
    """The per-run numbers of the experiment (the run file keeps every segment's H and global step).

    A closed-loop SB3 run (``plan_h`` 1) records no segments: it chooses anew at every step, i.e. one
    segment of H = 1 per step and nothing ever dropped.
    """
    seg = run["segments"]
    steps = max(1, int(run["global_step"]))
    channel = run.get("plan_channel") or {}
    dropped = channel.get("dropped_planned")
    if closed_loop_baseline(run) and not seg["H"]:
        seg = {"H": [1] * int(run["global_step"]), "reason": ["h_max"] * int(run["global_step"])}
        dropped = 0
    hs = h_stats(seg["H"]) if seg["H"] else {"mean": None, "median": None}
    retreats = sum(r == "retreat" for r in seg["reason"])
    return {
        "final_return": run["metrics"]["final_return"],
        "return_mean": run["metrics"]["return_mean"],
        "replans_per_100": 100.0 * len(seg["H"]) / steps,
        "H_mean": hs["mean"],
        "H_median": hs["median"],
        "segments": len(seg["H"]),
        "retreats": int(retreats),
        "retreats_per_100": 100.0 * retreats / steps,
        "dropped_planned": dropped,
        "dropped_planned_per_100": None if dropped is None else 100.0 * dropped / steps,
        "latency_steps": channel.get("latency_steps"),
        "wall_s": run["wall_s"],
    }


STAT_KEYS = (
    "final_return",
    "return_mean",
    "replans_per_100",
    "H_mean",
    "H_median",
    "retreats_per_100",
    "dropped_planned_per_100",
    "wall_s",
)


def group_stats(group: list[dict[str, Any]]) -> dict[str, Any]:
    nums = [run_numbers(r) for r in group]
    out: dict[str, Any] = {"n": len(group), "seeds": sorted(r["seed"] for r in group)}
    for key in STAT_KEYS:
        out[key] = bootstrap_mean([x[key] for x in nums])
    out["per_seed"] = {key: [x[key] for x in nums] for key in ("final_return", "replans_per_100", "H_mean")}
    return out


def interp_log_rate(rates: np.ndarray, rets: np.ndarray, at: float) -> float:
    """The front's return at re-plan rate ``at``: linear in log rate, clamped at the front's ends."""
    order = np.argsort(rates)
    return float(np.interp(np.log(at), np.log(rates[order]), rets[order]))


def front_gap(
    front: list[tuple[list[float], list[float]]],
    point: tuple[list[float], list[float]],
    n_boot: int = N_BOOT,
    seed: int = 0,
) -> dict[str, Any]:
    """Point return minus the front's return interpolated at the point's re-plan rate.

    ``front``: per fixed H, (per-seed re-plan rates, per-seed returns); ``point`` the same for AdaptiveH.
    Interpolation is linear in log re-plan rate and clamped at the front's ends. The interval resamples
    the seeds of each group apart (each bootstrap replicate re-draws the front and the point).
    """
    groups = [(np.asarray(r, float), np.asarray(v, float)) for r, v in front if len(r)]
    pr, pv = np.asarray(point[0], float), np.asarray(point[1], float)
    if len(groups) < 2 or len(pr) == 0:
        return {
            "diff": None,
            "lo": None,
            "hi": None,
            "n_a": len(pr),
            "n_b": min((len(g[0]) for g in groups), default=0),
            "front_at_rate": None,
            "extrapolated": None,
        }

    mean_rates = np.array([g[0].mean() for g in groups])
    mean_rets = np.array([g[1].mean() for g in groups])
    at = float(pr.mean())
    front_at = interp_log_rate(mean_rates, mean_rets, at)
    rng = np.random.default_rng(seed)
    boot_front = []
    for rates, rets in groups:  # the same seed draw for a group's rate and return
        idx = rng.integers(0, len(rates), size=(n_boot, len(rates)))
        boot_front.append((rates[idx].mean(axis=1), rets[idx].mean(axis=1)))
    idx = rng.integers(0, len(pr), size=(n_boot, len(pr)))
    b_rate, b_ret = pr[idx].mean(axis=1), pv[idx].mean(axis=1)
    diffs = np.array(
        [
            b_ret[b]
            - interp_log_rate(
                np.array([f[0][b] for f in boot_front]), np.array([f[1][b] for f in boot_front]), b_rate[b]
            )
            for b in range(n_boot)
        ]
    )
    lo, hi = np.percentile(diffs, [2.5, 97.5])
    return {
        "diff": float(pv.mean() - front_at),
        "lo": float(lo),
        "hi": float(hi),
        "n_a": int(len(pr)),
        "n_b": int(min(len(g[0]) for g in groups)),
        "point_rate": at,
        "front_at_rate": front_at,
        "extrapolated": bool(at < mean_rates.min() or at > mean_rates.max()),
    }


def front_gap_paired(front: list[dict[str, Any]], point: dict[str, Any], seed: int = 0) -> dict[str, Any]:
    """Per seed, the point's final return minus that seed's own fixed-H front interpolated at that seed's
    re-plan rate (as :func:`front_gap`, one world at a time), averaged over the seeds with a 95% interval
    that resamples seeds. ``per_seed`` keeps each seed's difference."""
    diffs: dict[int, float] = {}
    for i, s in enumerate(point["seeds"]):
        rates, rets = [], []
        for f in front:
            if s in f["seeds"]:
                j = f["seeds"].index(s)
                rates.append(f["per_seed"]["replans_per_100"][j])
                rets.append(f["per_seed"]["final_return"][j])
        if len(rates) >= 2:
            at = point["per_seed"]["replans_per_100"][i]
            front_at = interp_log_rate(np.asarray(rates), np.asarray(rets), at)
            diffs[s] = point["per_seed"]["final_return"][i] - front_at
    m = bootstrap_mean(list(diffs.values()), seed=seed)
    d = {"diff": m["mean"], "lo": m["lo"], "hi": m["hi"], "n_a": m["n"], "n_b": m["n"]}
    return {**d, "outcome": outcome(d), "per_seed": {str(k): v for k, v in diffs.items()}}


def best_fixed_h_per_seed(front: list[dict[str, Any]], seeds: list[int]) -> list[float] | None:
    """On each seed, the highest final return any fixed H reached there (a per-seed oracle over H); None
    when some seed has no fixed-H run."""
    by_h = [finals_by_seed(f) for f in front]
    best = [max((finals[s] for finals in by_h if s in finals), default=None) for s in seeds]
    return None if None in best else best


def front_gap_if_best(
    front: list[dict[str, Any]], pairs: list[tuple[list[float], list[float]]], st: dict[str, Any], seed: int
) -> dict[str, Any] | None:
    """What the unpaired comparison can resolve at a point's re-plan rates: its gap to the front (as
    :func:`front_gap`) had it returned, on each seed, the best fixed H's return there. When even this
    interval holds zero, a point re-planning this often is on the front unless it beats every fixed H;
    only fewer re-plans at the same return can put it above."""
    if not st["n"]:
        return None
    best = best_fixed_h_per_seed(front, st["seeds"])
    if best is None:
        return None
    gap = front_gap(pairs, (st["per_seed"]["replans_per_100"], best), seed=seed)
    return {**gap, "outcome": outcome(gap), "returns": best}


def finals_by_seed(group: dict[str, Any]) -> dict[int, float]:
    """A group's final return on each seed it ran."""
    return dict(zip(group["seeds"], group["per_seed"]["final_return"], strict=True))


def per_seed_minus(point: dict[str, Any], other: dict[str, Any]) -> dict[str, float]:
    """``point − other`` final return on each seed both ran."""
    a, b = finals_by_seed(point), finals_by_seed(other)
    return {str(k): a[k] - b[k] for k in sorted(set(a) & set(b))}


def _vs_closed_loop(point: dict[str, Any], h1: dict[str, Any] | None) -> dict[str, Any] | None:
    """The point against fixed H = 1 (the closed loop), paired per seed, and how many times fewer
    re-plans it needed."""
    if h1 is None or not point["n"]:
        return None
    d = bootstrap_paired_diff(finals_by_seed(point), finals_by_seed(h1))
    ratio = h1["replans_per_100"]["mean"] / point["replans_per_100"]["mean"]
    return {**d, "outcome": outcome(d), "fewer_replans": ratio}


def _vs_front(pairs: list[tuple[list[float], list[float]]], st: dict[str, Any], seed: int) -> dict[str, Any]:
    """A group's final return against the fixed-H front at its re-plan rate (``front_gap``), with outcome."""
    gap = front_gap(pairs, (st["per_seed"]["replans_per_100"], st["per_seed"]["final_return"]), seed=seed)
    gap["outcome"] = outcome(gap)
    gap["position"] = POSITION.get(gap["outcome"], gap["outcome"])
    return {"metric": "final_return", "interpolation": "linear in log re-plans/100", **gap}


def _plan_baselines(
    plan: PlansPlan,
    runs: dict[str, dict[str, Any]],
    key: str,
    pairs: list[tuple[list[float], list[float]]],
    closed: dict[str, Any],
) -> dict[str, Any]:
    """The baselines in plan mode on this setting (those planned here; a group without finished runs
    has n 0): their numbers, their place against the front, and the plan's cost against their closed
    loop (the paper bench's H = 1 run of the same env and seeds, when there is one)."""
    out: dict[str, Any] = {}
    if key not in plan.baseline_settings:
        return out
    for i, method in enumerate(plan.baseline_methods):
        algo, h = baseline_of(method)  # type: ignore[misc]
        st = group_stats(plan.finished(runs, key, method))
        vs_closed = None
        if algo in closed:
            d = bootstrap_diff(st["per_seed"]["final_return"], closed[algo]["per_seed"])
            vs_closed = {**d, "outcome": outcome(d)}
        out[method] = {
            "label": method_label(method),
            "algo": algo,
            "H": h,
            **st,
            "planned_seeds": [r.seed for r in plan.planned(key, method)],
            "vs_front": _vs_front(pairs, st, seed=100 + i),
            "minus_closed_loop": vs_closed,  # plan mode minus the same algorithm's closed loop
        }
    return out


def _setting(plan: PlansPlan, runs: dict[str, dict[str, Any]], key: str, base: dict[str, Any]) -> dict:
    front = []
    for h in plan.front_h:
        g = plan.finished(runs, key, fixed_method(h))
        front.append({"H": h, "method": fixed_method(h), **group_stats(g)})
    pairs = {
        metric: [(f["per_seed"]["replans_per_100"], f["per_seed"][metric]) for f in front]
        for metric in ("final_return",)
    }
    plan_base = _plan_baselines(plan, runs, key, pairs["final_return"], base)
    best = max((f for f in front if f["n"]), key=lambda f: f["final_return"]["mean"], default=None)
    points = {}
    for i, method in enumerate(m for m in plan.points if plan.planned(key, m)):
        group = plan.finished(runs, key, method)
        st = group_stats(group)
        rate = st["replans_per_100"]["mean"]
        dominated_by = [
            f["H"]
            for f in front
            if f["n"]
            and rate is not None
            and f["replans_per_100"]["mean"] <= rate
            and f["final_return"]["mean"] > st["final_return"]["mean"]
        ]  # fixed H with no more re-plans and a higher mean return (point estimates)
        vs_best = None
        if best is not None:
            d = bootstrap_diff(st["per_seed"]["final_return"], best["per_seed"]["final_return"])
            vs_best = {"H": best["H"], **d, "outcome": outcome(d)}
        vs_base = {}
        for algo, b in base.items():
            d = bootstrap_diff(st["per_seed"]["final_return"], b["per_seed"])
            vs_base[algo] = {**d, "outcome": outcome(d)}
        vs_plan_base = {}
        for other, b in plan_base.items():  # the same constraint: AdaptiveH minus the baseline in plan mode
            d = bootstrap_diff(st["per_seed"]["final_return"], b["per_seed"]["final_return"])
            vs_plan_base[other] = {**d, "outcome": outcome(d)}
        hs = _h_stats(group) if group else {"n": 0}
        by_h = {f["H"]: f for f in front if f["n"]}
        points[method] = {
            "vs_front_paired": front_gap_paired(front, st, seed=i),
            "vs_H1_paired": _vs_closed_loop(st, by_h.get(1)),
            # Against fixed H = 5 on the same seed: a seed below it is a collapse to name.
            "minus_H5_per_seed": per_seed_minus(st, by_h[5]) if 5 in by_h and st["n"] else {},
            "label": method_label(method),
            **st,
            "vs_front": _vs_front(pairs["final_return"], st, seed=i),
            "vs_front_if_best_fixed_H": front_gap_if_best(front, pairs["final_return"], st, seed=i),
            "dominated_by_fixed_H": dominated_by,
            "vs_best_fixed_H": vs_best,
            "vs_closed_loop_baselines": vs_base,
            "vs_plan_baselines": vs_plan_base,
            "H_over_time": hs.get("evolution"),
            "per_seed_median_H": hs.get("per_seed_median_H", []),
        }
    return {
        "label": SETTINGS[key].label,
        "steps": plan.steps[key],
        "front": front,
        "points": points,
        "baselines": base,
        "plan_baselines": plan_base,
    }


def paper_baselines(plan: PlansPlan, key: str, paper_dir: Path | None) -> dict[str, Any]:
    """TD3/DDPG/SAC closed-loop final returns from the paper bench's runs of the same env, seeds and steps
    (H = 1 of the plan-mode baselines: SB3's own loop, which the paper bench runs unchanged)."""
    out: dict[str, Any] = {}
    if paper_dir is None:
        return out
    for algo in BASELINES:
        vals, rets, seeds = [], [], []
        for seed in plan.seeds:
            path = paper_dir / "runs" / f"{key}__{algo}__s{seed}__{plan.steps[key]}.json"
            if not path.is_file():
                continue
            run = json.loads(path.read_text())
            if run.get("env_kwargs") != env_kwargs(SETTINGS[key], seed):
                continue  # another world: not comparable
            vals.append(run["metrics"]["final_return"])
            rets.append(run["metrics"]["return_mean"])
            seeds.append(seed)
        if vals:
            out[algo] = {
                "n": len(vals),
                "seeds": seeds,
                "final_return": bootstrap_mean(vals),
                "return_mean": bootstrap_mean(rets),
                "per_seed": vals,
                "execution": "closed loop (H = 1), results/paper",
                "replans_per_100": 100.0,
                "H": 1,
            }
    return out


def _minus_fixed(
    curves: dict[str, Any], latencies: list[int], method: str, rivals: tuple[str, ...]
) -> dict[str, Any]:
    """``method`` minus each rival (final return) at each latency, keyed ``L<latency>:<rival>``."""
    out = {}
    for i, lat in enumerate(latencies):
        for rival in rivals:
            if method in curves and rival in curves:
                a = curves[method]["points"][i]["per_seed"]["final_return"]
                b = curves[rival]["points"][i]["per_seed"]["final_return"]
                d = bootstrap_diff(a, b)
                out[f"L{lat}:{rival}"] = {**d, "outcome": outcome(d)}
    return out


def _latency(plan: PlansPlan, runs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    out = {}
    ada, h1, h10 = plan_method(LATENCY_THRESHOLD), fixed_method(1), fixed_method(10)
    for key in plan.latency_settings:
        # One set of seeds along a curve: those with finished latency runs (latency 0 is the front's
        # run, finished for more seeds); before any latency run, the planned latency seeds.
        done = {r.seed for r in plan.runs if r.env == key and r.latency and r.name in runs}
        seeds = done or set(plan.latency_seeds)
        curves = {}
        for method in plan.latency_methods:
            pts = []
            for lat in plan.latencies:
                g = [r for r in plan.finished(runs, key, method, lat) if r["seed"] in seeds]
                pts.append({"latency_steps": lat, **group_stats(g)})
            first, last = pts[0]["per_seed"]["final_return"], pts[-1]["per_seed"]["final_return"]
            d = bootstrap_diff(last, first)
            curves[method] = {
                "label": method_label(method),
                "points": pts,
                "loss_at_max_latency": {**d, "outcome": outcome(d)},
            }
        out[key] = {
            "label": SETTINGS[key].label,
            "seeds": plan.latency_seeds,
            "seeds_finished": sorted(done),  # with latency runs; every point of a curve uses these
            "curves": curves,
            "adaptiveh_minus_fixed": _minus_fixed(curves, plan.latencies, ada, (h1, h10)),
            "default_minus_fixed": _minus_fixed(curves, plan.latencies, DEFAULT_METHOD, (h1, h10)),
        }
    return out


def _h_drift(plan: PlansPlan, runs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    out = {}
    for slow, fast in DRIFT_PAIRS:
        if slow not in plan.settings or fast not in plan.settings:
            continue
        by_method = {}
        for method in (m for m in plan.points if plan.planned(slow, m) and plan.planned(fast, m)):
            hs = {k: _h_stats(plan.finished(runs, k, method)) for k in (slow, fast)}
            rates = {
                k: [run_numbers(r)["replans_per_100"] for r in plan.finished(runs, k, method)]
                for k in (slow, fast)
            }
            comps = {}
            if hs[slow].get("n") and hs[fast].get("n"):
                for stat in ("mean", "median"):
                    d = bootstrap_diff(hs[slow][f"per_seed_{stat}_H"], hs[fast][f"per_seed_{stat}_H"])
                    comps[f"{stat}_H"] = {**d, "outcome": outcome(d)}
            d = bootstrap_diff(rates[fast], rates[slow])
            comps["replans_per_100 (fast minus slow)"] = {**d, "outcome": outcome(d)}
            by_method[method] = {
                "label": method_label(method),
                "slow": {k: hs[slow].get(k) for k in ("n", "mean_H", "median_H", "evolution", "quantiles")},
                "fast": {k: hs[fast].get(k) for k in ("n", "mean_H", "median_H", "evolution", "quantiles")},
                "slow_minus_fast": comps,
            }
        out[f"{slow}-{fast}"] = {"slow": slow, "fast": fast, "methods": by_method}
    return out


def plans_verdicts(
    plan: PlansPlan, settings: dict[str, Any], latency: dict[str, Any], drift: dict[str, Any]
) -> dict[str, Any]:
    """Each claim per comparison: "better" only when the whole 95% interval favours AdaptiveH."""
    out: dict[str, Any] = {}
    comps = {f"{k}:{m}": p["vs_front"] for k, s in settings.items() for m, p in s["points"].items()}
    out["above_fixed_h_front"] = {
        "metric": "final return, AdaptiveH minus the fixed-H front at its re-plan rate",
        "comparisons": comps,
        "verdict": _overall(list(comps.values())),
    }
    for method in plan.points:
        c = {k: s["points"][method]["vs_front"] for k, s in settings.items() if method in s["points"]}
        out[f"above_front:{method}"] = {
            "metric": "as above, one AdaptiveH point",
            "comparisons": c,
            "verdict": _overall(list(c.values())),
        }
    for claim, key, who in (
        ("latency_adaptiveh_vs_fixed", "adaptiveh_minus_fixed", f"AdaptiveH (plan {LATENCY_THRESHOLD})"),
        ("latency_default_vs_fixed", "default_minus_fixed", "AdaptiveH (the default)"),
    ):
        comps = {f"{k}:{c}": d for k, v in latency.items() for c, d in v[key].items()}
        out[claim] = {
            "metric": f"final return, {who} minus fixed H at each latency",
            "comparisons": comps,
            "verdict": _overall(list(comps.values())),
        }
    comps = {
        f"{pair}:{m}:{s}": d
        for pair, v in drift.items()
        for m, x in v["methods"].items()
        for s, d in x["slow_minus_fast"].items()
        if s in ("mean_H", "median_H")
    }
    out["h_narrows_when_faster"] = {
        "metric": "per-seed mean and median H of AdaptiveH in plan mode, slow minus fast",
        "comparisons": comps,
        "verdict": _overall(list(comps.values())),
    }
    if plan.baseline_methods:
        comps = {
            f"{k}:{m}:{b}": d
            for k, s in settings.items()
            for m, p in s["points"].items()
            for b, d in p.get("vs_plan_baselines", {}).items()
        }
        out["above_plan_baselines"] = {
            "metric": "final return, AdaptiveH minus TD3/DDPG/SAC in plan mode (same model, re-plan every H)",
            "comparisons": comps,
            "verdict": _overall(list(comps.values())),
        }
    return out


def plans_aggregate(plan: PlansPlan, runs: dict[str, dict[str, Any]], paper_dir: Path | None) -> dict:
    settings = {k: _setting(plan, runs, k, paper_baselines(plan, k, paper_dir)) for k in plan.settings}
    latency = _latency(plan, runs)
    drift = _h_drift(plan, runs)
    stale = stale_runs(plan.runs, runs)
    return {
        "plan": {
            "quick": plan.quick,
            "settings": {k: {**SETTINGS[k].model_dump(), "steps_used": plan.steps[k]} for k in plan.settings},
            "front_H": plan.front_h,
            "points": plan.points,
            "latencies": plan.latencies,
            "latency_settings": plan.latency_settings,
            "latency_methods": plan.latency_methods,
            "seeds": plan.seeds,
            "latency_seeds": plan.latency_seeds,
            "runs_total": len(plan.runs),
            "runs_finished": sum(r.name in runs for r in plan.runs),
            "bootstrap_resamples": N_BOOT,
            "execution": "plan (every run); latency_steps 0 unless in the latency sweep",
            "baseline_methods": plan.baseline_methods,
            "baseline_settings": plan.baseline_settings,
            "baseline_seeds": plan.baseline_seeds,
            "baselines": _baselines_note(plan),
        },
        "settings": settings,
        "latency": latency,
        "h_drift": drift,
        "verdicts": plans_verdicts(plan, settings, latency, drift),
        "missing_runs": [r.name for r in plan.runs if r.name not in runs],
        "stale_runs": stale,
        "code_commits": _count([str((r.get("code") or {}).get("commit")) for r in runs.values()]),
        "dirty_runs": sum((r.get("code") or {}).get("dirty") is not False for r in runs.values()),
        "machines": machines(runs),
        "per_run": {name: run_numbers(r) for name, r in sorted(runs.items())},
    }


def _baselines_note(plan: PlansPlan) -> str:
    closed = "TD3/DDPG/SAC closed loop (H = 1) from the paper bench's runs where env, seed and steps match"
    if not plan.baseline_methods or not plan.baseline_settings:
        return f"{closed}; plan-mode baselines (H > 1) not in this plan"
    return (
        f"{closed}; in plan mode (re-planning every H steps over the nominal model): "
        f"{', '.join(method_label(m) for m in plan.baseline_methods)} on "
        f"{', '.join(plan.baseline_settings)}, seeds {plan.baseline_seeds} (the budget: ~300 s per 20k "
        "SB3 steps on one core)"
    )


def plans_report(plan: PlansPlan, out_dir: Path, paper_dir: Path | None = None) -> dict[str, Any]:
    """Build ``summary.json``, ``summary.md`` and the figures from the finished runs (partial is fine)."""
    runs = load_runs(plan, out_dir)  # type: ignore[arg-type]
    summary = plans_aggregate(plan, runs, paper_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    summary["figures"] = [p.name for p in make_plans_figures(plan, summary, out_dir)]
    summary["tables"] = write_plans_markdown(summary, out_dir).name
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False))
    return summary
