"""The paper's experiments ("Results Analysis"): AdaptiveH vs TD3, DDPG and the fixed-H RKHS learner.

One plan of runs (environment x algorithm x seed, equal env steps per environment, the same seeded
non-stationary schedule for every algorithm at a given seed), executed one process per run over the
cores (so that wall-clock and peak RSS are the run's own), resumable: a finished run writes
``runs/<name>.json`` and is never recomputed. The report (``summary.json`` and the PNG figures) is built
from whatever runs are finished, naming the missing ones, so a partial experiment is still readable.

Metrics per run (all from the episodes the agent itself played while learning, as in the paper):

* ``return_mean``: mean return of all episodes of the run (the paper's "cumulative average return");
* ``final_return``: mean return of the episodes that ended in the last 10% of the steps;
* ``steps_to_threshold``: first step at which the mean of the last 5 episode returns reaches the
  environment's stated threshold (``reached`` false and the budget recorded when it never does);
* ``wall_s``: wall-clock of ``learn``; ``peak_rss_mb``: ``ru_maxrss`` of the run's own process.

Aggregates are the mean over seeds with a 95% percentile-bootstrap interval (2000 resamples).
"""

from __future__ import annotations

import json
import math
import multiprocessing as mp
import os
import resource
import sys
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ALGOS = ("adaptiveh", "td3", "ddpg", "rkhs")
ALGO_LABELS = {"adaptiveh": "AdaptiveH", "td3": "TD3", "ddpg": "DDPG", "rkhs": "RKHS fixed-H"}
ALGO_COLORS = {"adaptiveh": "tab:red", "td3": "tab:blue", "ddpg": "tab:green", "rkhs": "tab:purple"}
CURVE_POINTS = 50
RETURN_WINDOW = 5  # episodes in the trailing mean used by curves and steps-to-threshold
FINAL_FRACTION = 0.1
N_BOOT = 2000
CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"


@dataclass(frozen=True)
class EnvSpec:
    """One environment setting of the paper; ``threshold`` is the stated return for steps-to-threshold."""

    key: str
    env_id: str
    preset: str
    label: str
    steps: int
    quick_steps: int
    threshold: float
    config_file: str  # configs/<file>: its ``agent`` section tunes AdaptiveH and the RKHS baseline

    def __post_init__(self) -> None:
        if self.steps < 1 or self.quick_steps < 1:
            raise ValueError(f"{self.key}: step budgets must be >= 1")


# Budgets: CartPole and Pendulum 20k steps (the zoo's Pendulum budget), Reach 10k (PyBullet + IK per
# step). Thresholds: CartPole 195 (CartPole-v0's "solved" level), Pendulum -400 (upright most of the
# episode; random play scores about -1200), Reach -5 over its 50-step episodes (configs/reach.yaml): a
# mean distance of 10 cm; random play scores -8 to -28, a proportional controller -1 to -5.
ENVS: dict[str, EnvSpec] = {
    e.key: e
    for e in (
        EnvSpec(
            "cartpole_slow",
            "NSCartPoleContinuous-v0",
            "slow",
            "NS CartPole (slow)",
            20_000,
            4_000,
            195.0,
            "cartpole.yaml",
        ),
        EnvSpec(
            "pendulum_slow",
            "NSPendulum-v0",
            "slow",
            "NS Pendulum (slow)",
            20_000,
            4_000,
            -400.0,
            "pendulum.yaml",
        ),
        EnvSpec("reach_slow", "NSReach-v0", "slow", "NS Reach (slow)", 10_000, 2_000, -5.0, "reach.yaml"),
        EnvSpec(
            "cartpole_fast",
            "NSCartPoleContinuous-v0",
            "fast",
            "NS CartPole (fast)",
            20_000,
            4_000,
            195.0,
            "cartpole.yaml",
        ),
    )
}
DRIFT_KEYS = {
    "NSCartPoleContinuous-v0": "gravity",
    "NSPendulum-v0": "noise_bound",
    "NSReach-v0": "target_speed",
}
MAIN_ENVS = ("cartpole_slow", "pendulum_slow", "reach_slow")  # paper Fig. main results (d)-(f)
SPEED_ENVS = ("cartpole_slow", "cartpole_fast")  # paper Figs. H and fast comparison
FULL_SEEDS = 5
QUICK_SEEDS = 2


