"""What the learner does at the switch from simulator to arm: handing a trained policy to another world.

Settings (each a stack config): ``franky_sim`` (configs/franka_sim.yaml against franky-sim, which this
bench starts on a private loopback address: another simulator, another arm model, its own PD lag) and the
reality-gap overlays on the PyBullet mock (configs/gaps/: ``slow_arm``, ``camera_offset``,
``actuation_latency``, ``target_motion``), and ``franka_limits``: franky-sim driven with the real arm's
motion settings (configs/franka_realsense.yaml's). Variants per setting and seed:

- ``scratch``: the product's default from an empty policy;
- ``handoff``: from the in-process PyBullet policy of the same seed (``adaptiveh train --config
  configs/reach.yaml --steps 10000``, trained here once per seed), learning on;
- ``frozen``: the same policy, never updated (``learner.agent.frozen``);
- ``fixed_h``: the same policy with the fixed-H learner at the ``handoff`` run's mean H.

Per run: success by quarter, steps until 90 % rolling success (20 episodes), workspace clips, reflexes
(``driver_error`` events), the achieved control rate while the arm is not homing (and the time spent
homing), mean H per quarter, and H over the first 500 steps; per setting, the handoff against fixed H and
against frozen (differences of success rates with 95 % intervals). Each run is kept in
``results/handoff/<setting>/<variant>_s<seed>.json`` and not run again (resumable) unless it learned after
the handoff at another ``handoff_step_scale`` than its config gives now; ``results/handoff.json``
and ``results/handoff.png`` summarise whatever has finished. One run at a time. A run under 90 % in its last
quarter keeps its recording in ``runs/handoff_short/`` (``recording_kept`` in its file).

    python bench/handoff.py [--settings franky_sim ...] [--variants ...] [--seeds 0 1 2] [--steps 6000]
                            [--out results/handoff] [--agent KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "scripts")]
import results_tables  # noqa: E402
from loopback import free_endpoint, unique_name  # noqa: E402

from bus import messages as m  # noqa: E402
from deploy.config import compose_stack_yaml  # noqa: E402
from experiments.stats import rate_diff  # noqa: E402
from monitor import recording  # noqa: E402

OUT = ROOT / "results" / "handoff"
SOURCES = ROOT / "runs" / "handoff_sources"
FAILED = ROOT / "runs" / "handoff_failed"  # the config and logs of a run whose stack exited in error
SHORT = ROOT / "runs" / "handoff_short"  # recordings of runs under GOAL in the last quarter, to read why
GOAL = 0.9  # last-quarter success the goals ask of every run
SETTINGS = {
    "franky_sim": "configs/franka_sim.yaml",
    "slow_arm": "configs/gaps/slow_arm.yaml",
    "camera_offset": "configs/gaps/camera_offset.yaml",
    "actuation_latency": "configs/gaps/actuation_latency.yaml",
    "target_motion": "configs/gaps/target_motion.yaml",
    "franka_limits": "configs/gaps/franka_limits.yaml",
}
VARIANTS = ("scratch", "handoff", "frozen", "fixed_h")
COLOURS = {"scratch": "tab:blue", "handoff": "tab:orange", "frozen": "tab:green", "fixed_h": "tab:red"}
SOURCE_STEPS = 10_000
ROLLING = 20  # episodes in the rolling success rate
OUTSIDE_M = 0.01  # the hand further than this outside the workspace box counts as out of it
HOMING_GAP_S = 0.2  # consecutive ticks further apart than this: the arm was homing (or held)
FRANKY_HOST = "127.0.77.7"


def source_policy(seed: int) -> Path:
    """The in-process PyBullet policy of ``seed`` (trained once, then reused)."""
    out = SOURCES / f"reach_s{seed}"
    if not (out / "result.json").exists():
        print(f"training the source policy, seed {seed} ({SOURCE_STEPS} steps in-process)", flush=True)
        subprocess.run(
            [
                sys.executable,
                "-m",
                "deploy.cli",
                "train",
                "--config",
                "configs/reach.yaml",
                "--steps",
                str(SOURCE_STEPS),
                "--seed",
                str(seed),
                "--out",
                str(out),
                "--fresh",
            ],
            cwd=ROOT,
            check=True,
            stdout=subprocess.DEVNULL,
        )
    return out / "checkpoint.pkl"


def stack_config(
    setting: str,
    variant: str,
    seed: int,
    steps: int,
    tmp: Path,
    fixed_h: int | None,
    overrides: dict[str, Any],
) -> Path:
    cfg = compose_stack_yaml(ROOT / SETTINGS[setting])
    cfg["name"] = unique_name("hand")
    cfg["zenoh"]["hub"] = free_endpoint()
    cfg["robot"]["seed"] = seed
    if cfg["robot"]["backend"] == "franka":
        cfg["robot"]["franka"]["ip"] = FRANKY_HOST
    agent = dict(cfg["learner"].get("agent") or {}) | overrides
    if variant == "frozen":
        agent["frozen"] = True
    if variant == "fixed_h":
        cfg["learner"]["algo"] = "rkhs"
        agent["fixed_h"] = fixed_h
    cfg["learner"].update(steps=steps, seed=seed, checkpoint_dir=str(tmp / "learner"), agent=agent)
    cfg["monitor"].update(port=0, foxglove_port=None)
    cfg["recording"]["dir"] = str(tmp / "rec")
    path = tmp / "stack.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def step_scale(setting: str, overrides: dict[str, Any]) -> float:
    """The fine-tuning step after a handoff that ``setting``'s config gives (``handoff_step_scale``)."""
    agent = (compose_stack_yaml(ROOT / SETTINGS[setting])["learner"].get("agent") or {}) | overrides
    return float(agent.get("handoff_step_scale", 1.0))


