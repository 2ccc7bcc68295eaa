"""Several arms, one learner: does pooling keep sample efficiency and save time? (issue #47)

Each run is ``adaptiveh up`` on ``configs/fleet.yaml`` with N simulated arms (PyBullet, no cameras: on
two cores a rendered camera per arm would starve the arms; no monitor, no recording, the same for every
N) learning NS Reach for ``--steps`` steps of all arms together, on one seed (the learner's; arm i's
target motion and exploration take seed 100 s + i). Per run: total steps and wall-clock (from the start
of ``adaptiveh up``) until the pooled rolling success over 20 episodes first reaches 70 %; the last
quarter's success per arm; the learner's transitions per second; each arm's control rate and CPU
(robot-io + actor, from /proc, in cores).

Fault runs, two arms, seed 0:
- ``learner_outage``: the learner SIGKILLed a third in, the supervisor brings it back 10 s later
  (``supervisor.backoff_s``): transitions lost (per-arm sequence numbers: each stream learned in order,
  without a gap, the sum equal to the learner's steps), seconds from the new learner's start to its first
  step learned;
- ``arm_killed``: the learner, arm0 and arm1 each under their own supervisor (``--arms``), as on three
  machines; arm1's supervisor and parts SIGKILLed half-way (a machine that loses power): arm0's
  last-quarter success beside the same seed's two-arm run;
- ``arm_added``: arm0 and arm1 from the start, arm2 started a third in: seconds from its robot-io's first
  state to its first plan, and whether that plan came from the newest snapshot.

Runs are kept one per file under ``results/fleet/`` and a finished one is not run again (resumable);
``results/fleet.json`` and ``results/fleet.png`` summarise whatever has finished (``--replot``: only
those). One run at a time: they would load each other.

    python bench/fleet.py [--arms 1 2 4] [--seeds 0 1 2] [--steps 6000] [--faults] [--replot]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
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
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
from loopback import free_endpoint, unique_name  # noqa: E402

from bus import messages as m  # noqa: E402
from bus.signing import mac_key  # noqa: E402
from bus.transport import Bus, ZenohConfig, open_session  # noqa: E402
from common.proc_status import cpu_seconds  # noqa: E402
from deploy.config import compose_stack_yaml  # noqa: E402
from deploy.stack import running_parts  # noqa: E402

OUT = ROOT / "results" / "fleet"
TOKEN = "fleet-bench-token"
WINDOW, GOAL = 20, 0.70  # rolling success over this many episodes; the level "learned" means
FAULTS = ("learner_outage", "arm_killed", "arm_added")
OUTAGE_S = 10.0
ADDED = ("first_plan_after_robot_io_s", "first_plan_after_start_s", "newest_snapshot_when_started")


def fleet_config(directory: Path, arms: int, seed: int, steps: int) -> dict[str, Any]:
    cfg = compose_stack_yaml(ROOT / "configs" / "fleet.yaml")
    cfg["name"] = unique_name("fleetbench")
    cfg["zenoh"]["hub"] = free_endpoint()
    cfg["monitor"] = None
    cfg["recording"]["enabled"] = False
    cfg["learner"].update(steps=steps, seed=seed, checkpoint_dir=str(directory / "learner"))
    cfg["fleet"] = {"arms": [{"name": f"arm{i}", "seed": 100 * seed + i} for i in range(arms)]}
    return cfg


class Watch:
    """The bench's peer: the learner's steps over time, and each arm's first state and first plan."""

    def __init__(self, cfg: dict[str, Any], arms: list[str]) -> None:
        self.bus = Bus(open_session(ZenohConfig(connect=(cfg["zenoh"]["hub"],))), cfg["name"], mac_key(TOKEN))
        self.lock = threading.Lock()
        self.steps: list[tuple[float, int]] = []  # (monotonic, learner's global step)
        self.snapshots: list[tuple[float, int]] = []
        self.first_state: dict[str, float] = {}
        self.first_chunk: dict[str, float] = {}
        self.first_version: dict[str, int] = {}
        self.bus.subscribe(m.TELEMETRY_LEARNER, self._on_telemetry)
        self.bus.subscribe(m.POLICY, lambda s: self._note(self.snapshots, s.version))
        self.bus.subscribe(m.TRANSITIONS, self._on_transition)
        for arm in arms:
            self.bus.subscribe(m.STATE, lambda _s, a=arm: self._first(self.first_state, a), arm=arm)
            self.bus.subscribe(m.CMD_CHUNK, lambda _c, a=arm: self._first(self.first_chunk, a), arm=arm)

    def _note(self, series: list, value: int) -> None:
        with self.lock:
            series.append((time.monotonic(), value))

    def _first(self, seen: dict[str, float], arm: str) -> None:
        with self.lock:
            seen.setdefault(arm, time.monotonic())

    def _on_telemetry(self, t: m.LearnerTelemetry) -> None:
        self._note(self.steps, t.global_step)

    def _on_transition(self, t: m.Transition) -> None:
        with self.lock:
            self.first_version.setdefault(t.arm, t.policy_version)

    def step_now(self) -> int:
        with self.lock:
            return self.steps[-1][1] if self.steps else 0

    def close(self) -> None:
        self.bus.close()