@dataclass(frozen=True)
class RunSpec:
    """One run of the plan; its name is its file name, so a changed budget is a different run."""

    env: str
    algo: str
    seed: int
    steps: int
    config: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)
    env_kwargs: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)

    @property
    def name(self) -> str:
        return f"{self.env}__{self.algo}__s{self.seed}__{self.steps}"


@dataclass
class Plan:
    runs: list[RunSpec]
    envs: list[str]
    algos: list[str]
    seeds: list[int]
    steps: dict[str, int]
    quick: bool


def _config_file(env: EnvSpec) -> dict[str, Any]:
    path = CONFIG_DIR / env.config_file
    if not path.is_file():
        return {}
    import yaml

    return dict(yaml.safe_load(path.read_text()) or {})


def agent_config(env: EnvSpec, algo: str) -> dict[str, Any]:
    """Hyperparameters per algorithm: RKHS learners from ``configs/<env>.yaml`` (the learner's tuned
    values, the fixed-H baseline uses the same ones), TD3/DDPG the zoo's (``learner.baselines``)."""
    if algo in ("td3", "ddpg"):
        return {}
    return dict(_config_file(env).get("agent") or {})


def env_kwargs(env: EnvSpec, seed: int) -> dict[str, Any]:
    """The env's constructor arguments: ``configs/<env>.yaml``'s ``env_kwargs`` (e.g. Reach's episode
    length), with this setting's preset and the run's seed; the same for every algorithm."""
    preset_key = "motion" if env.env_id == "NSReach-v0" else "preset"
    return {**(_config_file(env).get("env_kwargs") or {}), preset_key: env.preset, "seed": seed}


def build_plan(
    quick: bool = False,
    seeds: int | None = None,
    steps: int | None = None,
    envs: list[str] | None = None,
    algos: list[str] | None = None,
    overrides: dict[str, dict[str, Any]] | None = None,
) -> Plan:
    """The runs of the full (or ``quick``) experiment, ordered so that a partial run is already useful."""
    env_keys = list(envs or ENVS)
    algo_keys = list(algos or ALGOS)
    for key in env_keys:
        if key not in ENVS:
            raise ValueError(f"unknown env {key!r}; choose from {sorted(ENVS)}")
    for algo in algo_keys:
        if algo not in ALGOS:
            raise ValueError(f"unknown algo {algo!r}; choose from {ALGOS}")
    n_seeds = seeds if seeds is not None else (QUICK_SEEDS if quick else FULL_SEEDS)
    if n_seeds < 1:
        raise ValueError(f"seeds must be >= 1, got {n_seeds}")
    if steps is not None and steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    budget = {k: steps or (ENVS[k].quick_steps if quick else ENVS[k].steps) for k in env_keys}
    runs = []
    for seed in range(n_seeds):
        for key in env_keys:
            for algo in algo_keys:
                cfg = {**agent_config(ENVS[key], algo), **(overrides or {}).get(algo, {})}
                runs.append(RunSpec(key, algo, seed, budget[key], cfg, env_kwargs(ENVS[key], seed)))
    # Cheap runs first (the RKHS learners on CartPole/Pendulum: ~1 min each, 10-20x faster than TD3/DDPG),
    # then everything else seed-major (Reach costs PyBullet + IK per step for every algorithm): a partial
    # experiment then already holds every seed for the H claim and complete seeds of the rest. The order
    # never changes a result: every run is its own process with its own seed.
    runs.sort(key=lambda r: (not _cheap(r), r.seed))
    return Plan(runs, env_keys, algo_keys, list(range(n_seeds)), budget, quick)


def _cheap(run: RunSpec) -> bool:
    return run.algo in ("adaptiveh", "rkhs") and ENVS[run.env].env_id != "NSReach-v0"


# -- one run (in its own process) ---------------------------------------------------------------


def make_env(env: EnvSpec, kwargs: dict[str, Any]) -> Any:
    """The env built from ``kwargs``, with only its first ``reset`` seeded (see ``_SeedOnce``)."""
    import gymnasium as gym

    import sim  # noqa: F401  (registers the NS environments)

    return _seed_once(gym.make(env.env_id, **kwargs))


