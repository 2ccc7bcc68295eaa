"""The tables of README.md and docs/, and the results pages, rendered from results/*.json, so no number is
typed by hand.

A table sits between ``<!-- table: NAME -->`` and ``<!-- end table -->``; the results pages
(``results/*.md``, the docs site's ``results/``: one per bench, and an index of every results file) are
written whole from ``PAGES``. ``python scripts/results_tables.py`` rewrites every block and page from
its results files, ``--check`` exits 1 naming those that differ (``tests/scripts/test_results_tables.py``
runs the check).
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

from experiments.plans_tables import default_table

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BLOCK = re.compile(r"(<!-- table: (?P<name>[\w-]+) -->\n)(?P<body>.*?)(<!-- end table -->)", re.S)
GOAL = 0.70  # the bar: last-quarter success in every run


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f}"


def _median(values: list[float]) -> float | None:
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def _fmt(x: float | None, spec: str = ".0f") -> str:
    return "-" if x is None else format(x, spec)


def _row_label(run: dict[str, Any]) -> str:
    return f"{run['variant']}/{run['condition']}" if run.get("variant") else run["condition"]


def stack_robustness_shipped(data: dict[str, Any]) -> str:
    """The shipped agent's rows only (the README's headline)."""
    shipped = {k: v for k, v in data["table"].items() if "/" not in k}
    runs = [r for r in data["runs"] if not r.get("variant")]
    return stack_robustness({**data, "table": shipped, "runs": runs})


def stack_robustness(data: dict[str, Any]) -> str:
    """``results/stack_robustness.json``: one row per condition (and agent variant), medians over seeds."""
    lines = [
        "| condition | seeds | last-quarter success %, median (range) | success by quarter %, median |"
        " runs < 70 % | mean H | workspace clips | target age p50 / p99 ms | load, 5-min avg |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for label, row in data["table"].items():
        runs = [r for r in data["runs"] if _row_label(r) == label]
        last = [r["success_by_quarter"][-1] for r in runs]
        by_q = " / ".join(_pct(_median([r["success_by_quarter"][q] for r in runs])) for q in range(4))
        lo, hi = row["last_quarter_success_range"]
        ages = [r.get("target_age_ms") or {} for r in runs]
        age = f"{_fmt(_median([a.get('p50') for a in ages]))} / {_fmt(_median([a.get('p99') for a in ages]))}"
        in_process = row.get("seeds") and label.endswith("in_process")
        lines.append(
            f"| {label} | {', '.join(map(str, row['seeds']))} "
            f"| {_pct(row['last_quarter_success_median'])} ({_pct(lo)}-{_pct(hi)}) | {by_q} "
            f"| {sum(x is not None and x < GOAL for x in last)} "
            f"| {_fmt(_median([r.get('mean_H') for r in runs]), '.1f')} "
            f"| {'-' if in_process else _fmt(row['workspace_clips_median'])} "
            f"| {'-' if in_process else age} "
            f"| {_fmt(_median([(r.get('load_during') or [None, None])[1] for r in runs]), '.1f')} |"
        )
    restarts = [
        (_row_label(r), (r.get("robot_io_restart") or {}).get("resumed_after_s"))
        for r in data["runs"]
        if _row_label(r) in data["table"]
    ]
    shown = ", ".join(f"{s:.1f} s ({label})" for label, s in restarts if s is not None)
    if shown:
        lines += ["", f"robot-io SIGKILLed halfway: learning resumed {shown} after the kill."]
    return "\n".join(lines) + "\n"


def sim_camera(data: dict[str, Any]) -> str:
    """``results/vision_bench.json``: each sim-camera renderer side by side, then a frame's whole path."""
    render = data["sim_render"]
    lines = ["| renderer | 640x480 fps, one core |", "|---|---|"]
    for name, label in (
        ("mujoco", "MuJoCo, EGL on llvmpipe (shipped)"),
        ("pybullet_egl", "PyBullet's EGL plugin on llvmpipe"),
        ("tiny", "PyBullet's TinyRenderer (fallback)"),
    ):
        lines.append(f"| {label} | {render[name]['640x480']['fps']:.1f} |")
    path = render["render_detect_deproject_640x480"]
    e2e, machine = data["end_to_end"], data["machine"]
    lines += [
        f"| render + detection + deprojection ({path['renderer']}) | {path['fps']:.1f} |",
        "",
        f"Capture to target received in another process ({e2e['size']} at {e2e['rate_hz']:.0f} Hz): "
        f"p50 {e2e['capture_to_target_ms']['p50']:.0f} ms, p99 {e2e['capture_to_target_ms']['p99']:.0f} ms "
        f"(machine load {machine['load_avg_1min']:.1f} on {machine['cores_available']} cores).",
    ]
    return "\n".join(lines) + "\n"