class CpuMeter:
    """CPU seconds of each part of a config's processes (summed over restarts), sampled every second."""

    def __init__(self, config: Path) -> None:
        self.config = config
        self.by_pid: dict[int, tuple[str, float]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.wait(1.0):
            for part, pid in running_parts(self.config).items():
                cpu = cpu_seconds(pid)
                if cpu is not None:
                    self.by_pid[pid] = (part, cpu)

    def stop(self) -> dict[str, float]:
        self._stop.set()
        self._thread.join()
        out: dict[str, float] = {}
        for part, cpu in self.by_pid.values():
            out[part] = out.get(part, 0.0) + cpu
        return out


def _up(config: Path, *args: str) -> subprocess.Popen:
    token = config.parent / "token"
    if not token.exists():
        token.write_text(TOKEN)
        token.chmod(0o600)
    return subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "up", str(config), "--token-file", str(token), *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        cwd=ROOT,
    )


def _stop(proc: subprocess.Popen, timeout: float = 60) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()


def _wait_step(watch: Watch, step: int, learner: subprocess.Popen, what: str) -> None:
    last = time.monotonic()
    while watch.step_now() < step:
        if learner.poll() is not None:
            raise RuntimeError(f"the learner's supervisor ended before {what} (step {watch.step_now()})")
        if time.monotonic() - last > 15:
            print(f"    … step {watch.step_now()}, waiting for {step} ({what})", flush=True)
            last = time.monotonic()
        time.sleep(0.2)


def run(kind: str, arms: int, seed: int, steps: int) -> dict[str, Any]:
    """One run of ``kind`` (``pooled`` or a fault); the record."""
    with tempfile.TemporaryDirectory(prefix="fleetbench-") as tmp:
        directory = Path(tmp)
        cfg = fleet_config(directory, arms + (kind == "arm_added"), seed, steps)
        if kind == "learner_outage":
            cfg["supervisor"] = {"backoff_s": OUTAGE_S, "max_restarts": 1}
        config = directory / "fleet.yaml"
        config.write_text(yaml.safe_dump(cfg))
        names = [a["name"] for a in cfg["fleet"]["arms"]]
        t0 = time.monotonic()
        procs = _start(kind, config, names)
        watch = Watch(cfg, names)
        meter = CpuMeter(config)
        try:
            extra = _fault(kind, config, watch, procs, names, steps)
            if procs["learner"].wait(timeout=steps / 5 + 600) != 0:
                raise RuntimeError(f"adaptiveh up ended with {procs['learner'].returncode}")
            wall = time.monotonic() - t0
        finally:
            for proc in procs.values():
                _stop(proc)
            cpu = meter.stop()
            watch.close()
        ckpt = directory / "learner"
        result = json.loads((ckpt / "result.json").read_text())
        actors = {n: _read(ckpt / f"actor-{n}.json") for n in names}
        return _record(kind, arms, seed, steps, wall, t0, watch, cpu, result, actors, extra)


def _start(kind: str, config: Path, names: list[str]) -> dict[str, subprocess.Popen]:
    """``adaptiveh up`` as the run needs it: one supervisor, or the learner's and the arms' apart."""
    if kind in ("pooled", "learner_outage"):
        return {"learner": _up(config)}
    procs = {"learner": _up(config, "--arms", "none")}
    time.sleep(2.0)  # the learner's supervisor owns the hub the arms join
    if kind == "arm_killed":
        procs.update({n: _up(config, "--arms", n) for n in names})
    else:  # arm_added: the last arm comes later
        procs["first"] = _up(config, "--arms", ",".join(names[:-1]))
    return procs