def _seed_once(env: Any) -> Any:
    """Pass a ``reset`` seed through only the first time.

    AdaptiveH reseeds every episode (``reset(seed=k)``), SB3 only the first; on NS Reach a seeded reset
    also redraws the target's motion, so without this the algorithms would face different schedules.
    Seeding once gives every algorithm at a given seed the same world.
    """
    import gymnasium as gym

    class _SeedOnce(gym.Wrapper):
        def __init__(self, inner: gym.Env) -> None:
            super().__init__(inner)
            self._seeded = False

        def reset(self, *, seed: int | None = None, options: dict | None = None) -> Any:
            if self._seeded:
                seed = None
            self._seeded = self._seeded or seed is not None
            return self.env.reset(seed=seed, options=options)

    return _SeedOnce(env)


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


def execute_run(spec: RunSpec, out_dir: str) -> dict[str, Any]:
    """Run one spec to completion and write ``runs/<name>.json``; errors come back, never raise."""
    try:
        return _execute(spec, Path(out_dir))
    except Exception:  # noqa: BLE001 - a failed run is reported and stays missing, the others go on
        return {"name": spec.name, "error": traceback.format_exc(limit=8)}


def code_version() -> dict[str, Any]:
    """The commit of the source tree this process imports, and whether its code/configs differ from it."""
    import subprocess

    root = Path(__file__).resolve().parent.parent
    paths = ["learner", "sim", "robot_io", "configs", "deploy/paper_bench.py"]
    try:
        git = ["git", "-C", str(root)]
        commit = subprocess.run(
            [*git, "rev-parse", "HEAD"], capture_output=True, text=True, timeout=20, check=True
        )
        dirty = subprocess.run(
            [*git, "status", "--porcelain", "--", *paths],
            capture_output=True,
            text=True,
            timeout=20,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None, "root": str(root)}
    return {"commit": commit.stdout.strip(), "dirty": bool(dirty.stdout.strip()), "root": str(root)}


def _execute(spec: RunSpec, out_dir: Path) -> dict[str, Any]:
    from learner.registry import make_agent

    env_spec = ENVS[spec.env]
    env = make_env(env_spec, spec.env_kwargs)
    agent = make_agent(spec.algo, env, spec.seed, dict(spec.config))
    t0 = time.perf_counter()
    log = agent.learn(spec.steps)
    wall = time.perf_counter() - t0
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    env.close()
    eps = log.episodes
    info_keys = sorted({k for e in eps for k in e.info})
    result = {
        "name": spec.name,
        "env": spec.env,
        "env_id": env_spec.env_id,
        "preset": env_spec.preset,
        "algo": spec.algo,
        "seed": spec.seed,
        "steps": spec.steps,
        "global_step": int(log.global_step),
        "config": spec.config,
        "env_kwargs": spec.env_kwargs,
        "threshold": env_spec.threshold,
        "wall_s": wall,
        "steps_per_s": log.global_step / wall if wall > 0 else None,
        "peak_rss_mb": peak_kb / 1024.0,
        "python": sys.version.split()[0],
        "code": code_version(),
        "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "metrics": run_metrics(
            [e.global_step for e in eps], [e.ret for e in eps], spec.steps, env_spec.threshold
        ),
        "episodes": {
            "global_step": [e.global_step for e in eps],
            "ret": [e.ret for e in eps],
            "length": [e.length for e in eps],
            "success": [e.success for e in eps],
            "info": {k: [e.info.get(k) for e in eps] for k in info_keys},
        },
        "segments": {
            "global_step": [s.global_step for s in log.segments],
            "H": [s.H for s in log.segments],
            "reason": [s.reason for s in log.segments],
        },
    }
    runs_dir = out_dir / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    tmp = runs_dir / f".{spec.name}.json.tmp"
    tmp.write_text(json.dumps(result))
    tmp.replace(runs_dir / f"{spec.name}.json")  # atomic: a run file exists only when complete
    return {k: result[k] for k in ("name", "wall_s", "peak_rss_mb", "global_step")}