def robot_io_tick(data: dict[str, Any]) -> str:
    """``results/robot_io_bench.json``: the control tick's parts, then the two-process latencies."""
    tick = data["tick_in_process"]
    qps = tick["ik_qps_per_command"]
    rows = [
        (f"IK, one command ({qps} QP{'s' if qps > 1 else ''})", tick["ik"]),
        ("one bare mink QP, same problem, same run", tick["bare_mink_qp"]),
        ("command check (joint, speed, workspace)", tick["command_check"]),
        ("state (position and velocity, one kinematics pass)", tick["state"]),
        ("the tick without the simulator's physics step", tick["tick_without_physics"]),
        ("PyBullet physics step (the mock's, not the controller's)", tick["physics_step"]),
        (
            "chunk sent → first joint command applied (two processes)",
            data["chunk_sent_to_first_command_applied"],
        ),
        ("e-stop sent → safety event received", data["estop_sent_to_event_received"]),
        ("e-stop sent → joint speed < 0.01 rad/s", data["estop_sent_to_joint_speed_below_0.01"]),
    ]
    lines = ["| measure | p50 ms | p99 ms | max ms |", "|---|---|---|---|"]
    lines += [f"| {name} | {p['p50_ms']:.2f} | {p['p99_ms']:.2f} | {p['max_ms']:.2f} |" for name, p in rows]
    rate = data["state_rate_hz"]
    lines += [
        "",
        f"State rate {rate['achieved']:.1f} Hz (target {rate['target']:.0f}); gap between states p99 "
        f"{rate['gap_p99_ms']:.0f} ms. IK p99 / bare QP p99: {tick['ik_p99_over_bare_qp_p99']:.2f}.",
    ]
    return "\n".join(lines) + "\n"


