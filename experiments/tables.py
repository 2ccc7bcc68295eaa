"""``summary.md`` and the printed verdicts: the README quotes them, generated so no number is hand-copied."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

from experiments.machines import mixed_machines
from experiments.plan import ALGO_LABELS


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
    lines += ["", "## Cost per method", "", format_cost(summary, markdown=True)]
    lines += ["", "## Verdicts", "", format_verdicts(summary, markdown=True), ""]
    if summary["missing_runs"]:
        lines += [f"Missing runs ({len(summary['missing_runs'])}): " + ", ".join(summary["missing_runs"]), ""]
    lines += [f"Code: {summary['code_commits']} (commit: runs)."] + format_machines(summary)
    if summary.get("dirty_runs"):
        lines += [f"Runs from a modified or unknown tree: {', '.join(summary['dirty_runs'])}", ""]
    if summary.get("stale_runs"):
        lines += [
            "Runs made under other hyperparameters than today's configs: " + ", ".join(summary["stale_runs"])
        ]
    path = out_dir / "summary.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def _num(value: float | None, digits: int = 0) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def format_cost(summary: dict[str, Any], markdown: bool = False) -> str:
    """Each method's throughput and memory over its finished runs (``summary["cost"]``) as a table."""
    head = ("method", "runs", "wall-clock s/run", "env steps/s", "peak RSS MB mean / max", "wall vs TD3")
    rows = []
    for algo, c in summary.get("cost", {}).items():
        lo, hi = c["wall_vs_td3_min"], c["wall_vs_td3_max"]
        ratio = "—" if lo is None else f"{lo:.2f}x" if abs(hi - lo) < 0.005 else f"{lo:.2f}-{hi:.2f}x"
        rss = f"{_num(c['peak_rss_mb'])} / {_num(c['peak_rss_mb_max'])}"
        rows.append(
            (ALGO_LABELS.get(algo, algo), str(c["runs"]), _num(c["wall_s_per_run"], 1),
             _num(c["steps_per_s"]), rss, ratio)
        )  # fmt: skip
    note = (
        "wall-clock of learn per run (mean over all the method's runs, one run per core), env steps per "
        "second over all its runs, peak RSS of each run's process; wall vs TD3: its mean wall-clock per "
        "run over TD3's on the same setting, lowest-highest over the settings."
    )
    if markdown:
        table = [f"| {' | '.join(head)} |", "|" + "---|" * len(head)]
        table += [f"| {' | '.join(r)} |" for r in rows]
        return "\n".join([note[0].upper() + note[1:], "", *table])
    widths = [max(len(x) for x in col) for col in zip(head, *rows, strict=True)]
    fmt = "  ".join(f"{{:<{w}}}" if i == 0 else f"{{:>{w}}}" for i, w in enumerate(widths))
    lines = textwrap.wrap("Cost per method: " + note, width=110)
    return "\n".join([*lines, fmt.format(*head), *(fmt.format(*r) for r in rows)])


def format_machines(summary: dict[str, Any]) -> list[str]:
    """summary.md's lines on which CPUs made the runs, and a warning where one setting's runs span several."""
    counts = summary.get("machines") or {}
    lines = ["Machines (CPU: runs) per setting: " + "; ".join(f"{env}: {by}" for env, by in counts.items())]
    mixed = mixed_machines(counts)
    if mixed:
        lines += [
            "Settings whose runs come from more than one CPU (or an unrecorded one): "
            + ", ".join(mixed)
            + ". A seed's run differs from one SIMD level to another (NS CartPole and NS Pendulum most)."
        ]
    return lines


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
            line = f"{sub}{comp}: {d['diff']:+.1f} [{d['lo']:+.1f}, {d['hi']:+.1f}]"
            line += f", seeds {d['n_a']} vs {d['n_b']}"
            p = d.get("paired") or {}
            line += f" -> {d.get('unpaired_outcome', d['outcome'])}"  # the level verdict decides on paired
            if p.get("diff") is not None:
                line += f"; paired over {p['n_a']} seeds {p['diff']:+.1f} [{p['lo']:+.1f}, {p['hi']:+.1f}]"
                line += f" -> {p['outcome']}"
            lines.append(line)
    return "\n".join(lines)