def _limit_threads() -> None:
    """One BLAS/torch thread per run: runs are the unit of parallelism (set before workers import numpy)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def run_plan(plan: Plan, out_dir: Path, jobs: int, progress: bool = True) -> dict[str, list[str]]:
    """Execute the plan's unfinished runs, ``jobs`` at a time, each in a fresh process."""
    out_dir.mkdir(parents=True, exist_ok=True)
    pending = [r for r in plan.runs if not (out_dir / "runs" / f"{r.name}.json").is_file()]
    done = [r.name for r in plan.runs if r not in pending]
    errors: list[str] = []
    if not pending:
        return {"skipped": done, "ran": [], "failed": []}
    from tqdm import tqdm

    _limit_threads()
    ran: list[str] = []
    bar = tqdm(
        total=sum(r.steps for r in pending),
        unit="step",
        unit_scale=True,
        disable=not progress,
        desc=f"paper bench: {len(pending)} runs ({len(done)} done before)",
        dynamic_ncols=True,
    )
    ctx = mp.get_context("spawn")  # fresh interpreter per run: its RSS and RNG are its own
    with ctx.Pool(processes=max(1, jobs), maxtasksperchild=1) as pool:
        by_name = {r.name: r for r in pending}
        results = pool.imap_unordered(_execute_star, [(r, str(out_dir)) for r in pending])
        for res in results:
            spec = by_name[res["name"]]
            bar.update(spec.steps)
            if "error" in res:
                errors.append(res["name"])
                tqdm.write(f"FAILED {res['name']}:\n{res['error']}", file=sys.stderr)
            else:
                ran.append(res["name"])
                bar.set_postfix_str(f"{res['name']} {res['wall_s']:.0f}s {res['peak_rss_mb']:.0f}MB")
    bar.close()
    return {"skipped": done, "ran": ran, "failed": errors}


def _execute_star(args: tuple[RunSpec, str]) -> dict[str, Any]:
    return execute_run(*args)


# -- statistics ---------------------------------------------------------------------------------


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


def _sign(d: dict[str, Any], higher_is_better: bool = True) -> str:
    """better / worse / tie for side a, from the bootstrap interval of the difference."""
    if d["diff"] is None:
        return "missing"
    if min(d["n_a"], d["n_b"]) < 2:
        return "too few seeds"  # a one-seed "interval" has width zero and would decide anything
    lo, hi = (d["lo"], d["hi"]) if higher_is_better else (-d["hi"], -d["lo"])
    return "better" if lo > 0 else "worse" if hi < 0 else "tie"


# -- report -------------------------------------------------------------------------------------


def load_runs(plan: Plan, out_dir: Path) -> dict[str, dict[str, Any]]:
    runs = {}
    for spec in plan.runs:
        path = out_dir / "runs" / f"{spec.name}.json"
        if path.is_file():
            runs[spec.name] = json.loads(path.read_text())
    return runs


def _group(plan: Plan, runs: dict[str, dict[str, Any]], env: str, algo: str) -> list[dict[str, Any]]:
    return [runs[r.name] for r in plan.runs if r.env == env and r.algo == algo and r.name in runs]


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
    per_seed_mean = [float(np.mean(g["segments"]["H"])) for g in group if g["segments"]["H"]]
    per_seed_median = [float(np.median(g["segments"]["H"])) for g in group if g["segments"]["H"]]
    retreat_frac = [
        float(np.mean([r == "retreat" for r in g["segments"]["reason"]])) for g in group if g["segments"]["H"]
    ]
    pooled = np.concatenate([np.asarray(g["segments"]["H"], float) for g in group])
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
        "quantiles": {q: float(np.percentile(pooled, p)) for q, p in (("p10", 10), ("p50", 50), ("p90", 90))},
        "pooled_mean_H": float(pooled.mean()),
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