def stale(run: dict[str, Any]) -> bool:
    """A run that learned after a handoff at another step than its config's now (runs before the key: 1.0)."""
    learned_after_handoff = run["variant"] in ("handoff", "fixed_h")
    now = step_scale(run["setting"], run.get("agent", {}))
    return learned_after_handoff and run.get("handoff_step_scale", 1.0) != now


def run_one(
    setting: str, variant: str, seed: int, steps: int, fixed_h: int | None, agent: dict[str, Any]
) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        path = stack_config(setting, variant, seed, steps, tmp, fixed_h, agent)
        cmd = [sys.executable, "-m", "deploy.cli", "up", str(path), "--summary", str(tmp / "summary.json")]
        if variant != "scratch":
            cmd += ["--policy-from", str(source_policy(seed))]
        t0 = time.time()
        with (tmp / "up.log").open("w") as log:
            up = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=log, text=True)
            for line in up.stdout:  # progress, as the stack prints it
                if line.startswith("["):
                    print(f"  {setting}/{variant} s{seed} {line.rstrip()}", flush=True)
            up.wait()
        if up.returncode != 0 or not (tmp / "summary.json").exists():
            kept = FAILED / setting / f"{variant}_s{seed}"
            shutil.rmtree(kept, ignore_errors=True)
            shutil.copytree(tmp, kept, ignore=shutil.ignore_patterns("*.mcap", "learner"))
            raise RuntimeError(
                f"{setting}/{variant} s{seed}: adaptiveh up exited {up.returncode} (its config and the"
                f" parts' logs kept in {kept.relative_to(ROOT)}):\n" + (tmp / "up.log").read_text()[-3000:]
            )
        summary = json.loads((tmp / "summary.json").read_text())
        result = json.loads((tmp / "learner" / "result.json").read_text())
        records = recording.read(summary["recording"])
        ticks = control_rate(records)
        box = yaml.safe_load(path.read_text())["robot"]["workspace"]
        outside = hand_outside_box(records, box["lo"], box["hi"])
        learned = learning(result["episodes"], result["segments"], steps)
        kept = keep_if_short(learned, summary["recording_parts"], setting, variant, seed)
    return {
        "setting": setting,
        "variant": variant,
        "seed": seed,
        "steps": summary["global_step"],
        "wall_clock_s": round(time.time() - t0, 1),
        "started_from": summary["started_from"],
        **learned,
        "recording_kept": kept,
        "workspace_clips": summary["safety_events"].get("workspace", 0),
        "reflexes": summary["safety_events"].get("driver_error", 0),
        "safety_events": summary["safety_events"],
        **ticks,
        **outside,
        "fixed_h": fixed_h,
        "handoff_step_scale": step_scale(setting, agent),
        **({"agent": agent} if agent else {}),
    }


