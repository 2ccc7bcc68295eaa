"""The plans experiment (issue #11): does the retreat pick the right moment when segments are committed plans?

Every run executes in plan mode (``execution: plan``, ``learner.plans``): a segment is a plan of up to
``H`` actions over the env's nominal model, played without waiting for the learner. Per setting:

* the **front**: RKHS fixed-H (re-plans every H steps) at H in ``FRONT_H``; H = 1 is the closed loop;
* the **points**: AdaptiveH with the ``plan`` retreat at each threshold in ``THRESHOLDS``, with the
  ``plan`` retreat's kernel narrowed by each of ``KERNEL_SCALES`` (default threshold), and with the
  ``local`` retreat (its default threshold);
* the **latency** sweep: fixed H = 1, fixed H = 10 and AdaptiveH (``plan``, 0.8) with a new plan taking
  effect ``latency_steps`` in ``LATENCIES`` steps late, on ``LATENCY_SETTINGS``;
* the **baselines** in the same mode (``td3-h<H>``, ``ddpg-h<H>``, ``sac-h<H>``;
  ``learner.baselines_plan``): the deterministic actor plus its exploration noise (SAC: its stochastic
  policy) over the same nominal model, re-planning every H steps, so every method meets the same
  constraint. SB3 runs cost ~300 s per 20k steps on one core (10-20x an RKHS run), so the budget is
  small: ``BASELINE_METHODS`` (TD3, SAC) at ``BASELINE_H`` (H = 10, the middle of the front) on
  ``BASELINE_SETTINGS`` (NS CartPole fast, NS Reach slow) with ``BASELINE_SEEDS`` (3) seeds, 12 runs,
  about 1-2 CPU-hours. H = 1 is their closed loop: the report takes those points (TD3, DDPG, SAC) from
  the paper bench's runs of the same env, seed and budget (``--paper-dir``) rather than re-running them.

The runs go through the paper bench's runner (one process per run, resumable ``runs/<name>.json``);
``experiments.plans_report`` builds ``summary.json``, ``summary.md`` and the figures from whatever is
finished; ``experiments.plans_bench`` does both. This module is what the worker processes import: it
holds the plan only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from experiments.plan import ENVS, EnvSpec, RunSpec, agent_config, env_kwargs
from learner.plan_tolerance import narrowest_scale

# NS Reach with the fast target (motion preset ``fast``), at the paper bench's Reach budget.
REACH_FAST = ENVS["reach_slow"].model_copy(
    update={"key": "reach_fast", "preset": "fast", "label": "NS Reach (fast)"}
)
# A target harder than ``fast`` (preset ``erratic``), held out: only the front and the default run there,
# and no setting of the retreat was chosen on it.
REACH_ERRATIC = ENVS["reach_slow"].model_copy(
    update={"key": "reach_erratic", "preset": "erratic", "label": "NS Reach (erratic, held out)"}
)
SETTINGS: dict[str, EnvSpec] = {
    **{k: ENVS.get(k, REACH_FAST) for k in ("cartpole_slow", "cartpole_fast", "pendulum_slow", "reach_slow")},
    "reach_fast": REACH_FAST,
    "reach_erratic": REACH_ERRATIC,
}
HELD_OUT = ("reach_erratic",)
FRONT_H = (1, 2, 5, 10, 20, 50)
THRESHOLDS = (0.5, 0.8, 0.9)
# The plan retreat with a narrower kernel between predicted and reached state (``plan_kernel_scale``, on
# the dimensions where the policy's kernel is narrowest: ``where_narrowest``), at the default threshold: a
# plan may drift by about this fraction of the policy's kernel width (NS Reach: 0.083 x 30 cm = 2.5 cm).
KERNEL_SCALES = (0.083, 0.15)
LATENCIES = (0, 2, 5, 10)
LATENCY_SETTINGS = ("cartpole_fast", "reach_slow")
LATENCY_THRESHOLD = 0.8
LATENCY_H = (1, 10)
DRIFT_PAIRS = (
    ("cartpole_slow", "cartpole_fast"),
    ("reach_slow", "reach_fast"),
    ("reach_fast", "reach_erratic"),
)
# ``adaptiveh bench plans --default-only``: the front, the default and the corrected option, nothing else
# (no other points, latency sweep or plan-mode baselines): e.g. more seeds behind the default's verdicts.
DEFAULT_ONLY = {
    "thresholds": (),
    "kernel_scales": (),
    "learned": False,
    "local": False,
    "baseline_methods": (),
    "latency_seeds": 0,
}
FULL_SEEDS = 5
QUICK_SEEDS = 2
QUICK_STEPS = {"NSCartPoleContinuous-v0": 1000, "NSPendulum-v0": 1000, "NSReach-v0": 500}
PLAN_BASELINES = ("td3", "ddpg", "sac")  # the off-policy SB3 baselines that can run in plan mode
BASELINE_METHODS = ("td3", "sac")
BASELINE_H = (10,)
BASELINE_SETTINGS = ("cartpole_fast", "reach_slow")
BASELINE_SEEDS = 3


def fixed_method(h: int) -> str:
    return f"rkhs-h{h}"


def plan_method(threshold: float) -> str:
    return f"adaptiveh-plan{threshold:g}"


def scale_method(scale: float) -> str:
    return f"adaptiveh-k{scale:g}"


def baseline_method(algo: str, h: int) -> str:
    return f"{algo}-h{h}"


LOCAL_METHOD = "adaptiveh-local"
# The points measured before the default tolerance (issue #33) keep what they ran with: the plan retreat
# at the policy's own kernel (``plan<t>``), a fixed kernel narrowed by a factor (``k<scale>``).
FIXED = {"plan_tolerance": "fixed"}
PLAN_KERNEL = {**FIXED, "plan_kernel_scale": 1.0}
# The library's defaults in plan mode (the plan retreat, its threshold and tolerance as AdaptiveHConfig has
# them): one configuration for every setting and the stack (issue #33).
DEFAULT_METHOD = "adaptiveh-default"
# The default with the plan model corrected online by its own one-step residuals (``plan_model:
# corrected``, ``learner/plan_model.py``): the systematic part of the prediction gap no longer counts.
CORRECTED_METHOD = "adaptiveh-corrected"
# The plan retreat whose tolerance is learned from the plan's own prediction gaps (``plan_tolerance:
# learned``, ``learner/plan_tolerance.py``), at the default threshold: no per-task constant.
LEARNED_METHOD = "adaptiveh-learned"


def _horizon(method: str, prefix: str) -> int:
    """The H of ``<prefix><H>``: a positive integer written plainly (``10``, not ``010`` or ``+10``)."""
    text = method.removeprefix(prefix)
    if not text.isdigit() or text != str(int(text)) or int(text) < 1:
        raise ValueError(f"unknown method {method!r}: H must be a positive integer ({prefix}10)")
    return int(text)


def where_narrowest(bandwidth: float | list[float] | None, scale: float) -> float | list[float]:
    """``scale`` as the learner applies it (``learner.plan_tolerance.narrowest_scale``), written out per
    dimension in the run's config when the policy's kernel has several widths."""
    if bandwidth is None or not isinstance(bandwidth, list) or len(set(bandwidth)) == 1:
        return scale
    return narrowest_scale(np.asarray(bandwidth, float), scale).tolist()


def baseline_of(method: str) -> tuple[str, int] | None:
    """(algo, H) of a plan-mode baseline method ``td3-h<H>``, ``ddpg-h<H>``, ``sac-h<H>``; None otherwise."""
    algo, sep, _ = method.partition("-h")
    if not sep or algo not in PLAN_BASELINES:
        return None
    return algo, _horizon(method, f"{algo}-h")


def method_config(method: str) -> tuple[str, dict[str, Any]]:
    """(algo, agent overrides) of a method name: ``rkhs-h<H>``, ``adaptiveh-plan<t>``, ``adaptiveh-k<scale>``,
    ``adaptiveh-local``, or a baseline ``td3-h<H>`` / ``ddpg-h<H>`` / ``sac-h<H>`` (``plan_h`` H; H = 1 is
    its closed loop)."""
    if method.startswith("rkhs-h"):
        return "rkhs", {"execution": "plan", "fixed_h": _horizon(method, "rkhs-h")}
    if method.startswith("adaptiveh-plan"):
        t = float(method.removeprefix("adaptiveh-plan"))
        return "adaptiveh", {"execution": "plan", "retreat": "plan", "retreat_threshold": t, **PLAN_KERNEL}
    if method.startswith("adaptiveh-k"):
        scale = float(method.removeprefix("adaptiveh-k"))
        return "adaptiveh", {"execution": "plan", "retreat": "plan", "plan_kernel_scale": scale, **FIXED}
    if method == LOCAL_METHOD:
        return "adaptiveh", {"execution": "plan", "retreat": "local", "retreat_threshold": None}
    if method == DEFAULT_METHOD:  # the configs' closed-loop ``retreat: local`` unset: plan mode's own
        return "adaptiveh", {"execution": "plan", "retreat": None}
    if method == LEARNED_METHOD:
        return "adaptiveh", {"execution": "plan", "retreat": "plan", "plan_tolerance": "learned"}
    if method == CORRECTED_METHOD:
        return "adaptiveh", {"execution": "plan", "retreat": None, "plan_model": "corrected"}
    base = baseline_of(method)
    if base is not None:
        return base[0], {"plan_h": base[1]}
    raise ValueError(f"unknown method {method!r}")


def method_label(method: str) -> str:
    if method.startswith("rkhs-h"):
        h = _horizon(method, "rkhs-h")
        return "fixed H = 1 (closed loop)" if h == 1 else f"fixed H = {h}"
    if method.startswith("adaptiveh-plan"):
        return f"AdaptiveH, plan retreat {method.removeprefix('adaptiveh-plan')}"
    if method.startswith("adaptiveh-k"):
        return f"AdaptiveH, plan retreat, kernel x{method.removeprefix('adaptiveh-k')}"
    if method == LOCAL_METHOD:
        return "AdaptiveH, local retreat"
    if method == LEARNED_METHOD:
        return "AdaptiveH, plan retreat, learned tolerance"
    if method == DEFAULT_METHOD:
        return "AdaptiveH, default (noise-floor tolerance)"
    if method == CORRECTED_METHOD:
        return "AdaptiveH, default + plan model corrected online"
    base = baseline_of(method)
    if base is not None:
        algo, h = base
        return f"{algo.upper()}, H = 1 (closed loop)" if h == 1 else f"{algo.upper()}, H = {h}"
    raise ValueError(f"unknown method {method!r}")


@dataclass(frozen=True)
class PlanRunSpec(RunSpec):
    """A run of the plans experiment: a method (``rkhs-h10``, ``adaptiveh-plan0.8``, ...) and a latency."""

    method: str = ""
    latency: int = 0

    @property
    def name(self) -> str:
        lat = f"-lat{self.latency}" if self.latency else ""
        return f"{self.env}__{self.method}{lat}__s{self.seed}__{self.steps}"

    @property
    def env_spec(self) -> EnvSpec:
        return SETTINGS[self.env]


@dataclass
class PlansPlan:
    runs: list[PlanRunSpec]
    settings: list[str]
    front_h: list[int]
    points: list[str]  # AdaptiveH methods
    latencies: list[int]
    latency_settings: list[str]
    latency_methods: list[str]
    seeds: list[int]
    latency_seeds: list[int]
    steps: dict[str, int]
    quick: bool
    baseline_methods: list[str] = field(default_factory=list)  # td3-h10, sac-h10, ...
    baseline_settings: list[str] = field(default_factory=list)
    baseline_seeds: list[int] = field(default_factory=list)

    @property
    def front(self) -> list[str]:
        return [fixed_method(h) for h in self.front_h]

    def finished(
        self, runs: dict[str, dict[str, Any]], setting: str, method: str, latency: int = 0
    ) -> list[dict[str, Any]]:
        """The finished run files of one (setting, method, latency) group, in seed order."""
        return [
            runs[r.name]
            for r in self.runs
            if (r.env, r.method, r.latency) == (setting, method, latency) and r.name in runs
        ]

    def planned(self, setting: str, method: str, latency: int = 0) -> list[PlanRunSpec]:
        return [r for r in self.runs if (r.env, r.method, r.latency) == (setting, method, latency)]


def build_plans_plan(
    quick: bool = False,
    seeds: int | None = None,
    latency_seeds: int | None = None,
    steps: int | None = None,
    settings: list[str] | None = None,
    front_h: tuple[int, ...] = FRONT_H,
    thresholds: tuple[float, ...] = THRESHOLDS,
    kernel_scales: tuple[float, ...] = KERNEL_SCALES,
    learned: bool = True,
    local: bool = True,
    latencies: tuple[int, ...] = LATENCIES,
    baseline_methods: tuple[str, ...] = BASELINE_METHODS,
    baseline_h: tuple[int, ...] = BASELINE_H,
    baseline_settings: tuple[str, ...] = BASELINE_SETTINGS,
    baseline_seeds: int = BASELINE_SEEDS,
) -> PlansPlan:
    """The runs, ordered so that a partial experiment is already useful: seed by seed (cheap settings
    first within a seed), each seed's latency runs, then its plan-mode baselines, after the next seed's
    front and points. The baselines run on ``baseline_settings`` among ``settings``, for the first
    ``baseline_seeds`` seeds (at most the experiment's)."""
    keys = list(settings or SETTINGS)
    for key in keys:
        if key not in SETTINGS:
            raise ValueError(f"unknown setting {key!r}; choose from {sorted(SETTINGS)}")
    n_seeds = seeds if seeds is not None else (QUICK_SEEDS if quick else FULL_SEEDS)
    n_lat = min(n_seeds, latency_seeds) if latency_seeds is not None else n_seeds
    if n_seeds < 1 or n_lat < 0:
        raise ValueError(f"seeds must be >= 1 (got {n_seeds}) and latency seeds >= 0 (got {n_lat})")
    if baseline_seeds < 0:
        raise ValueError(f"baseline seeds must be >= 0, got {baseline_seeds}")
    for algo in baseline_methods:
        if algo not in PLAN_BASELINES:
            raise ValueError(f"unknown plan-mode baseline {algo!r}; choose from {PLAN_BASELINES}")
    base_methods = [baseline_method(a, h) for a in baseline_methods for h in baseline_h]
    for method in base_methods:
        baseline_of(method)  # H >= 1
    if steps is not None and steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    budget = {k: steps or (QUICK_STEPS[SETTINGS[k].env_id] if quick else SETTINGS[k].steps) for k in keys}
    points = [plan_method(t) for t in thresholds] + [scale_method(k) for k in kernel_scales]
    points += ([LOCAL_METHOD] if local else []) + ([LEARNED_METHOD] if learned else [])
    points += [DEFAULT_METHOD, CORRECTED_METHOD]
    front = [fixed_method(h) for h in front_h]
    lat_settings = [k for k in LATENCY_SETTINGS if k in keys]
    lat_methods = [fixed_method(h) for h in LATENCY_H] + [plan_method(LATENCY_THRESHOLD), DEFAULT_METHOD]

    def spec(key: str, method: str, seed: int, latency: int = 0) -> PlanRunSpec:
        algo, overrides = method_config(method)
        cfg = {**agent_config(SETTINGS[key], algo), **overrides}
        if "plan_kernel_scale" in overrides:
            cfg["plan_kernel_scale"] = where_narrowest(cfg.get("bandwidth"), overrides["plan_kernel_scale"])
        if algo in ("adaptiveh", "rkhs"):  # the SB3 baselines have no learner latency
            cfg["latency_steps"] = latency
        cfg = {k: v for k, v in cfg.items() if v is not None}
        kwargs = env_kwargs(SETTINGS[key], seed)
        return PlanRunSpec(key, algo, seed, budget[key], cfg, kwargs, method, latency)

    cheap_first = sorted(keys, key=lambda k: SETTINGS[k].env_id == "NSReach-v0")
    main_runs = [
        spec(k, m, s)
        for s in range(n_seeds)
        for k in cheap_first
        for m in front + ([DEFAULT_METHOD, CORRECTED_METHOD] if k in HELD_OUT else points)
    ]
    have = {r.name for r in main_runs}
    lat_runs = []
    for s in range(n_lat):
        for k, m, lat in ((k, m, lat) for k in lat_settings for m in lat_methods for lat in latencies):
            r = spec(k, m, s, lat)
            if r.name not in have:  # latency 0 of the front / points is the same run
                lat_runs.append(r)
                have.add(r.name)
    base_settings = [k for k in cheap_first if k in baseline_settings]
    n_base = min(n_seeds, baseline_seeds)
    base_runs = [spec(k, m, s) for s in range(n_base) for k in base_settings for m in base_methods]
    base_runs = [r for r in base_runs if r.name not in have]
    # Each seed's latency runs, then its baselines, follow the next seed's front and points:
    # s0, s1, L-s0, B-s0, s2, L-s1, B-s1, s3, ... (a stable sort keeps latency before baselines)
    runs = sorted(
        main_runs + lat_runs + base_runs,
        key=lambda r: 2 * r.seed + (3 if r.latency or baseline_of(r.method) else 0),
    )
    return PlansPlan(
        runs=runs,
        settings=keys,
        front_h=list(front_h),
        points=points,
        latencies=list(latencies),
        latency_settings=lat_settings,
        latency_methods=lat_methods,
        seeds=list(range(n_seeds)),
        latency_seeds=list(range(n_lat)),
        steps=budget,
        quick=quick,
        baseline_methods=base_methods,
        baseline_settings=base_settings,
        baseline_seeds=list(range(n_base)),
    )
