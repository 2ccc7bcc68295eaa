"""PNG figures mirroring the paper's: main results, H window, slow-vs-fast comparison, summary bars."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from experiments.metrics import RETURN_WINDOW
from experiments.plan import ALGO_LABELS, ENVS, MAIN_ENVS, SPEED_ENVS, Plan

DPI = 110
MAX_WIDTH_IN = 14.5  # 1595 px at DPI: a figure fits a laptop screen

ALGO_COLORS = {
    "adaptiveh": "tab:red",
    "td3": "tab:blue",
    "ddpg": "tab:green",
    "sac": "tab:orange",
    "ppo": "tab:brown",
    "rkhs": "tab:purple",
}


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
        fig, axes = plt.subplots(1, len(main), figsize=(min(5 * len(main), MAX_WIDTH_IN), 4), squeeze=False)
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
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def replot(out_dir: Path) -> list[Path]:
    """Redraw the figures from ``out_dir/summary.json`` as the bench wrote it: nothing run or aggregated."""
    summary = json.loads((out_dir / "summary.json").read_text())
    p = summary["plan"]
    steps = {k: e["steps_used"] for k, e in p["envs"].items()}
    plan = Plan([], list(p["envs"]), p["algos"], p["seeds"], steps, p["quick"])
    return make_figures(plan, summary, out_dir)