def keep_if_short(
    learned: dict[str, Any], parts: list[str], setting: str, variant: str, seed: int
) -> str | None:
    """Keep the recording of a run that ended under ``GOAL`` (``runs/handoff_short/``): what the arm and the
    learner did is the only way to tell why it fell short (`adaptiveh replay` reads it)."""
    quarters = learned["success_by_quarter"]
    if quarters is None or quarters[-1] >= GOAL:
        return None
    dest = SHORT / setting
    dest.mkdir(parents=True, exist_ok=True)
    first = dest / f"{variant}_s{seed}.mcap"
    for n, part in enumerate(parts):
        shutil.copyfile(part, first if n == 0 else recording.part_path(first, n + 1))
    return str(first.relative_to(ROOT))


def learning(episodes: list[dict], segments: list[dict], steps: int) -> dict[str, Any]:
    """Success by quarter (of episodes), steps to 90 % rolling success, and H by quarter and early on."""
    success = np.array([bool(e["success"]) for e in episodes], float)
    q = max(1, len(success) // 4)
    by_quarter = (
        [float(np.mean(success[i * q : (i + 1) * q])) for i in range(4)] if len(success) >= 4 else None
    )
    rolling = [np.mean(success[max(0, i - ROLLING + 1) : i + 1]) for i in range(len(success))]
    reached = next(
        (episodes[i]["global_step"] for i, r in enumerate(rolling) if i >= ROLLING - 1 and r >= 0.9), None
    )
    h = np.array([(s["global_step"], s["H"]) for s in segments], float).reshape(-1, 2)
    quarter_steps = steps / 4
    h_q = [
        float(np.mean(h[(h[:, 0] > i * quarter_steps) & (h[:, 0] <= (i + 1) * quarter_steps), 1]))
        if np.any((h[:, 0] > i * quarter_steps) & (h[:, 0] <= (i + 1) * quarter_steps))
        else None
        for i in range(4)
    ]
    early = h[h[:, 0] <= 500, 1]
    return {
        "success_by_quarter": by_quarter,
        "steps_to_90pct_rolling": reached,
        "mean_H_by_quarter": h_q,
        "mean_H": float(np.mean(h[:, 1])) if len(h) else None,
        "H_first_500_steps": float(np.mean(early)) if len(early) else None,
        "episodes": len(episodes),
        # each episode's final hand-to-target distance (success: under 5 cm): how near the misses were
        "final_distance_m": [round(float(e["info"]["distance"]), 4) for e in episodes],
    }


def control_rate(records: list) -> dict[str, Any]:
    """robot-io's tick rate while the arm is not homing, from the states' stamps; the time spent homing."""
    ticks: dict[int, float] = {}
    for topic, _, _, data in records:
        if topic.endswith("/" + m.STATE.name):
            s = m.RobotState.FromString(data)
            ticks.setdefault(s.tick, s.stamp)
    order = sorted(ticks)
    gaps = np.array([ticks[b] - ticks[a] for a, b in zip(order, order[1:], strict=False) if b == a + 1])
    running = gaps[gaps < HOMING_GAP_S]
    return {
        "control_hz_not_homing": round(len(running) / float(running.sum()), 2) if len(running) else None,
        "control_hz_p5_window": _worst_window_hz(running),
        "homing_s": round(float(gaps[gaps >= HOMING_GAP_S].sum()), 1),
        "ticks": len(order),
    }


def hand_outside_box(records: list, lo: list[float], hi: list[float]) -> dict[str, Any]:
    """How often and how far the measured hand left ``robot.workspace`` in the ticks that played an action
    (each tick once): robot-io clips each goal into the box, so a hand outside it then is the arm overshooting
    its command (on a real arm: toward the table). Homing (a joint-space move) and holds publish states too:
    their deepest excursion is reported apart."""
    playing: dict[int, Any] = {}
    other = []
    for topic, _, _, data in records:
        if topic.endswith("/" + m.STATE.name):
            s = m.RobotState.FromString(data)
            if s.played_index >= 0:
                playing.setdefault(s.tick, s.ee_pos)
            else:
                other.append(s.ee_pos)
    homing = outside_box(np.array(other).reshape(-1, 3), lo, hi)
    return outside_box(np.array(list(playing.values())).reshape(-1, 3), lo, hi) | {
        "hand_outside_box_not_playing_max_m": homing["hand_outside_box_max_m"]
    }


def outside_box(hands: np.ndarray, lo: list[float], hi: list[float]) -> dict[str, Any]:
    """The share of ``hands`` (N x 3) more than ``OUTSIDE_M`` outside the box, and the deepest."""
    beyond = np.maximum(np.asarray(lo) - hands, hands - np.asarray(hi)).max(axis=1, initial=0.0)
    return {
        "hand_outside_box_share": round(float(np.mean(beyond > OUTSIDE_M)), 4) if len(hands) else None,
        "hand_outside_box_max_m": round(float(beyond.max(initial=0.0)), 3),
    }


def _worst_window_hz(gaps: np.ndarray, window: int = 100) -> float | None:
    """The 5th percentile, over windows of ``window`` ticks, of the tick rate in each."""
    if len(gaps) < window:
        return None
    sums = np.convolve(gaps, np.ones(window), "valid")
    return round(float(np.percentile(window / sums, 5)), 2)


def run_file(out: Path, setting: str, variant: str, seed: int) -> Path:
    return out / setting / f"{variant}_s{seed}.json"


def other_runs(out: Path, steps: int, agent: dict[str, Any]) -> list[Path]:
    """The runs in ``out`` of another length than ``steps`` or with other ``--agent`` keys than ``agent``:
    one summary would mix them."""
    paths = sorted(out.glob("*/*.json"))
    return [
        p for p in paths if (r := json.loads(p.read_text()))["steps"] != steps or r.get("agent", {}) != agent
    ]


def agent_override(kv: str) -> tuple[str, Any]:
    """``KEY=VALUE`` (VALUE read as YAML) of ``--agent``."""
    key, sep, value = kv.partition("=")
    if not sep:
        raise SystemExit(f"--agent {kv!r}: expected KEY=VALUE")
    return key, yaml.safe_load(value)


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Per setting and variant: medians over seeds (and their ranges)."""
    rows = []
    for setting in SETTINGS:
        for variant in VARIANTS:
            group = [r for r in runs if r["setting"] == setting and r["variant"] == variant]
            if not group:
                continue
            rows.append(
                {
                    "setting": setting,
                    "variant": variant,
                    "seeds": sorted(r["seed"] for r in group),
                    "success_by_quarter": _median_lists([r["success_by_quarter"] for r in group]),
                    "last_quarter_range": [
                        min(r["success_by_quarter"][3] for r in group),
                        max(r["success_by_quarter"][3] for r in group),
                    ],
                    "steps_to_90pct_rolling": [r["steps_to_90pct_rolling"] for r in group],
                    "mean_H_by_quarter": _median_lists([r["mean_H_by_quarter"] for r in group]),
                    "H_first_500_steps": _median([r["H_first_500_steps"] for r in group]),
                    "workspace_clips": _median([r["workspace_clips"] for r in group]),
                    "reflexes": max(r["reflexes"] for r in group),
                    "control_hz_not_homing": _median([r["control_hz_not_homing"] for r in group]),
                    "homing_s": _median([r["homing_s"] for r in group]),
                }
            )
    comparisons = [
        c
        for setting in SETTINGS
        for against in ("fixed_h", "frozen")
        if (c := compare(runs, setting, "handoff", against)) is not None
    ]
    return {"command": "python bench/handoff.py", "rows": rows, "comparisons": comparisons, "runs": runs}


def compare(runs: list[dict[str, Any]], setting: str, variant: str, against: str) -> dict[str, Any] | None:
    """``variant`` against ``against`` on the seeds both ran: the difference of their success rates over the
    last quarter's episodes and over every episode after the handoff, pooled over those seeds, each with a
    95 % interval (experiments.stats.rate_diff). A quarter holds a few dozen episodes, so one episode more
    or less moves it by 3 points: the whole run says more about which start does better."""
    by = {(r["variant"], r["seed"]): r for r in runs if r["setting"] == setting and r["success_by_quarter"]}
    seeds = sorted(s for v, s in by if v == variant and (against, s) in by)
    if not seeds:
        return None

    def pooled(v: str, quarters: slice) -> tuple[int, int]:
        counts = [_successes(by[(v, s)], quarters) for s in seeds]
        return sum(c for c, _ in counts), sum(n for _, n in counts)

    return {
        "setting": setting,
        "variant": variant,
        "against": against,
        "seeds": seeds,
        "last_quarter": rate_diff(pooled(variant, slice(3, 4)), pooled(against, slice(3, 4))),
        "whole_run": rate_diff(pooled(variant, slice(0, 4)), pooled(against, slice(0, 4))),
    }


def _successes(run: dict[str, Any], quarters: slice) -> tuple[int, int]:
    """(successes, episodes) in ``quarters`` of a run; a quarter: ``episodes // 4`` episodes (learning())."""
    q = run["episodes"] // 4
    fractions = run["success_by_quarter"][quarters]
    return sum(round(f * q) for f in fractions), q * len(fractions)


def _median(values: list) -> float | None:
    values = [v for v in values if v is not None]
    return float(np.median(values)) if values else None


def _median_lists(lists: list) -> list | None:
    lists = [x for x in lists if x]
    if not lists:
        return None
    return [_median([x[i] for x in lists]) for i in range(len(lists[0]))]


def plot(summary: dict[str, Any], path: Path) -> None:
    """One panel per setting: success by quarter for each start (median over seeds)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    settings = [s for s in SETTINGS if any(r["setting"] == s for r in summary["rows"])]
    fig, axes = plt.subplots(
        1, len(settings), figsize=(max(6.0, min(15.0, 3.2 * len(settings))), 3.6), squeeze=False
    )
    for ax, setting in zip(axes[0], settings, strict=True):
        for r in (r for r in summary["rows"] if r["setting"] == setting):
            ys = [np.nan if y is None else 100 * y for y in r["success_by_quarter"]]
            ax.plot([1, 2, 3, 4], ys, marker="o", label=r["variant"], color=COLOURS[r["variant"]])
        ax.set(title=setting, xlabel="quarter of the run", ylim=(-5, 105), xticks=[1, 2, 3, 4])
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("success, % (median over seeds)")
    axes[0][0].legend(fontsize=8, loc="lower right")
    fig.suptitle("Success by quarter: from scratch vs handed off from the PyBullet policy", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--steps", type=int, default=6000)
    ap.add_argument(
        "--out",
        type=Path,
        default=OUT,
        help="where the runs go (a run there is not made again); the summary and figure go beside it as"
        " <out>.json and <out>.png; runs of another length or --agent there are named and refused",
    )
    ap.add_argument(
        "--agent",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="learner.agent keys (YAML values) over each setting's config, every variant; kept in each run",
    )
    args = ap.parse_args()
    agent = dict(agent_override(kv) for kv in args.agent)
    if mixed := other_runs(args.out, args.steps, agent):
        names = ", ".join(str(p.relative_to(args.out)) for p in mixed[:3]) + (
            ", ..." if len(mixed) > 3 else ""
        )
        print(
            f"{args.out} holds runs of another length than {args.steps} steps or other --agent keys"
            f" ({names}): use another --out"
        )
        return 2
    todo = [(s, v, seed) for s in args.settings for seed in args.seeds for v in args.variants]
    for n, (setting, variant, seed) in enumerate(todo, 1):
        out = run_file(args.out, setting, variant, seed)
        if out.exists() and not stale(json.loads(out.read_text())):
            continue
        fixed_h = None
        if variant == "fixed_h":
            path = run_file(args.out, setting, "handoff", seed)
            handoff = json.loads(path.read_text()) if path.exists() else None
            if handoff is None or stale(handoff):
                print(f"[{n}/{len(todo)}] {setting}/fixed_h s{seed}: needs the handoff run first; skipped")
                continue
            fixed_h = max(1, round(handoff["mean_H"]))
        print(f"[{n}/{len(todo)}] {setting} / {variant} / seed {seed}", flush=True)
        if compose_stack_yaml(ROOT / SETTINGS[setting])["robot"]["backend"] == "franka":
            from franka_simulators import FrankySimServer

            with FrankySimServer(FRANKY_HOST):
                run = run_one(setting, variant, seed, args.steps, fixed_h, agent)
        else:
            run = run_one(setting, variant, seed, args.steps, fixed_h, agent)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(run, indent=1))
        print(f"  -> success by quarter {run['success_by_quarter']}, mean H {run['mean_H']}", flush=True)
    runs = [json.loads(p.read_text()) for p in sorted(args.out.glob("*/*.json"))]
    runs = [r for r in runs if not stale(r)]
    summary = summarise(runs)
    args.out.with_suffix(".json").write_text(json.dumps(summary, indent=1))
    if summary["rows"]:
        plot(summary, args.out.with_suffix(".png"))
    print(results_tables.handoff(summary))
    print(results_tables.handoff_comparisons(summary))
    print("python scripts/results_tables.py puts it in the README")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
