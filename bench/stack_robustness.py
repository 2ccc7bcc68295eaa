"""Does the whole stack learn NS Reach when timing is unkind? (issue #32)

Each run is the main job (``adaptiveh up`` on ``configs/sim.yaml``: robot-io, the sim camera and vision,
the learner, the monitor, the recorder) for ``--steps`` steps (6000, the main job's budget) on one seed,
in one condition:

- ``quiet``: nothing else started by the bench;
- ``loaded``: two CPU-bound processes at normal priority beside the stack (started and stopped here);
- ``latency100`` / ``latency250`` / ``latency500``: ``learner.latency_ms`` (each plan published that late);
- ``slow_camera``: the sim camera at ``SLOW_CAMERA_HZ``;
- ``robot_io_restart``: quiet, robot-io SIGKILLed halfway; the row adds the seconds from the kill to the
  first action the new robot-io played for the learner.

Per run: success and final distance by quarter, mean H, retreats, safety events by kind (``workspace``
clips among them), the target's age when it reached this process (p50/p99: capture -> arrival) and
state -> chunk latency (a state's stamp to the next chunk's). The in-process learner (``NSReach-v0``) on
the same seeds is the reference. Runs are kept one per file under ``results/stack_robustness/`` and a
finished one is not run again (resumable); ``results/stack_robustness.json`` and ``.png`` (the shipped
stack; ``_history.png``: the other variants) summarise whatever has finished (``--replot``: only redraw
the figures from the JSON). One run at a time: they would load each other.

    python bench/stack_robustness.py [--seeds 0 1 2] [--conditions quiet loaded ...] [--steps 6000]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]
from loopback import free_endpoint, unique_name  # noqa: E402
from stack_bench import curve, latency, quarters, run_in_process  # noqa: E402

from bus import messages as m  # noqa: E402
from bus.signing import mac_key  # noqa: E402
from bus.transport import Bus, open_session, wait_listening  # noqa: E402
from deploy.config import compose_stack_yaml, load_stack_config, load_yaml  # noqa: E402
from deploy.stack import running_parts  # noqa: E402

OUT = ROOT / "results" / "stack_robustness"
GOAL = 0.70  # issue #32: last-quarter success in every run
SLOW_CAMERA_HZ = 5.0
CONDITIONS: dict[str, dict[str, Any]] = {
    "quiet": {},
    "loaded": {"load": 2},
    "latency100": {"latency_ms": 100.0},
    "latency250": {"latency_ms": 250.0},
    "latency500": {"latency_ms": 500.0},
    "slow_camera": {"camera_hz": SLOW_CAMERA_HZ},
    "robot_io_restart": {"kill_robot_io": True},
}

# The stack's agent against reach.yaml's (issue #35: does the stack need another agent than the task's?).
# Each is laid over configs/sim.yaml's composed agent; "" is the shipped one. reach_agent: reach.yaml's as
# it is (its kernel on the relative coordinates, its step and exploration schedules) with the plan
# retreat's tolerance kept; reach_agent_plan1: the same, the plan retreat at the policy's own kernel.
# learned_tolerance (issue #33): the shipped agent with the plan retreat's tolerance learned from the
# plan's own prediction error (learner/plan_tolerance.py) instead of the default noise floor.
# mean_limit: the shipped agent with the policy's mean bounded to the action box (a mean far past the
# box clips every sample to the same action, which then carries no gradient: the non-take-off's
# suspected trap at a wall). again: the shipped agent once more, to see whether a run repeats. ik_box: the
# shipped agent once more after robot-io's IK took the workspace box as a limit and its joint limits
# 1e-3 rad inside the command check's (the arm slides along a wall and is never pinned at a joint limit;
# docs/robot_interface.md), the other rows being from before.
# old_agent: the stack's agent before it took reach.yaml's (kernel 0.5 on the relative coordinates, no
# step or exploration schedules), kept for comparison. tiny_camera (issue #34): the shipped stack with
# the sim camera it had before, PyBullet's TinyRenderer at 320x240 and 15 Hz. own_kernel (issue #33): the
# shipped agent with the plan kernel the stack had before the default tolerance replaced it (0.083 on the
# relative coordinates, fixed). corrected_model (issue #33): the shipped agent with its plan model
# corrected online by the actor (``plan_model: corrected``, learner/plan_model.py). refactor (issue #46): the
# shipped agent after acting became one segment loop and one robot link (learner/acting.py,
# deploy/robot_link.py) and the learner took pooled arms' streams apart (#47), the rows before being older.
VARIANTS = (
    "",
    "old_agent",
    "reach_agent",
    "reach_agent_plan1",
    "learned_tolerance",
    "mean_limit",
    "again",
    "ik_box",
    "tiny_camera",
    "own_kernel",
    "corrected_model",
    "refactor",
)
TINY_CAMERA = {
    "rate_hz": 15.0,
    "intrinsics": {"width": 320, "height": 240, "fx": 307.5, "fy": 307.5, "cx": 159.5, "cy": 119.5},
}
ACTION_BOX_M = 0.05  # NS Reach's action bound per axis (robot.max_step_m)
OLD_AGENT = {"alpha_final": None, "sigma_final": None, "bandwidth": [5.0] * 12 + [0.5] * 3}
OWN_KERNEL = [1.0] * 12 + [0.083] * 3


def apply_variant(variant: str, base: dict[str, Any]) -> None:
    """Lay ``variant`` over the composed stack config ``base``: its agent, or its camera."""
    base["learner"]["agent"] = variant_agent(variant, base["learner"]["agent"])
    if variant == "tiny_camera":
        base["vision"].update(TINY_CAMERA)
        base["vision"]["sim"] = {**base["vision"].get("sim", {}), "renderer": "tiny"}


def variant_agent(variant: str, agent: dict[str, Any]) -> dict[str, Any]:
    if variant in ("", "again", "ik_box", "tiny_camera", "refactor"):
        return agent
    if variant == "own_kernel":
        return {**agent, "plan_kernel_scale": OWN_KERNEL, "plan_tolerance": "fixed"}
    if variant == "old_agent":
        return {**agent, **OLD_AGENT}
    if variant == "mean_limit":
        return {**agent, "mean_limit": ACTION_BOX_M}
    if variant == "learned_tolerance":
        return {**agent, "plan_tolerance": "learned"}
    if variant == "corrected_model":
        return {**agent, "plan_model": "corrected"}
    reach = {**load_yaml(ROOT / "configs/reach.yaml")["agent"], "retreat": None}
    if variant == "reach_agent":
        return {**reach, **{k: agent[k] for k in ("plan_kernel_scale", "plan_tolerance") if k in agent}}
    return {**reach, "plan_kernel_scale": 1.0, "plan_tolerance": "fixed"}


class Watcher:
    """The bench's own peer on the run's bus (with the stack's key: genuine messages only)."""

    def __init__(self, config: Path, token: str) -> None:
        cfg = load_stack_config(config)
        # A client of the supervisor's hub, never its listener: opened first, it would take the hub
        zc = cfg.zenoh.model_copy(update={"connect": (cfg.zenoh.hub,)})
        wait_listening(cfg.zenoh.hub)
        self.bus = Bus(open_session(zc), cfg.name, mac_key(token))
        self.lock = threading.Lock()
        self.states: list[tuple[float, int, str]] = []
        self.chunks: list[tuple[float, int]] = []
        self.target_age: list[float] = []
        self.played: list[tuple[float, str]] = []  # (arrival, robot-io instance) of ticks that played ours
        self.bus.subscribe(m.STATE, self._state)
        self.bus.subscribe(m.CMD_CHUNK, lambda c: self._add(self.chunks, (c.stamp, c.seq)))
        self.bus.subscribe(m.TARGET, self._target)

    def _add(self, where: list, item: Any) -> None:
        with self.lock:
            where.append(item)

    def _state(self, s: m.RobotState) -> None:
        with self.lock:
            self.states.append((s.stamp, s.chunk_seq, m.label(s, "mode")))
            if s.session and s.played_chunk >= 0:
                self.played.append((time.time(), s.instance))

    def _target(self, t: m.Target) -> None:
        if t.valid and t.frame_stamp > 0:
            self._add(self.target_age, time.time() - t.frame_stamp)


def _config(base: dict, tmp: Path, seed: int, steps: int, cond: dict[str, Any]) -> Path:
    cfg = json.loads(json.dumps(base))
    cfg["name"] = unique_name("rob")
    cfg["zenoh"] = {**cfg.get("zenoh", {}), "hub": free_endpoint()}
    cfg["robot"]["seed"] = seed
    cfg["learner"].update(
        steps=steps, seed=seed, checkpoint_dir=str(tmp / "learner"), latency_ms=cond.get("latency_ms", 0.0)
    )
    if "camera_hz" in cond:
        cfg["vision"]["rate_hz"] = cond["camera_hz"]
    cfg["monitor"].update(port=0, foxglove_port=None)
    cfg["recording"]["dir"] = str(tmp / "rec")
    path = tmp / "stack.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def _burners(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def _kill_robot_io_halfway(path: Path, watcher: Watcher, steps: int, up: subprocess.Popen) -> dict[str, Any]:
    """SIGKILL robot-io once the learner is halfway; seconds until the new one plays the learner's chunk."""
    half = steps // 2
    while up.poll() is None:
        with watcher.lock:
            n = len(watcher.played)
        if n >= half:
            break
        time.sleep(0.5)
    pid = running_parts(path).get("robot-io")
    if pid is None:
        return {"killed": False}
    with watcher.lock:
        old = {inst for _, inst in watcher.played[-20:]}
    t_kill = time.time()
    os.kill(pid, signal.SIGKILL)
    while up.poll() is None and time.time() - t_kill < 120:
        with watcher.lock:
            new = [t for t, inst in watcher.played if t > t_kill and inst not in old]
        if new:
            return {"killed": True, "resumed_after_s": new[0] - t_kill}
        time.sleep(0.1)
    return {"killed": True, "resumed_after_s": None}


def run_one(base: dict, condition: str, seed: int, steps: int) -> dict[str, Any]:
    cond = CONDITIONS[condition]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        path = _config(base, tmp, seed, steps, cond)
        burners = _burners(cond.get("load", 0))
        summary_path = tmp / "summary.json"
        t0 = time.time()
        errors = (tmp / "up.stderr").open("w")
        up = subprocess.Popen(
            [sys.executable, "-m", "deploy.cli", "up", str(path), "--summary", str(summary_path)],
            stdout=subprocess.PIPE,
            stderr=errors,
            text=True,
        )
        watcher: Watcher | None = None
        try:
            token = up.stdout.readline().strip().removeprefix("operator token: ")
            watcher = Watcher(path, token)
            restart = _kill_robot_io_halfway(path, watcher, steps, up) if cond.get("kill_robot_io") else None
            progress = threading.Thread(target=_echo, args=(up, condition, seed), daemon=True)
            progress.start()
            up.wait(timeout=steps * 0.5 + 600)
            progress.join(timeout=5)
        finally:
            for p in burners:
                p.kill()
            if up.poll() is None:
                up.kill()
            errors.close()
            if watcher is not None and not summary_path.exists():
                watcher.bus.close()  # its Zenoh threads would keep this process from exiting
        if not summary_path.exists():
            tail = (tmp / "up.stderr").read_text()[-3000:]
            raise RuntimeError(
                f"{condition} seed {seed}: adaptiveh up exited {up.returncode} without a summary:\n{tail}"
            )
        summary = json.loads(summary_path.read_text())
        result = json.loads((tmp / "learner" / "result.json").read_text())
        actor_file = tmp / "learner" / "actor.json"  # execution: actor (what the actor beside the arm did)
        actor = json.loads(actor_file.read_text()) if actor_file.exists() else None
        with watcher.lock:
            states, chunks, ages = list(watcher.states), list(watcher.chunks), list(watcher.target_age)
        watcher.bus.close()
    c = curve(result["episodes"])
    segments = result["segments"]
    out = {
        "condition": condition,
        "seed": seed,
        "steps": summary["global_step"],
        "wall_clock_s": time.time() - t0,
        "success_by_quarter": quarters([{**e, "success": float(bool(e["success"]))} for e in c], "success"),
        "final_distance_by_quarter": quarters(c, "final_distance"),
        "mean_H": float(np.mean([s["H"] for s in segments])) if segments else None,
        "segments": len(segments),
        "retreats": sum(s["reason"] == "retreat" for s in segments),
        "safety_events": summary["safety_events"],
        "workspace_clips": summary["safety_events"].get("workspace", 0),
        "target_age_ms": _pcts(ages),
        "state_to_chunk_ms": latency(states, chunks),
        "restarts": summary["restarts"],
        "load_during": os.getloadavg(),
        "actor": actor,
    }
    if restart is not None:
        out["robot_io_restart"] = restart
    return out


def _echo(up: subprocess.Popen, condition: str, seed: int) -> None:
    for line in up.stdout:
        if line.startswith("["):
            print(f"  {condition} seed {seed}: {line.strip()}", flush=True)


def _pcts(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    a = 1e3 * np.asarray(values)
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "n": len(a)}


def reference(base: dict, seed: int, steps: int) -> dict[str, Any]:
    cfg = json.loads(json.dumps(base))
    cfg["learner"]["seed"] = seed
    cfg["robot"]["seed"] = seed
    with tempfile.TemporaryDirectory() as d:
        res = run_in_process(cfg, steps, Path(d))
    c = res["curve"]
    return {
        "condition": "in_process",
        "seed": seed,
        "success_by_quarter": quarters([{**e, "success": float(bool(e["success"]))} for e in c], "success"),
        "final_distance_by_quarter": quarters(c, "final_distance"),
        "retreats": res["retreats"],
        "segments": res["segments"],
        "mean_H": res["mean_H"],
        "wall_clock_s": res["wall_clock_s"],
    }


def label(run: dict[str, Any]) -> str:
    """A run's row: its condition, after its agent variant when it is not the shipped agent."""
    return f"{run['variant']}/{run['condition']}" if run.get("variant") else run["condition"]


def _labels(runs: list[dict[str, Any]]) -> list[str]:
    order = [f"{v}/{c}" if v else c for v in VARIANTS for c in [*CONDITIONS, "in_process"]]
    return [x for x in order if any(label(r) == x for r in runs)]


def table(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Per condition: last-quarter success median and range over seeds, and the non-take-offs."""
    out: dict[str, Any] = {}
    for cond in _labels(runs):
        rows = [r for r in runs if label(r) == cond]
        if not rows:
            continue
        last = [r["success_by_quarter"][-1] for r in rows if r["success_by_quarter"][-1] is not None]
        out[cond] = {
            "seeds": sorted(r["seed"] for r in rows),
            "last_quarter_success_median": float(np.median(last)) if last else None,
            "last_quarter_success_range": [min(last), max(last)] if last else None,
            "non_take_offs": sum(x == 0 for x in last),
            "workspace_clips_median": float(np.median([r.get("workspace_clips", 0) for r in rows])),
            "resumed_after_s": [
                r["robot_io_restart"].get("resumed_after_s") for r in rows if "robot_io_restart" in r
            ],
        }
    return out


def plot(runs: list[dict[str, Any]], path: Path) -> None:
    """``path``: the shipped stack, one panel per condition; ``<stem>_history.png`` beside it when other
    variants ran: one panel per variant against the shipped stack (each at most 1600 px wide)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    order = [*CONDITIONS, "in_process"]
    shipped = [r for r in runs if not r.get("variant")]
    conds = [c for c in order if any(r["condition"] == c for r in shipped)]
    cols = max(1, min(4, len(conds)))
    rows = max(1, -(-len(conds) // cols))
    fig, axes = plt.subplots(
        rows, cols, figsize=(3.6 * cols, 2.8 * rows + 0.8), sharex=True, sharey=True, squeeze=False
    )
    for ax, cond in zip(axes.flat, conds, strict=False):
        for r in sorted((r for r in shipped if r["condition"] == cond), key=lambda r: r["seed"]):
            q = [np.nan if x is None else 100 * x for x in r["success_by_quarter"]]
            ax.plot(range(1, 5), q, "o-", ms=3, lw=1, color=f"C{r['seed'] % 10}", label=f"seed {r['seed']}")
        ax.set_title("in_process (reference)" if cond == "in_process" else cond, fontsize=10)
    for ax in axes.flat:
        ax.axhline(100 * GOAL, color="g", ls="--", lw=1, label=f"goal: last quarter >= {100 * GOAL:.0f} %")
        ax.set(xticks=range(1, 5), ylim=(-5, 105))
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(conds) :]:
        ax.axis("off")
    for ax in axes[:, 0]:
        ax.set_ylabel("success, %")
    for ax in axes[-1]:
        ax.set_xlabel("quarter of the run")
    _figure_legend(fig, axes)
    fig.suptitle("NS Reach over the shipped stack (configs/sim.yaml): success by quarter, one line per seed")
    _save(fig, path)

    variants = [v for v in VARIANTS if v and any(r.get("variant") == v for r in runs)]
    if not variants:
        return
    cols = min(3, len(variants))
    rows = -(-len(variants) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.8 * cols, 3.3 * rows + 0.8), sharey=True, squeeze=False)
    for ax, variant in zip(axes.flat, variants, strict=False):
        mine = [r for r in runs if r.get("variant") == variant]
        vconds = [c for c in order if any(r["condition"] == c for r in mine)]
        for i, cond in enumerate(vconds):
            last = _last_quarter([r for r in mine if r["condition"] == cond])
            ax.plot(
                i + (np.linspace(-0.12, 0.12, len(last)) if len(last) > 1 else 0.0),
                last,
                "o",
                ms=4,
                color="tab:blue",
                alpha=0.8,
                zorder=3,
                label="this variant, one dot per seed",
            )
            ref = _last_quarter([r for r in shipped if r["condition"] == cond])
            if ref:
                ax.plot(i, np.median(ref), "_", ms=20, mew=2, color="black", label="shipped stack, median")
        ax.axhline(100 * GOAL, color="g", ls="--", lw=1, label=f"goal: last quarter >= {100 * GOAL:.0f} %")
        ax.set_xticks(range(len(vconds)), vconds, rotation=30, ha="right", fontsize=8)
        ax.set(xlim=(-0.6, len(vconds) - 0.4), ylim=(-5, 105), title=variant)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(variants) :]:
        ax.axis("off")
    for ax in axes[:, 0]:
        ax.set_ylabel("last-quarter success, %")
    _figure_legend(fig, axes)
    fig.suptitle(
        "Other agents and cameras (kept for comparison): last-quarter success against the shipped stack"
    )
    _save(fig, path.with_name(f"{path.stem}_history.png"))


def _last_quarter(runs: list[dict[str, Any]]) -> list[float]:
    return [100 * r["success_by_quarter"][-1] for r in runs if r["success_by_quarter"][-1] is not None]


def _figure_legend(fig: Any, axes: Any) -> None:
    """One legend under the panels: every label once."""
    seen: dict[str, Any] = {}
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            seen.setdefault(lab, h)
    labels = sorted(seen, key=lambda lab: (not lab.startswith("seed"), lab))
    fig.legend([seen[lab] for lab in labels], labels, loc="lower center", ncol=len(labels), fontsize=8)


def _save(fig: Any, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig.tight_layout(rect=(0, 0.05, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--conditions", nargs="+", default=list(CONDITIONS), choices=list(CONDITIONS))
    ap.add_argument("--steps", type=int, default=6000)
    ap.add_argument("--no-reference", action="store_true", help="skip the in-process runs")
    ap.add_argument("--summarize", action="store_true", help="run nothing: rewrite the summary from the runs")
    ap.add_argument(
        "--variant",
        default="",
        choices=VARIANTS,
        help="an agent or camera variant (default: configs/sim.yaml as shipped)",
    )
    ap.add_argument(
        "--replot", action="store_true", help="run nothing: redraw the figures from the summary JSON"
    )
    args = ap.parse_args()
    os.chdir(ROOT)
    if args.replot:
        summary = json.loads((ROOT / "results" / "stack_robustness.json").read_text())
        plot(summary["runs"], ROOT / "results" / "stack_robustness.png")
        print("wrote results/stack_robustness.png (and _history.png)")
        return 0
    base = compose_stack_yaml(ROOT / "configs/sim.yaml")
    apply_variant(args.variant, base)
    prefix = f"{args.variant}-" if args.variant else ""
    OUT.mkdir(parents=True, exist_ok=True)
    todo = [] if args.summarize else [(c, s) for s in args.seeds for c in args.conditions]
    if not args.no_reference and not args.summarize:
        todo += [("in_process", s) for s in args.seeds]
    for i, (cond, seed) in enumerate(todo, 1):
        file = OUT / f"{prefix}{cond}_s{seed}_{args.steps}.json"
        if file.exists():
            print(f"[{i}/{len(todo)}] {cond} seed {seed}: done earlier ({file.name})")
            continue
        print(f"[{i}/{len(todo)}] {cond} seed {seed}: running", flush=True)
        run = (
            reference(base, seed, args.steps)
            if cond == "in_process"
            else run_one(base, cond, seed, args.steps)
        )
        run.update(commit=_commit(), machine={"cpus": os.cpu_count(), "python": platform.python_version()})
        run.update(variant=args.variant, agent=base["learner"]["agent"])
        file.write_text(json.dumps(run, indent=1, default=float))
        print(f"  success by quarter {run['success_by_quarter']}", flush=True)
    runs = [json.loads(p.read_text()) for p in sorted(OUT.glob(f"*_{args.steps}.json"))]
    summary = {"steps": args.steps, "table": table(runs), "runs": runs}
    (ROOT / "results" / "stack_robustness.json").write_text(json.dumps(summary, indent=1, default=float))
    plot(runs, ROOT / "results" / "stack_robustness.png")
    for cond, row in summary["table"].items():
        print(f"{cond:18s} {row}")
    return 0


def _commit() -> str:
    out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT)
    dirty = subprocess.run(["git", "status", "--porcelain"], capture_output=True, text=True, cwd=ROOT).stdout
    # The bench's own output (results/) does not make the code dirty.
    return out.stdout.strip() + ("+dirty" if re.search(r"^ ?M (?!results/)", dirty, re.M) else "")


if __name__ == "__main__":
    sys.exit(main())