def summarize(plan: Plan, runs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """What the README quotes: per (env, algo) stats, curves, H statistics, verdicts, missing runs."""
    groups: dict[str, dict[str, Any]] = {}
    for env in plan.envs:
        groups[env] = {}
        for algo in plan.algos:
            g = _group(plan, runs, env, algo)
            m = [x["metrics"] for x in g]
            groups[env][algo] = {
                "n_runs": len(g),
                "seeds": sorted(x["seed"] for x in g),
                "return_mean": bootstrap_mean([x["return_mean"] for x in m]),
                "final_return": bootstrap_mean([x["final_return"] for x in m]),
                "steps_to_threshold": bootstrap_mean([x["steps_to_threshold"] for x in m]),
                "reached_fraction": float(np.mean([x["reached"] for x in m])) if m else None,
                "wall_s": bootstrap_mean([x["wall_s"] for x in g]),
                "peak_rss_mb": bootstrap_mean([x["peak_rss_mb"] for x in g]),
                "curve": _curve_stats(g),
            }
    h = {env: _h_stats(_group(plan, runs, env, "adaptiveh")) for env in SPEED_ENVS if env in plan.envs}
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
    # A run finished under other hyperparameters than the plan's current ones (configs/*.yaml edited
    # since): kept, as finished runs are never recomputed, but named so that nobody mistakes it.
    stale = [
        r.name
        for r in plan.runs
        if r.name in runs
        and (runs[r.name].get("config"), runs[r.name].get("env_kwargs")) != (r.config, r.env_kwargs)
    ]
    return {
        "plan": {
            "quick": plan.quick,
            "envs": {k: {**asdict(ENVS[k]), "steps_used": plan.steps[k]} for k in plan.envs},
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
        "missing_runs": missing,
        "stale_runs": stale,
        # Which code produced the runs: commits (with run counts) and runs made from a modified tree.
        "code_commits": _count([str((r.get("code") or {}).get("commit")) for r in runs.values()]),
        "dirty_runs": sorted(n for n, r in runs.items() if (r.get("code") or {}).get("dirty") is not False),
    }


def _count(items: list[str]) -> dict[str, int]:
    return {k: items.count(k) for k in sorted(set(items))}


def _vals(plan: Plan, runs: dict[str, dict[str, Any]], env: str, algo: str, key: str) -> list[float]:
    return [g["metrics"][key] for g in _group(plan, runs, env, algo)]


def _overall(comparisons: list[dict[str, Any]], higher_is_better: bool = True) -> str:
    """Confirmed: every comparison significantly favours AdaptiveH; partly: some do; not: none do.

    The note says how many point estimates lean the claimed way, so a non-significant trend is visible.
    """
    outcomes = [c["outcome"] for c in comparisons]
    known = [c for c in comparisons if c["outcome"] in ("better", "tie", "worse")]
    if not known:
        return "no data"
    wins = sum(c["outcome"] == "better" for c in known)
    verdict = "confirmed" if wins == len(known) else "partly confirmed" if wins else "not confirmed"
    leaning = sum((c["diff"] > 0) == higher_is_better and c["diff"] != 0 for c in known)
    notes = [
        f"{wins} of {len(known)} significant at 95%, {leaning} of {len(known)} point estimates lean that way"
    ]
    if len(known) < len(outcomes):
        notes.append(f"{len(outcomes) - len(known)} comparisons lack runs")
    return f"{verdict} ({'; '.join(notes)})"


def verdicts(plan: Plan, runs: dict[str, dict[str, Any]], h: dict[str, Any]) -> dict[str, Any]:
    """The paper's claims, each tested per environment with bootstrap intervals of differences.

    A comparison is "better" only when the whole 95% interval of the difference favours AdaptiveH; a
    claim is confirmed when every comparison is better, partly when some are, not when none are.
    """
    out: dict[str, Any] = {}
    if "adaptiveh" not in plan.algos:
        return out
    for claim, key, rivals, higher in (
        ("outperforms_td3_ddpg", "final_return", ("td3", "ddpg"), True),
        ("outperforms_td3_ddpg_over_run", "return_mean", ("td3", "ddpg"), True),
        ("faster_convergence", "steps_to_threshold", ("td3", "ddpg"), False),
        ("outperforms_rkhs_fixed_h", "final_return", ("rkhs",), True),
    ):
        comps = {}
        for env in plan.envs:
            for rival in rivals:
                if rival not in plan.algos:
                    continue
                d = bootstrap_diff(
                    _vals(plan, runs, env, "adaptiveh", key), _vals(plan, runs, env, rival, key)
                )
                comps[f"{env}:{rival}"] = {**d, "outcome": _sign(d, higher)}
        out[claim] = {
            "metric": f"{key}, AdaptiveH minus rival",
            "comparisons": comps,
            "verdict": _overall(list(comps.values()), higher),
        }
    slow, fast = h.get("cartpole_slow", {}), h.get("cartpole_fast", {})
    if slow.get("n") and fast.get("n"):
        comps = {}  # slow minus fast > 0: H narrows when the world changes faster
        for stat in ("mean", "median"):
            d = bootstrap_diff(slow[f"per_seed_{stat}_H"], fast[f"per_seed_{stat}_H"])
            comps[f"cartpole_slow-fast:{stat}_H"] = {**d, "outcome": _sign(d, True)}
        out["h_narrows_when_faster"] = {
            "metric": "per-seed mean and median H of AdaptiveH, slow minus fast (NS CartPole)",
            "comparisons": comps,
            "verdict": _overall(list(comps.values())),
        }
    else:
        out["h_narrows_when_faster"] = {"verdict": "no data", "comparisons": {}}
    return out


# -- figures ------------------------------------------------------------------------------------


def _kilo_steps(ax: Any) -> None:
    from matplotlib.ticker import FuncFormatter

    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x / 1000:g}k" if x else "0"))


def _plot_curves(ax: Any, plan: Plan, summary: dict[str, Any], env: str) -> None:
    g = summary["groups"][env]
    for algo in plan.algos:
        c = g[algo]["curve"]
        n = g[algo]["n_runs"]
        label = f"{ALGO_LABELS[algo]} (n={n}/{len(plan.seeds)})" if n else f"{ALGO_LABELS[algo]} (missing)"
        if not c["steps"]:
            ax.plot([], [], color=ALGO_COLORS[algo], label=label)
            continue
        ax.plot(c["steps"], c["mean"], color=ALGO_COLORS[algo], label=label)
        ax.fill_between(c["steps"], c["lo"], c["hi"], color=ALGO_COLORS[algo], alpha=0.2, linewidth=0)
    spec = ENVS[env]
    ax.axhline(spec.threshold, color="grey", linestyle=":", linewidth=1)
    ax.set_xlim(0, summary["plan"]["envs"][env]["steps_used"])
    if not any(g[algo]["n_runs"] for algo in plan.algos):
        ax.text(0.5, 0.5, "no finished runs yet", transform=ax.transAxes, ha="center", color="grey")
    drift = summary["drift"].get(env)
    if drift and drift["steps"]:
        twin = ax.twinx()
        twin.plot(drift["steps"], drift["values"], color="0.6", linewidth=0.8, linestyle="--")
        twin.set_ylabel(f"{drift['key']} (hidden, dashed)", color="0.5", fontsize=8)
        twin.tick_params(labelsize=7, colors="0.5")
    ax.set_title(spec.label)
    _kilo_steps(ax)
    ax.set_xlabel("environment steps")
    ax.set_ylabel(f"return (mean of last {RETURN_WINDOW} episodes)")
    ax.legend(fontsize=7)


def make_figures(plan: Plan, summary: dict[str, Any], out_dir: Path) -> list[Path]:
    """PNG figures mirroring the paper's: main results, H window, slow-vs-fast comparison, summary bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    paths = []
    main = [e for e in MAIN_ENVS if e in plan.envs]
    if main:
        fig, axes = plt.subplots(1, len(main), figsize=(5 * len(main), 4), squeeze=False)
        for ax, env in zip(axes[0], main, strict=True):
            _plot_curves(ax, plan, summary, env)
        fig.suptitle("Learning curves, mean and 95% bootstrap interval over seeds")
        paths.append(_save(fig, out_dir / "main_results.png"))
    speed = [e for e in SPEED_ENVS if e in plan.envs]
    if speed:
        fig, axes = plt.subplots(1, len(speed), figsize=(5 * len(speed), 4), squeeze=False, sharey=True)
        for ax, env in zip(axes[0], speed, strict=True):
            _plot_curves(ax, plan, summary, env)
        fig.suptitle("NS CartPole at two degrees of non-stationarity")
        paths.append(_save(fig, out_dir / "fast_comparison.png"))
    if "adaptiveh" in plan.algos and speed:
        fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(11, 4))
        colors = {"cartpole_slow": "tab:blue", "cartpole_fast": "tab:orange"}
        for env in speed:
            hs = summary["H"].get(env, {})
            label = ENVS[env].label
            if not hs.get("n"):
                ax_a.plot([], [], color=colors[env], label=f"{label} (missing)")
                continue
            evo = hs["evolution"]
            ax_a.plot(evo["steps"], evo["mean"], color=colors[env], label=f"{label} (n={hs['n']})")
            ax_a.fill_between(evo["steps"], evo["lo"], evo["hi"], color=colors[env], alpha=0.2, linewidth=0)
            hist = hs["histogram"]
            ax_b.bar(
                hist["H"],
                hist["fraction"],
                width=1.0,
                alpha=0.5,
                color=colors[env],
                label=f"{label}: mean {hs['pooled_mean_H']:.1f}, median {hs['quantiles']['p50']:.0f}",
            )
        _kilo_steps(ax_a)
        ax_a.set_title("(a) AdaptiveH window H over training")
        ax_a.set_xlabel("environment steps")
        ax_a.set_ylabel("mean H of the segments (20 bins)")
        ax_a.legend(fontsize=8)
        ax_b.set_title("(b) distribution of H, slow vs fast")
        ax_b.set_xlabel("H (segment length)")
        ax_b.set_ylabel("fraction of segments (all seeds)")
        ax_b.legend(fontsize=8)
        paths.append(_save(fig, out_dir / "h_window.png"))
    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    width = 0.8 / max(1, len(plan.algos))
    for k, (key, title) in enumerate(
        (
            ("final_return", "final return (last 10% of steps)"),
            ("steps_to_threshold", "steps to return threshold"),
        )
    ):
        ax = axes[k]
        for j, algo in enumerate(plan.algos):
            xs, ys, err = [], [], [[], []]
            for i, env in enumerate(plan.envs):
                s = summary["groups"][env][algo][key]
                if s["n"]:
                    xs.append(i + j * width)
                    ys.append(s["mean"])
                    err[0].append(s["mean"] - s["lo"])
                    err[1].append(s["hi"] - s["mean"])
            if xs:
                ax.bar(xs, ys, width, yerr=err, color=ALGO_COLORS[algo], capsize=2)
        ax.set_xticks([i + width * (len(plan.algos) - 1) / 2 for i in range(len(plan.envs))])
        ax.set_xticklabels([ENVS[e].label for e in plan.envs], fontsize=7)
        ax.set_title(title)
        handles = [Patch(color=ALGO_COLORS[a], label=ALGO_LABELS[a]) for a in plan.algos]
        ax.legend(handles=handles, fontsize=7)
    paths.append(_save(fig, out_dir / "summary_bars.png"))
    return paths


def _save(fig: Any, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def report(plan: Plan, out_dir: Path) -> dict[str, Any]:
    """Build ``summary.json`` and the figures from the finished runs (a partial set is fine)."""
    runs = load_runs(plan, out_dir)
    summary = summarize(plan, runs)
    summary["figures"] = [p.name for p in make_figures(plan, summary, out_dir)]
    summary["tables"] = write_markdown(summary, out_dir).name
    summary["per_run"] = {
        name: {
            "wall_s": r["wall_s"],
            "peak_rss_mb": r["peak_rss_mb"],
            **{k: r["metrics"][k] for k in ("return_mean", "final_return", "steps_to_threshold", "reached")},
        }
        for name, r in sorted(runs.items())
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False))
    return summary


def _fmt(stat: dict[str, Any], digits: int = 0) -> str:
    if not stat or stat.get("mean") is None:
        return "—"
    if stat["n"] == 1:
        return f"{stat['mean']:.{digits}f} (1 seed)"
    return f"{stat['mean']:.{digits}f} [{stat['lo']:.{digits}f}, {stat['hi']:.{digits}f}]"


def write_markdown(summary: dict[str, Any], out_dir: Path) -> Path:
    """``summary.md``: the tables and verdicts the README quotes, generated so no number is hand-copied."""
    plan = summary["plan"]
    lines = [
        "# Paper experiments: results",
        "",
        f"Runs finished: {plan['runs_finished']} of {plan['runs_total']} "
        f"({len(plan['seeds'])} seeds planned). Mean over seeds [95% bootstrap interval]; "
        "returns are those of the episodes played while learning.",
        "",
        "| env (steps, threshold) | algorithm | seeds | return over run | final return (last 10%) "
        "| steps to threshold | reached | wall-clock s | peak RSS MB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for env, by_algo in summary["groups"].items():
        e = plan["envs"][env]
        for algo, g in by_algo.items():
            frac = g["reached_fraction"]
            reached = "—" if frac is None else f"{round(frac * g['n_runs'])}/{g['n_runs']}"
            lines.append(
                f"| {e['label']} ({e['steps_used']}, {e['threshold']:g}) | {ALGO_LABELS[algo]} "
                f"| {g['n_runs']} | {_fmt(g['return_mean'], 1)} | {_fmt(g['final_return'], 1)} "
                f"| {_fmt(g['steps_to_threshold'])} | {reached} | {_fmt(g['wall_s'])} "
                f"| {_fmt(g['peak_rss_mb'])} |"
            )
    lines += [
        "",
        "## Window H of AdaptiveH (NS CartPole)",
        "",
        "| setting | seeds | segments | mean H per seed | median H per seed | p10 / p50 / p90 (pooled) "
        "| segments ended by retreat |",
        "|---|---|---|---|---|---|---|",
    ]
    for env, h in summary["H"].items():
        if h.get("n"):
            q = h["quantiles"]
            lines.append(
                f"| {plan['envs'][env]['label']} | {h['n']} | {h['segments']} | {_fmt(h['mean_H'], 2)} "
                f"| {_fmt(h['median_H'], 1)} | {q['p10']:.0f} / {q['p50']:.0f} / {q['p90']:.0f} "
                f"| {_fmt(h['retreat_fraction'], 2)} |"
            )
    lines += ["", "## Verdicts", "", format_verdicts(summary, markdown=True), ""]
    if summary["missing_runs"]:
        lines += [f"Missing runs ({len(summary['missing_runs'])}): " + ", ".join(summary["missing_runs"]), ""]
    lines += [f"Code: {summary['code_commits']} (commit: runs)."]
    if summary.get("dirty_runs"):
        lines += [f"Runs from a modified or unknown tree: {', '.join(summary['dirty_runs'])}", ""]
    if summary.get("stale_runs"):
        lines += [
            "Runs made under other hyperparameters than today's configs: " + ", ".join(summary["stale_runs"])
        ]
    path = out_dir / "summary.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def format_verdicts(summary: dict[str, Any], markdown: bool = False) -> str:
    """The verdicts with every comparison's difference and interval (plain text or a Markdown list)."""
    plan = summary["plan"]
    lines = [] if markdown else [f"runs finished: {plan['runs_finished']}/{plan['runs_total']}"]
    bullet, sub = ("- ", "  - ") if markdown else ("", "  ")
    for claim, v in summary["verdicts"].items():
        metric = f" ({v['metric']})" if v.get("metric") else ""
        verdict = f"**{v['verdict']}**" if markdown else v["verdict"]
        lines.append(f"{bullet}{claim}{metric}: {verdict}")
        for comp, d in v.get("comparisons", {}).items():
            if d.get("diff") is None:
                lines.append(f"{sub}{comp}: missing")
                continue
            lines.append(
                f"{sub}{comp}: {d['diff']:+.1f} [{d['lo']:+.1f}, {d['hi']:+.1f}], "
                f"seeds {d['n_a']} vs {d['n_b']} -> {d['outcome']}"
            )
    return "\n".join(lines)


def main_paper(
    quick: bool,
    out: Path,
    jobs: int,
    seeds: int | None = None,
    steps: int | None = None,
    envs: list[str] | None = None,
    algos: list[str] | None = None,
    report_only: bool = False,
    overrides: dict[str, dict[str, Any]] | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Run (unless ``report_only``) and report; returns the summary."""
    plan = build_plan(quick, seeds, steps, envs, algos, overrides)
    outcome = {"skipped": [], "ran": [], "failed": []}
    if not report_only:
        outcome = run_plan(plan, out, jobs, progress)
    summary = report(plan, out)
    summary["last_invocation"] = {k: len(v) for k, v in outcome.items()}
    summary["failed_runs"] = outcome["failed"]
    (out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False))
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
