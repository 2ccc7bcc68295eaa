"""Figures of the plans experiment: the fixed-H front with the AdaptiveH points and the baselines (in plan
mode, and their closed loop from the paper bench), latency, H slow vs fast."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from experiments.figures import DPI, MAX_WIDTH_IN, _kilo_steps, _save
from experiments.plans import DEFAULT_METHOD, PlansPlan

POINT_COLORS = ["tab:red", "tab:orange", "tab:brown", "black", "tab:gray", "tab:green", "tab:pink", "navy"]
DEFAULT_COLOR = "gold"  # the default stands out in every panel


def point_colors(methods: list[str]) -> list[str]:
    """One colour per method: the default gold, the others in order."""
    others = iter(POINT_COLORS * 2)
    return [DEFAULT_COLOR if m == DEFAULT_METHOD else next(others) for m in methods]


BASE_STYLE = {"td3": ("tab:blue", "s"), "ddpg": ("tab:cyan", "D"), "sac": ("tab:olive", "P")}


def _err(stat: dict[str, Any]) -> list[list[float]]:
    return [[stat["mean"] - stat["lo"]], [stat["hi"] - stat["mean"]]]


def _front_panel(ax: Any, s: dict[str, Any]) -> None:
    front = sorted((f for f in s["front"] if f["n"]), key=lambda f: f["replans_per_100"]["mean"])
    if front:
        xs = [f["replans_per_100"]["mean"] for f in front]
        ys = [f["final_return"]["mean"] for f in front]
        ax.plot(xs, ys, color="tab:purple", marker="o", label="fixed-H front (RKHS)")
        ax.fill_between(
            xs,
            [f["final_return"]["lo"] for f in front],
            [f["final_return"]["hi"] for f in front],
            color="tab:purple",
            alpha=0.2,
            linewidth=0,
        )
        for f, x, y in zip(front, xs, ys, strict=True):
            ax.annotate(
                f"H={f['H']}",
                (x, y),
                textcoords="offset points",
                xytext=(3, 4),
                fontsize=7,
                color="tab:purple",
            )
    for color, p in zip(point_colors(list(s["points"])), s["points"].values(), strict=True):
        if not p["n"]:
            continue
        ax.errorbar(
            p["replans_per_100"]["mean"],
            p["final_return"]["mean"],
            yerr=_err(p["final_return"]),
            xerr=_err(p["replans_per_100"]),
            fmt="*",
            markersize=11,
            color=color,
            mec="black" if color == DEFAULT_COLOR else color,
            capsize=2,
            label=p["label"],
        )
    closed_at = {}  # the closed-loop points, side by side right of H = 1 so they do not hide it
    for k, (algo, b) in enumerate(s["baselines"].items()):
        color, marker = BASE_STYLE.get(algo, ("grey", "^"))
        closed_at[algo] = (100.0 * (1.12 + 0.12 * k), b["final_return"]["mean"])
        ax.errorbar(
            *closed_at[algo],
            yerr=_err(b["final_return"]),
            fmt=marker,
            mfc="none",
            color=color,
            capsize=2,
            label=f"{algo.upper()} closed loop (paper bench, n={b['n']})",
        )
    missing = []
    for b in s.get("plan_baselines", {}).values():
        color, marker = BASE_STYLE.get(b["algo"], ("grey", "^"))
        if not b["n"]:
            missing.append(b["label"])
            continue
        x, y = b["replans_per_100"]["mean"], b["final_return"]["mean"]
        ax.errorbar(
            x,
            y,
            yerr=_err(b["final_return"]),
            xerr=_err(b["replans_per_100"]),
            fmt=marker,
            markersize=7,
            color=color,
            capsize=2,
            label=f"{b['label']}, plan mode (n={b['n']})",
        )
        if b["algo"] in closed_at:  # the same algorithm from its closed loop to plan mode
            cx, cy = closed_at[b["algo"]]
            ax.plot([cx, x], [cy, y], linestyle=":", color=color, linewidth=1)
    if missing:
        ax.text(
            0.02,
            0.02,
            "plan-mode baselines missing: " + ", ".join(missing),
            transform=ax.transAxes,
            fontsize=6,
            color="grey",
        )
    if not front and not any(p["n"] for p in s["points"].values()):
        ax.text(0.5, 0.5, "no finished runs yet", transform=ax.transAxes, ha="center", color="grey")
    ax.set_xscale("log")
    ax.set_title(f"{s['label']} ({s['steps']:,} steps)")
    ax.set_xlabel("re-plans per 100 steps (log)")
    ax.set_ylabel("final return (last 10 % of steps)")


def _shared_legend(fig: Any, axes: Any, rows: int) -> None:
    """One legend for every panel, below them: in the panels it hid the points (each label once)."""
    handles: dict[str, Any] = {}
    for ax in axes.flat:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, handle)
    fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=3, fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, 0.17 / rows, 1, 1))


def _save_laid_out(fig: Any, path: Path) -> Path:
    """Save a figure whose layout is set (``_save`` would lay it out again over the shared legend)."""
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def make_plans_figures(plan: PlansPlan | None, summary: dict[str, Any], out_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    settings = list(summary["settings"])
    cols = min(3, len(settings))
    rows = -(-len(settings) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(min(5.5 * cols, MAX_WIDTH_IN), 4.8 * rows), squeeze=False)
    for ax, key in zip(axes.flat, settings, strict=False):
        _front_panel(ax, summary["settings"][key])
    for ax in list(axes.flat)[len(settings) :]:
        ax.axis("off")
    fig.suptitle(
        "Plan execution: return vs re-plans per 100 steps; fixed-H front (mean, 95% band), AdaptiveH and "
        "the baselines in plan mode\n(each point's verdict against the front: summary.md beside this figure)"
    )
    _shared_legend(fig, axes, rows)
    paths.append(_save_laid_out(fig, out_dir / "front.png"))

    lat = summary["latency"]
    fig, axes = plt.subplots(
        1, max(1, len(lat)), figsize=(min(5.5 * max(1, len(lat)), MAX_WIDTH_IN), 4), squeeze=False
    )
    for ax, v in zip(axes[0], lat.values(), strict=False):
        colors = ["tab:purple", "tab:blue", "tab:red", "tab:orange"]
        colors = [DEFAULT_COLOR if m == DEFAULT_METHOD else colors[i] for i, m in enumerate(v["curves"])]
        for color, c in zip(colors, v["curves"].values(), strict=True):
            pts = [p for p in c["points"] if p["n"]]
            if not pts:
                ax.plot([], [], color=color, label=f"{c['label']} (missing)")
                continue
            xs = [p["latency_steps"] for p in pts]
            ax.plot(xs, [p["final_return"]["mean"] for p in pts], marker="o", color=color, label=c["label"])
            ax.fill_between(
                xs,
                [p["final_return"]["lo"] for p in pts],
                [p["final_return"]["hi"] for p in pts],
                color=color,
                alpha=0.2,
                linewidth=0,
            )
        ax.set_title(f"{v['label']}, seeds finished {v['seeds_finished']}")
        ax.set_xlabel("learner latency (steps until a new plan takes effect)")
        ax.set_ylabel("final return (last 10 % of steps)")
        ax.legend(fontsize=7)
    if not lat:
        axes[0][0].axis("off")
    fig.suptitle("Return against learner latency (plan execution, mean and 95% band)")
    paths.append(_save(fig, out_dir / "latency.png"))

    drift = summary["h_drift"]
    fig, axes = plt.subplots(max(1, len(drift)), 2, figsize=(12, 4 * max(1, len(drift))), squeeze=False)
    for row, (pair, v) in zip(axes, drift.items(), strict=False):
        ax_t, ax_b = row
        labels, slow_m, fast_m, slow_e, fast_e = [], [], [], [[], []], [[], []]
        for color, m in zip(point_colors(list(v["methods"])), v["methods"].values(), strict=True):
            for side, style in (("slow", "-"), ("fast", "--")):
                evo = m[side].get("evolution")
                if evo and evo["steps"]:
                    ax_t.plot(
                        evo["steps"], evo["mean"], linestyle=style, color=color, label=f"{m['label']}, {side}"
                    )
            labels.append(m["label"].replace("AdaptiveH, ", ""))
            for side, means, err in (("slow", slow_m, slow_e), ("fast", fast_m, fast_e)):
                st = m[side].get("mean_H") or {}
                means.append(st.get("mean") or 0.0)
                err[0].append((st["mean"] - st["lo"]) if st.get("mean") is not None else 0.0)
                err[1].append((st["hi"] - st["mean"]) if st.get("mean") is not None else 0.0)
        _kilo_steps(ax_t)
        ax_t.set_title(f"H over training: {pair} (solid slow, dashed fast)")
        ax_t.set_xlabel("environment steps")
        ax_t.set_ylabel("mean H of the segments (20 bins, over seeds)")
        ax_t.legend(fontsize=6)
        xs = list(range(len(labels)))
        ax_b.bar([x - 0.2 for x in xs], slow_m, 0.4, yerr=slow_e, capsize=2, color="tab:blue", label="slow")
        ax_b.bar([x + 0.2 for x in xs], fast_m, 0.4, yerr=fast_e, capsize=2, color="tab:orange", label="fast")
        ax_b.set_xticks(xs)
        ax_b.set_xticklabels(labels, fontsize=7)
        ax_b.set_title(f"per-seed mean H (95% interval): {pair}")
        ax_b.set_ylabel("mean H")
        ax_b.legend(fontsize=7)
    if not drift:
        for ax in axes[0]:
            ax.axis("off")
    fig.suptitle("AdaptiveH window H under slow vs fast drift (plan execution)")
    paths.append(_save(fig, out_dir / "h_drift.png"))
    return paths


def replot(out_dir: Path) -> list[Path]:
    """Redraw the figures from ``out_dir/summary.json`` as the bench wrote it: nothing run or aggregated
    (the figures read the summary alone)."""
    return make_plans_figures(None, json.loads((out_dir / "summary.json").read_text()), out_dir)