def handoff(data: dict[str, Any]) -> str:
    """``results/handoff.json``: per setting and start, medians over the seeds run."""
    lines = [
        "| setting | start | seeds | success by quarter %, median | last quarter % (range) | steps to 90 %"
        " rolling | mean H by quarter | H, first 500 steps | clips | reflexes | Hz not homing | homing s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in data["rows"]:
        lo, hi = r["last_quarter_range"]
        cells = [
            r["setting"],
            r["variant"],
            ", ".join(map(str, r["seeds"])),
            " / ".join(_pct(x) for x in r["success_by_quarter"] or []),
            f"{_pct(lo)}-{_pct(hi)}",
            ", ".join(_fmt(x, "d") for x in r["steps_to_90pct_rolling"]),
            " / ".join(_fmt(x, ".1f") for x in r["mean_H_by_quarter"] or []),
            _fmt(r["H_first_500_steps"], ".1f"),
            _fmt(r["workspace_clips"]),
            str(r["reflexes"]),
            _fmt(r["control_hz_not_homing"], ".1f"),
            _fmt(r["homing_s"]),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def handoff_headline(data: dict[str, Any]) -> str:
    """``results/handoff.json``, one row per setting (the README's): each start's first and last quarter
    (medians over seeds, the last quarter's range), and the handoff's H early on against its last quarter."""
    starts = ("scratch", "handoff", "frozen", "fixed_h")
    lines = [
        "| setting | "
        + " | ".join(f"{s}: first / last quarter %" for s in starts)
        + " | handoff H, first 500 steps / last quarter |",
        "|---|" + "---|" * (len(starts) + 1),
    ]
    settings = dict.fromkeys(r["setting"] for r in data["rows"])
    for setting in settings:
        rows = {r["variant"]: r for r in data["rows"] if r["setting"] == setting}
        cells = [setting]
        for start in starts:
            r = rows.get(start)
            if r is None:
                cells.append("not run")
                continue
            q = r["success_by_quarter"] or [None] * 4
            lo, hi = r["last_quarter_range"]
            cells.append(f"{_pct(q[0])} / {_pct(q[3])} ({_pct(lo)}-{_pct(hi)}; seeds {len(r['seeds'])})")
        h = rows.get("handoff")
        last_h = (h["mean_H_by_quarter"] or [None] * 4)[3] if h else None
        cells.append(f"{_fmt(h['H_first_500_steps'], '.1f')} / {_fmt(last_h, '.1f')}" if h else "-")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def handoff_comparisons(data: dict[str, Any]) -> str:
    """``results/handoff.json``: the handoff learning with the adaptive retreat against fixed H and against
    the frozen policy, per setting: the difference of success rates in the last quarter and over the whole
    run, pooled over the seeds both ran, with 95 % intervals."""
    lines = [
        "| setting | against | seeds | last quarter, points (95 % interval)"
        " | whole run, points (95 % interval) |",
        "|---|---|---|---|---|",
    ]
    for c in data["comparisons"]:
        cells = [c["setting"], c["against"], ", ".join(map(str, c["seeds"]))]
        for key in ("last_quarter", "whole_run"):
            d = c[key]
            cells.append(f"{100 * d['diff']:+.1f} ({100 * d['lo']:+.1f} to {100 * d['hi']:+.1f})")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def fleet(data: dict[str, Any]) -> str:
    """``results/fleet.json``: per number of arms, the seeds' steps and seconds to 70 % rolling success,
    last-quarter success per arm, the learner's rate and each arm's CPU."""
    lines = [
        "| arms | seeds | steps to 70 % rolling (each seed) | seconds to 70 % (each seed) |"
        " last-quarter success % per arm (each seed) | learner transitions/s | CPU per arm, cores (max) |"
        " steps/s per arm |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for n, r in sorted(data["by_arms"].items(), key=lambda kv: int(kv[0])):
        per_arm = "; ".join("/".join(_pct(x) for x in seed) for seed in r["last_quarter_success_per_arm"])
        cells = [
            n,
            ", ".join(map(str, r["seeds"])),
            ", ".join(_fmt(x, "d") for x in r["steps_to_goal"]),
            ", ".join(_fmt(x) for x in r["wall_to_goal_s"]),
            per_arm,
            _fmt(r["learner_transitions_per_s"]),
            f"{_fmt(r['cpu_cores_per_arm'], '.2f')} ({_fmt(r['max_cpu_cores_per_arm'], '.2f')})",
            _fmt(r["steps_per_s_per_arm"], ".1f"),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def fleet_goals(data: dict[str, Any]) -> str:
    """``results/fleet.json``: each goal of issue #47 the bench measures, its value and whether it is met."""
    lines = ["| goal | measured | bar | met |", "|---|---|---|---|"]
    for name, g in data["goals"].items():
        value = g["value"]
        shown = "-" if value is None else (f"{value:.2f}" if isinstance(value, float) else str(value))
        lines.append(f"| {name.replace('_', ' ')} | {shown} | {g['goal']} | {'yes' if g['met'] else 'no'} |")
    return "\n".join(lines) + "\n"


def plans_point(data: dict[str, Any], method: str) -> str:
    """A plans-bench summary (``results/plans``, or ``results/plans_s10``: the front, the default and the
    corrected option on 10 seeds): one plan-retreat point per setting against the bar (above the
    fixed-H front on 4 of 5 settings, below on none)."""
    return "\n".join(default_table(data, method)) + "\n"


TABLES: dict[str, tuple[str, Callable[[dict[str, Any]], str]]] = {
    "robot_io_tick": ("results/robot_io_bench.json", robot_io_tick),
    "sim_camera": ("results/vision_bench.json", sim_camera),
    "stack_robustness": ("results/stack_robustness.json", stack_robustness),
    "stack_robustness_shipped": ("results/stack_robustness.json", stack_robustness_shipped),
    "handoff": ("results/handoff.json", handoff),
    "handoff_headline": ("results/handoff.json", handoff_headline),
    "handoff_comparisons": ("results/handoff.json", handoff_comparisons),
    "handoff_velocity": ("results/handoff_velocity.json", handoff),
    "handoff_velocity_comparisons": ("results/handoff_velocity.json", handoff_comparisons),
    "handoff_start": ("results/handoff_start.json", handoff),
    "handoff_rest_lead01": ("results/handoff_rehearsal_rest_lead01.json", handoff),
    "handoff_sigma005": ("results/handoff_rehearsal_sigma005.json", handoff),
    "handoff_anneal4000": ("results/handoff_anneal4000.json", handoff),
    "handoff_schedule10000": ("results/handoff_schedule10000.json", handoff),
    "handoff_hmax20": ("results/handoff_hmax20.json", handoff),
    "handoff_hmax20_comparisons": ("results/handoff_hmax20.json", handoff_comparisons),
    "handoff_corrected": ("results/handoff_corrected.json", handoff),
    "handoff_corrected_comparisons": ("results/handoff_corrected.json", handoff_comparisons),
    "handoff_franka_limits_sim_box": ("results/handoff_franka_limits_sim_box.json", handoff),
    "handoff_franka_limits_sim_box_rerun": ("results/handoff_franka_limits_sim_box_rerun.json", handoff),
    "fleet": ("results/fleet.json", fleet),
    "fleet_goals": ("results/fleet.json", fleet_goals),
    "plans_default": ("results/plans/summary.json", partial(plans_point, method="adaptiveh-default")),
    "plans_corrected": ("results/plans/summary.json", partial(plans_point, method="adaptiveh-corrected")),
    "plans_s10_default": ("results/plans_s10/summary.json", partial(plans_point, method="adaptiveh-default")),
    "plans_s10_corrected": (
        "results/plans_s10/summary.json",
        partial(plans_point, method="adaptiveh-corrected"),
    ),
}


def render(name: str) -> str:
    if name not in TABLES:
        raise KeyError(f"table {name!r}: no such table; known: {sorted(TABLES)}")
    path, make = TABLES[name]
    return make(json.loads((ROOT / path).read_text()))


def refreshed(text: str) -> str:
    """``text`` with every table block rendered again."""
    return BLOCK.sub(lambda mt: mt.group(1) + render(mt.group("name")) + mt.group(4), text)


# -- the results pages ---------------------------------------------------------------------------------

RESULTS = ROOT / "results"
PAGE_HEADER = (
    "*Generated from `{sources}` by `python scripts/results_tables.py`;"
    " tests/scripts/test_results_tables.py fails while this page is stale.*"
)


class Page(NamedTuple):
    """One results page: its title, what it answers, the command that made its results, and its parts:
    ``("## heading", TABLE name)``, ``("## heading", "figure.png")`` or ``("## heading", "text")``."""

    title: str
    intro: str
    made_by: str
    parts: tuple[tuple[str, str], ...]
    explained: str  # the docs page that reads these numbers


PAGES: dict[str, Page] = {
    "stack_robustness.md": Page(
        "The main job under timing conditions",
        "What the main job (`bash scripts/run.sh`: 6000 steps, the actor beside the arm) achieves under"
        " each timing condition, per seed, with the in-process learner on the same seeds as the reference:"
        " medians over seeds, the range in brackets.",
        "python bench/stack_robustness.py",
        (
            ("## The shipped stack", "stack_robustness_shipped"),
            ("## Every condition and agent variant", "stack_robustness"),
            ("## Figure", "stack_robustness.png"),
            ("## Earlier agents and cameras", "stack_robustness_history.png"),
        ),
        "../stack_timing.md#timing-measured",
    ),
    "handoff.md": Page(
        "From the simulator to the arm: handoffs",
        "What a policy trained in simulation brings to franky-sim and to four reality-gap overlays of the"
        " mock, against learning from scratch and a frozen policy: medians over the seeds run.",
        "python bench/handoff.py",
        (
            ("## By setting and start", "handoff"),
            (
                "## Learning with the retreat against fixed H and against the frozen policy (handoff minus"
                " the other, pooled over seeds; the interval takes episodes as independent)",
                "handoff_comparisons",
            ),
            ("## Figure", "handoff.png"),
            (
                "## The rehearsal before it took the real arm's stream (`franka_sim.yaml` with"
                " `stream: velocity`, a 10 cm command lead and its tracking fit; `--out"
                " results/handoff_velocity`). The franky-sim sections below ran at these settings too",
                "handoff_velocity",
            ),
            ("### Against fixed H and the frozen policy", "handoff_velocity_comparisons"),
            (
                "## The rehearsal's stream with a 10 cm command lead (tried, not adopted: `command_lead_m:"
                " 0.1` and its tracking fit, `results/handoff_rehearsal_rest_lead01/reach_model.json`;"
                " `--out results/handoff_rehearsal_rest_lead01`)",
                "handoff_rest_lead01",
            ),
            (
                "## The rehearsal with the exploration ending at half the mock's (tried, not adopted:"
                " `--agent sigma_final=0.05 --out results/handoff_rehearsal_sigma005`)",
                "handoff_sigma005",
            ),
            (
                "## Scratch on franky-sim: the start, 1000 steps (`--seeds 3 4 5 6 --steps 1000 --out"
                " results/handoff_start`)",
                "handoff_start",
            ),
            (
                "## Scratch on franky-sim, exploration annealed by step 4000 (tried, not adopted:"
                " `learner.agent.schedule_steps: 4000`, `--out results/handoff_anneal4000`)",
                "handoff_anneal4000",
            ),
            (
                "## Scratch on franky-sim, exploration annealed over 10000 steps, ungated (the default until"
                " `schedule_gate`; `--out results/handoff_schedule10000`)",
                "handoff_schedule10000",
            ),
            (
                "## Handoff on franky-sim with segments of at most 20 steps (tried, not adopted:"
                " `--agent h_max=20 --out results/handoff_hmax20`)",
                "handoff_hmax20",
            ),
            ("### Against fixed H at its mean H", "handoff_hmax20_comparisons"),
            (
                "## Segments of at most 20 steps and the plan model corrected online (tried, not adopted:"
                " `--agent h_max=20 plan_model=corrected --out results/handoff_corrected`)",
                "handoff_corrected",
            ),
            ("### Against fixed H at its mean H", "handoff_corrected_comparisons"),
            (
                "## The real arm's settings with the simulator's workspace box (`franka_limits.yaml` until"
                " 2026-12-08; on franka-sim its policy folded the arm onto itself; `--out"
                " results/handoff_franka_limits_sim_box`)",
                "handoff_franka_limits_sim_box",
            ),
            (
                "### The same, seed 0 again at the code of 2026-12-08 (each franky motion its own dynamics"
                " factor; `--seeds 0 --out results/handoff_franka_limits_sim_box_rerun`)",
                "handoff_franka_limits_sim_box_rerun",
            ),
        ),
        "../handoff.md#results",
    ),
    "fleet.md": Page(
        "Several arms, one learner",
        "NS Reach over the stack with N simulated arms feeding one learner on this 2-core machine (cameras"
        " off for every N): steps of all arms together and seconds until the pooled rolling success over"
        " 20 episodes reaches 70 %, then the fault runs (learner outage, an arm stopped, an arm added).",
        "python bench/fleet.py --arms 1 2 4 --seeds 0 1 2 --faults",
        (("## By number of arms", "fleet"), ("## Goals", "fleet_goals"), ("## Figure", "fleet.png")),
        "../fleet.md#measured",
    ),
    "plans.md": Page(
        "Plans: the plan retreat against fixed horizons",
        "The default plan retreat, one configuration for every setting, against the fixed-H front (unpaired,"
        " and paired per seed), on five seeds and on ten; every number of each bench is in its own"
        " report ([five seeds](plans/summary.md), [ten seeds](plans_s10/summary.md)).",
        "adaptiveh bench plans",
        (
            ("## The default, five seeds", "plans_default"),
            ("## The plan model corrected online, five seeds", "plans_corrected"),
            ("## The default, ten seeds", "plans_s10_default"),
            ("## The plan model corrected online, ten seeds", "plans_s10_corrected"),
            ("## Return against re-plans", "plans/front.png"),
            ("## Return against latency", "plans/latency.png"),
        ),
        "../paper_plans.md",
    ),
    "robot_io.md": Page(
        "robot-io's control tick",
        "The control tick's parts in one process (PyBullet mock, 20 Hz, random steps up to the action"
        " bound), then robot-io as its own process driven over loopback Zenoh.",
        "python bench/robot_io_bench.py",
        (("## The tick and its latencies", "robot_io_tick"),),
        "../robot_interface.md",
    ),
    "vision.md": Page(
        "The sim camera and vision",
        "Each renderer of the sim camera side by side on one core, and a frame's path from capture to the"
        " target received in another process.",
        "python bench/vision_bench.py",
        (("## Renderers and latency", "sim_camera"),),
        "../vision.md",
    ),
}
INDEX = "index.md"


def _sources(page: Page) -> list[str]:
    return sorted({TABLES[name][0] for _, name in page.parts if name in TABLES})


def render_page(page: Page) -> str:
    """``page`` as markdown: its tables rendered from their results files, its figures linked."""
    sources = _sources(page)
    lines = [
        f"# {page.title}",
        "",
        PAGE_HEADER.format(sources="`, `".join(sources)),
        "",
        f"{page.intro} Made by `{page.made_by}`; read in [the docs]({page.explained}).",
        "",
    ]
    for heading, part in page.parts:
        lines += [heading, ""]
        if part in TABLES:
            lines += [render(part).rstrip("\n"), ""]
        elif part.endswith(".png"):
            lines += [f"![{heading.lstrip('# ')}]({part})", ""]
        else:
            lines += [part, ""]
    return "\n".join(lines).rstrip("\n") + "\n"


def render_index(pages: dict[str, Page] = PAGES, results: Path = RESULTS) -> str:
    """The results index: each page, then every results file (JSON, figure, report) and the page that
    shows it (else the docs pages that name it), so a results file nothing shows is listed as such."""
    docs = sorted((ROOT / "docs").glob("*.md"))
    shown: dict[str, str] = {}
    for name, page in pages.items():
        for source in _sources(page):
            shown.setdefault(source.removeprefix("results/"), name)
        for _, part in page.parts:
            if part.endswith(".png"):
                shown.setdefault(part, name)
    files = sorted(
        p.relative_to(results).as_posix()
        for pattern in ("*.json", "*.png", "*/summary.md", "*/summary.json", "*/*.png")
        for p in results.glob(pattern)
    )
    lines = [
        "# Results",
        "",
        PAGE_HEADER.format(sources="results/"),
        "",
        "What the benches measured, one page per bench; each table is rendered from the results file"
        " the bench wrote, so no number on these pages is typed by hand.",
        "",
        *(f"- [{page.title}]({name}): `{page.made_by}`" for name, page in pages.items()),
        "- [The paper bench](paper/summary.md): `adaptiveh bench paper`, its report",
        "",
        "## Every results file",
        "",
        "| file | shown on |",
        "|---|---|",
    ]
    for f in files:
        report = f"{f.split('/')[0]}/summary.md"
        if f in shown:
            where = f"[{pages[shown[f]].title}]({shown[f]})"
        elif f == report:
            where = f"[the report itself]({report})"
        elif "/" in f and (results / report).is_file():
            where = f"[its report]({report})"
        else:
            read = [d for d in docs if f"results/{f}" in d.read_text()]
            where = ", ".join(f"read in [{d.stem}](../{d.name})" for d in read[:2]) or "-"
        lines.append(f"| `{f}` | {where} |")
    return "\n".join(lines) + "\n"


def rendered_pages() -> dict[str, str]:
    """Every results page, file name under results/ -> markdown."""
    return {**{name: render_page(page) for name, page in PAGES.items()}, INDEX: render_index()}


def stale_pages(pages: dict[str, str], results: Path = RESULTS) -> list[str]:
    """The pages whose file under ``results`` is missing or differs."""
    return [
        n for n, text in pages.items() if not (results / n).is_file() or (results / n).read_text() != text
    ]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="change nothing; exit 1 if a table is stale")
    args = ap.parse_args()
    stale = []
    for doc in DOCS:
        text = doc.read_text()
        new = refreshed(text)
        if new != text:
            stale.append(str(doc.relative_to(ROOT)))
            if not args.check:
                doc.write_text(new)
    pages = rendered_pages()
    for name in stale_pages(pages):
        stale.append(f"results/{name}")
        if not args.check:
            (RESULTS / name).write_text(pages[name])
    if stale:
        print(("stale tables in: " if args.check else "rewrote: ") + ", ".join(stale))
    return 1 if stale and args.check else 0


if __name__ == "__main__":
    sys.exit(main())