def _fault(
    kind: str, config: Path, watch: Watch, procs: dict[str, subprocess.Popen], names: list[str], steps: int
) -> dict[str, Any]:
    if kind == "learner_outage":
        _wait_step(watch, steps // 3, procs["learner"], "the kill")
        killed = running_parts(config)["learn"]
        os.kill(killed, signal.SIGKILL)
        t_kill = time.monotonic()
        while running_parts(config).get("learn") in (None, killed):
            time.sleep(0.05)
        t_back = time.monotonic()
        with watch.lock:
            before = len(watch.steps)
        while True:
            with watch.lock:
                if len(watch.steps) > before and watch.steps[-1][0] > t_back:
                    t_learning = watch.steps[-1][0]
                    break
            time.sleep(0.05)
        return {"outage_s": t_back - t_kill, "learning_again_s": t_learning - t_back}
    if kind == "arm_killed":  # as a machine that loses power: its supervisor and parts SIGKILLed at once
        _wait_step(watch, steps // 2, procs["learner"], "killing arm1")
        parts = running_parts(config)
        for pid in [procs.pop("arm1").pid, parts["robot-io@arm1"], parts["act@arm1"]]:
            os.kill(pid, signal.SIGKILL)
        return {"arm1_killed_at_step": watch.step_now()}
    if kind == "arm_added":
        _wait_step(watch, steps // 3, procs["learner"], "adding an arm")
        newest = max((v for _, v in watch.snapshots), default=-1)
        procs[names[-1]] = _up(config, "--arms", names[-1])
        t_add = time.monotonic()
        while names[-1] not in watch.first_chunk and time.monotonic() - t_add < 120:
            time.sleep(0.05)
        with watch.lock:
            state, chunk = watch.first_state.get(names[-1]), watch.first_chunk.get(names[-1])
        time.sleep(1.0)
        return {
            "added_at_step": watch.step_now(),
            "first_plan_after_robot_io_s": None if state is None or chunk is None else chunk - state,
            "first_plan_after_start_s": None if chunk is None else chunk - t_add,  # processes' start-up too
            "newest_snapshot_when_started": newest,
            "first_transition_policy_version": watch.first_version.get(names[-1]),
        }
    return {}


def _read(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text()) if path.exists() else {}


def rolling_goal(episodes: list[dict[str, Any]]) -> int | None:
    """The learner's step at the episode where the pooled success over the last ``WINDOW`` first reaches
    ``GOAL`` (None: never)."""
    success = np.array([bool(e.get("success")) for e in episodes], float)
    for i in range(WINDOW - 1, len(success)):
        if success[i - WINDOW + 1 : i + 1].mean() >= GOAL:
            return int(episodes[i]["global_step"])
    return None


def wall_at(step: int | None, series: list[tuple[float, int]], t0: float) -> float | None:
    """Seconds from ``t0`` until the learner's telemetry first showed ``step``."""
    if step is None:
        return None
    return next((t - t0 for t, s in series if s >= step), None)


def last_quarter(episodes: list[dict[str, Any]]) -> float | None:
    if len(episodes) < 4:
        return None
    tail = episodes[-(len(episodes) // 4) :]
    return float(np.mean([bool(e.get("success")) for e in tail]))


def _record(
    kind: str,
    arms: int,
    seed: int,
    steps: int,
    wall: float,
    t0: float,
    watch: Watch,
    cpu: dict[str, float],
    result: dict[str, Any],
    actors: dict[str, dict[str, Any]],
    extra: dict[str, Any],
) -> dict[str, Any]:
    episodes = result.get("episodes", [])
    goal_step = rolling_goal(episodes)
    per_arm = {}
    for name, actor in actors.items():
        own = [e for e in episodes if e.get("arm") == name]
        part_cpu = cpu.get(f"robot-io@{name}", 0.0) + cpu.get(f"act@{name}", 0.0)
        per_arm[name] = {
            "episodes": len(own),
            "last_quarter_success": last_quarter(own),
            "steps": actor.get("steps"),
            "steps_per_s": (actor.get("steps") or 0) / wall,  # start-up included
            "cpu_cores": part_cpu / wall,
            "transitions_lost": actor.get("transitions_lost"),
            "retreats": actor.get("retreats"),
            "segments": actor.get("segments"),
        }
    learned = result.get("transitions_learned", {})
    return {
        "kind": kind,
        "arms": arms,
        "seed": seed,
        "steps": steps,
        "wall_s": wall,
        "steps_to_goal": goal_step,
        "wall_to_goal_s": wall_at(goal_step, watch.steps, t0),
        "last_quarter_success": last_quarter(episodes),
        "per_arm": per_arm,
        "learner_transitions_per_s": result.get("steps_this_session", 0)
        / max(result.get("wall_clock_s", 1), 1e-9),
        "learner_cpu_cores": cpu.get("learn", 0.0) / wall,
        "cpu_by_part": {k: v / wall for k, v in cpu.items()},
        "transitions_learned_sum": sum(learned.values()),
        "global_step": result.get("global_step"),
        "transitions_lost": result.get("transitions_lost"),
        "curve": [(e["global_step"], bool(e.get("success")), e.get("arm", "")) for e in episodes],
        "telemetry": [(round(t - t0, 2), s) for t, s in watch.steps[:: max(1, len(watch.steps) // 400)]],
        **extra,
    }


def runs_wanted(args: argparse.Namespace) -> list[tuple[str, int, int]]:
    wanted = [("pooled", n, s) for n in args.arms for s in args.seeds]
    if args.faults:
        wanted += [(kind, 2, 0) for kind in FAULTS]
    return wanted


def path_of(kind: str, arms: int, seed: int, steps: int) -> Path:
    return OUT / f"{kind}_n{arms}_s{seed}_{steps}.json"


def summarise(steps: int) -> dict[str, Any]:
    records = [json.loads(p.read_text()) for p in sorted(OUT.glob(f"*_{steps}.json"))]
    pooled = [r for r in records if r["kind"] == "pooled"]
    by_n: dict[int, list[dict[str, Any]]] = {}
    for r in pooled:
        by_n.setdefault(r["arms"], []).append(r)
    rows = {n: _row(rs) for n, rs in sorted(by_n.items())}
    faults = {r["kind"]: _fault_row(r, by_n.get(2, [])) for r in records if r["kind"] != "pooled"}
    return {
        "what": __doc__.split("\n\n")[0],
        "command": "python bench/fleet.py --arms 1 2 4 --seeds 0 1 2 --faults",
        "machine": {
            "cores": os.cpu_count(),
            "python": platform.python_version(),
            "cpu": platform.processor(),
        },
        "cameras": "off for every N (vision: null; each arm's actor reads sim/target_truth)",
        "steps": steps,
        "by_arms": rows,
        "goals": _goals(rows, faults),
        "faults": faults,
    }


def _mean(values: list[float | None]) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


def _row(rs: list[dict[str, Any]]) -> dict[str, Any]:
    arms = [a for r in rs for a in r["per_arm"].values()]
    return {
        "seeds": [r["seed"] for r in rs],
        "steps_to_goal": [r["steps_to_goal"] for r in rs],
        "wall_to_goal_s": [r["wall_to_goal_s"] for r in rs],
        "mean_steps_to_goal": _mean([r["steps_to_goal"] for r in rs]),
        "mean_wall_to_goal_s": _mean([r["wall_to_goal_s"] for r in rs]),
        "reached_goal": sum(r["steps_to_goal"] is not None for r in rs),
        "last_quarter_success_per_arm": [
            [a["last_quarter_success"] for a in r["per_arm"].values()] for r in rs
        ],
        "learner_transitions_per_s": _mean([r["learner_transitions_per_s"] for r in rs]),
        "learner_cpu_cores": _mean([r["learner_cpu_cores"] for r in rs]),
        "steps_per_s_per_arm": _mean([a["steps_per_s"] for a in arms]),
        "cpu_cores_per_arm": _mean([a["cpu_cores"] for a in arms]),
        "max_cpu_cores_per_arm": max((a["cpu_cores"] for a in arms), default=None),
        "wall_s": _mean([r["wall_s"] for r in rs]),
    }


def _fault_row(r: dict[str, Any], two_arms: list[dict[str, Any]]) -> dict[str, Any]:
    out = {k: r.get(k) for k in ("outage_s", "learning_again_s", "arm1_killed_at_step", "added_at_step")}
    out.update(
        {k: r.get(k) for k in ADDED},
        first_transition_policy_version=r.get("first_transition_policy_version"),
        transitions_lost=r.get("transitions_lost"),
        actors_lost=sum((a.get("transitions_lost") or 0) for a in r["per_arm"].values()),
        learned_in_order_equals_steps=r["transitions_learned_sum"] == r["global_step"],
        last_quarter_success_per_arm={n: a["last_quarter_success"] for n, a in r["per_arm"].items()},
    )
    same_seed = [x for x in two_arms if x["seed"] == r["seed"]]
    if r["kind"] == "arm_killed" and same_seed:
        out["arm0_last_quarter_without_the_kill"] = same_seed[0]["per_arm"]["arm0"]["last_quarter_success"]
    return {k: v for k, v in out.items() if v is not None}


def _at_most(value: float | None, bar: str) -> dict[str, Any]:
    """A goal met when ``value`` is at most ``bar`` (as the issue writes it)."""
    return {"value": value, "goal": f"<= {bar}", "met": value is not None and value <= float(bar)}


def _goals(rows: dict[int, dict[str, Any]], faults: dict[str, dict[str, Any]]) -> dict[str, Any]:
    one = rows.get(1, {})
    goals: dict[str, Any] = {}
    for n in (2, 4):
        if n in rows and one.get("mean_steps_to_goal") and rows[n]["mean_steps_to_goal"]:
            ratio = rows[n]["mean_steps_to_goal"] / one["mean_steps_to_goal"]
            goals[f"steps_to_goal_ratio_n{n}"] = _at_most(ratio, "1.25")
    if 2 in rows and one.get("mean_wall_to_goal_s") and rows[2]["mean_wall_to_goal_s"]:
        goals["wall_to_goal_ratio_n2"] = _at_most(
            rows[2]["mean_wall_to_goal_s"] / one["mean_wall_to_goal_s"], "0.65"
        )
    cpu = [r["max_cpu_cores_per_arm"] for r in rows.values() if r["max_cpu_cores_per_arm"] is not None]
    if cpu:
        goals["cpu_cores_per_arm_max"] = _at_most(max(cpu), "0.35")
    goals.update(_ingest_goals())
    outage = faults.get("learner_outage")
    if outage:
        ok = outage["transitions_lost"] == 0 and outage["actors_lost"] == 0
        goals["outage_lost"] = {"value": outage["transitions_lost"], "goal": "0", "met": ok}
        goals["outage_learning_again_s"] = _at_most(outage.get("learning_again_s"), "5")
    killed = faults.get("arm_killed")
    if killed and "arm0_last_quarter_without_the_kill" in killed:
        with_kill = killed["last_quarter_success_per_arm"]["arm0"]
        gap = abs(with_kill - killed["arm0_last_quarter_without_the_kill"]) if with_kill is not None else None
        goals["arm_killed_other_within_10_points"] = _at_most(gap, "0.10")
    added = faults.get("arm_added")
    if added:
        goals["arm_added_first_plan_s"] = _at_most(added.get("first_plan_after_robot_io_s"), "2")
    return goals


def _ingest_goals() -> dict[str, Any]:
    """The learner's ceiling at budgets 1000 and 100 (``bench/learner_ingest.py``'s newest run, the feeder
    bench: no Zenoh, no arms), against the fleet's needs: 20 arms at 20 Hz, and 2,000 at budget 100."""
    path = ROOT / "results" / "learner_ingest.json"
    if not path.exists():
        return {}
    rows = json.loads(path.read_text())["runs"]["after"]["rows"]
    return {
        f"learner_ingest_per_s_budget_{r['budget']}": {
            "value": r["transitions_per_s"],
            "goal": f">= {r['goal_per_s']:.0f}",
            "met": r["goal_met"],
            "us_per_transition": r["us_per_transition"],
            "arithmetic_us": r["arithmetic"]["us_total"],
        }
        for r in rows
        if r["budget"] in (100, 1000)
    }


def plot(summary: dict[str, Any], steps: int) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    records = [json.loads(p.read_text()) for p in sorted(OUT.glob(f"pooled_*_{steps}.json"))]
    fig, (a, b, c) = plt.subplots(1, 3, figsize=(15, 4.2))
    colours = {1: "tab:blue", 2: "tab:orange", 4: "tab:green"}
    for r in records:
        curve = r["curve"]
        if len(curve) < WINDOW:
            continue
        success = np.array([s for _, s, _ in curve], float)
        rolling = np.convolve(success, np.ones(WINDOW) / WINDOW, "valid") * 100
        x = np.array([g for g, _, _ in curve])[WINDOW - 1 :]
        label = f"{r['arms']} arm{'s' if r['arms'] > 1 else ''}" if r["seed"] == 0 else None
        colour = colours.get(r["arms"], "grey")
        a.plot(x, rolling, color=colour, alpha=0.8, lw=1.2, label=label)
        tel = np.array(r["telemetry"], float)
        if len(tel):
            b.plot(np.interp(x, tel[:, 1], tel[:, 0]), rolling, color=colour, alpha=0.8, lw=1.2, label=label)
    for ax in (a, b):
        ax.axhline(100 * GOAL, color="k", lw=0.8, ls="--")
        ax.set(ylabel=f"success, rolling {WINDOW} episodes (%)", ylim=(-5, 105))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    a.set(xlabel="environment steps, all arms together", title="sample efficiency")
    b.set(xlabel="wall-clock from adaptiveh up (s)", title="time")
    rows = summary["by_arms"]
    ns = sorted(rows, key=int)
    steps_goal = [rows[n]["mean_steps_to_goal"] or np.nan for n in ns]
    wall_goal = [rows[n]["mean_wall_to_goal_s"] or np.nan for n in ns]
    xs = np.arange(len(ns))
    by_steps = c.bar(xs - 0.2, steps_goal, 0.4, color="tab:purple")
    c2 = c.twinx()
    by_time = c2.bar(xs + 0.2, wall_goal, 0.4, color="tab:gray")
    c.set(xticks=xs, xticklabels=[f"{n} arm(s)" for n in ns], ylabel="steps to 70 %")
    c2.set(ylabel="seconds to 70 %")
    c.set_title("to 70 % rolling success (mean of the seeds that reached it)")
    for ax, heights in ((c, steps_goal), (c2, wall_goal)):  # headroom for the legend, on the front axes
        if np.isfinite(heights).any():
            ax.set_ylim(0, 1.3 * np.nanmax(heights))
    c2.legend([by_steps, by_time], ["steps (left axis)", "seconds (right axis)"], loc="upper center", ncols=2)
    fig.suptitle(f"NS Reach over the stack: N simulated arms, one learner ({steps} steps in all, 2 cores)")
    fig.tight_layout()
    path = ROOT / "results" / "fleet.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--arms", type=int, nargs="+", default=[1, 2, 4])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--steps", type=int, default=6000)
    p.add_argument("--faults", action="store_true", help="also the three fault runs (two arms, seed 0)")
    p.add_argument("--replot", action="store_true", help="only summarise the finished runs")
    args = p.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    if not args.replot:
        wanted = runs_wanted(args)
        for i, (kind, arms, seed) in enumerate(wanted, 1):
            path = path_of(kind, arms, seed, args.steps)
            if path.exists():
                print(f"[{i}/{len(wanted)}] {path.name}: done before", flush=True)
                continue
            print(f"[{i}/{len(wanted)}] {kind}, {arms} arm(s), seed {seed} ...", flush=True)
            record = run(kind, arms, seed, args.steps)
            path.write_text(json.dumps(record, indent=1))
            print(
                f"    {record['wall_s']:.0f} s; 70 % at step {record['steps_to_goal']}"
                f" ({record['wall_to_goal_s'] or float('nan'):.0f} s); last quarter"
                f" {record['last_quarter_success']}; CPU per arm"
                f" {[round(a['cpu_cores'], 2) for a in record['per_arm'].values()]}",
                flush=True,
            )
    summary = summarise(args.steps)
    (ROOT / "results" / "fleet.json").write_text(json.dumps(summary, indent=1))
    figure = plot(summary, args.steps)
    print(json.dumps(summary["goals"], indent=1))
    print(f"results/fleet.json, {figure.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
