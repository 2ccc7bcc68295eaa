"""Stack benchmark: what going through the deployed stack costs against NS Reach in-process.

Starts ``adaptiveh robot-io`` (PyBullet mock, owns the loopback hub) and ``adaptiveh learn`` as separate
processes and listens from this one: the control-loop rate achieved (robot state stamps while running),
the state-to-command latency across processes (robot state stamp -> the learner's next chunk stamp; one
machine, one clock), and the learner's training curve. Then the same algo, agent config, seed, step
count, episode length and target motion in-process on ``NSReach-v0``. The learner section is read from
``configs/sim.yaml`` as it is when this runs. The target is the simulator's ground truth on both sides
(``sim/target_truth``) so the comparison isolates the transport and process split, not vision.
Writes ``results/stack_bench.json`` and ``results/stack_bench.png``.

``--latency-ms`` injects that much learner latency into the Zenoh run (each chunk is published that
late). The actor beside the arm (``learner.execution: actor``, the product's default) is measured by
bench/stack_robustness.py. Run: ``python bench/stack_bench.py [--steps 1500] [--seed 0] [--latency-ms 250]
[--algo rkhs --fixed-h 10]`` (the last two: the fixed-H learner instead of configs/sim.yaml's AdaptiveH).
``--replot`` runs nothing and redraws the figure from the JSON at ``--out`` (the retired plan execution's
``results/stack_bench_plan*.json`` too).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bus import messages as m
from bus.transport import Bus, ZenohConfig, open_session

ROOT = Path(__file__).resolve().parents[1]
# Free ports and unique names: the tests' helper. The repository root goes first: with tests/ alone in
# front, ``import tasks`` found the test folder tests/tasks (a namespace package) before the installed one.
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
from loopback import free_endpoint, unique_name  # noqa: E402

from deploy.config import compose_stack_yaml  # noqa: E402


class Listener:
    """Robot states and learner chunks as this process receives them."""

    def __init__(self, hub: str, robot: str) -> None:
        self.bus = Bus(open_session(ZenohConfig(hub=hub)), robot)
        self.lock = threading.Lock()
        self.states: list[tuple[float, int, str]] = []  # (stamp, chunk_seq, mode)
        self.chunks: list[tuple[float, int]] = []  # (stamp, chunk_seq)
        self.bus.subscribe(m.STATE, self._state)
        self.bus.subscribe(m.CMD_CHUNK, self._chunk)

    def _state(self, s: m.RobotState) -> None:
        with self.lock:
            self.states.append((s.stamp, s.chunk_seq, m.label(s, "mode")))

    def _chunk(self, c: m.ActionChunk) -> None:
        with self.lock:
            self.chunks.append((c.stamp, c.seq))


def loop_rate(states: list[tuple[float, int, str]], t0: float, t1: float, hz: float) -> dict[str, float]:
    """Rate and period percentiles of the robot's state stream (one state per control tick) while the
    learner ran; the loop catches up after a late tick, so the late fraction is reported too."""
    st = np.array(sorted(s[0] for s in states if t0 <= s[0] <= t1))
    if len(st) < 3:
        return {}
    dt = np.diff(st) * 1e3
    return {
        "achieved_hz": float((len(st) - 1) / (st[-1] - st[0])),
        "period_ms_p50": float(np.percentile(dt, 50)),
        "period_ms_p99": float(np.percentile(dt, 99)),
        "late_ticks_pct": float(100 * np.mean(dt > 1.5e3 / hz)),
        "states": len(st),
    }


def latency(states: list[tuple[float, int, str]], chunks: list[tuple[float, int]]) -> dict[str, Any]:
    """State-to-command: for chunk k+1, the first robot state (after chunk k was sent) that reports chunk
    k executing is what the learner waited for; latency = chunk k+1's stamp - that state's stamp. Pairs
    over 1 s are episode resets (a reset query sits between them) and are counted apart."""
    st = sorted(states)
    stamps = np.array([s[0] for s in st])
    out, resets = [], 0
    for (t_prev, seq_prev), (t_next, seq_next) in zip(chunks, chunks[1:], strict=False):
        if seq_next != seq_prev + 1:
            continue
        i = int(np.searchsorted(stamps, t_prev, side="right"))
        while i < len(st) and st[i][1] < seq_prev:
            i += 1
        if i >= len(st) or st[i][0] > t_next:
            continue
        lat = t_next - st[i][0]
        if lat > 1.0:
            resets += 1
        else:
            out.append(lat * 1e3)
    a = np.array(out)
    if not len(a):
        return {"pairs": 0}
    return {
        "p50_ms": float(np.percentile(a, 50)),
        "p99_ms": float(np.percentile(a, 99)),
        "mean_ms": float(a.mean()),
        "max_ms": float(a.max()),
        "pairs": len(a),
        "reset_pairs_excluded": resets,
    }


def curve(episodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [
        {
            "step": e["global_step"],
            "return": e["ret"],
            "final_distance": (e.get("info") or {}).get("distance"),
            "success": e.get("success"),
        }
        for e in episodes
    ]


def quarters(eps: list[dict[str, Any]], key: str) -> list[float | None]:
    q = max(1, len(eps) // 4)
    vals = [[e[key] for e in eps[i * q : (i + 1) * q] if e[key] is not None] for i in range(4)]
    return [float(np.mean(v)) if v else None for v in vals]


def run_zenoh(cfg: dict[str, Any], steps: int, tmp: Path, latency_ms: float = 0.0) -> dict[str, Any]:
    cfg = json.loads(json.dumps(cfg))
    cfg["name"] = unique_name("bench")
    cfg["zenoh"] = {**cfg.get("zenoh", {}), "hub": free_endpoint()}
    cfg.pop("vision", None)
    tmp = tmp / "closed_loop"
    tmp.mkdir(parents=True, exist_ok=True)
    cfg["learner"].update(
        steps=steps,
        target_topic="sim/target_truth",
        checkpoint_dir=str(tmp / "l"),
        checkpoint_every=10**9,
        execution="closed_loop",
        latency_ms=latency_ms,
    )
    path = tmp / "stack.yaml"
    path.write_text(yaml.safe_dump(cfg))
    cli = [sys.executable, "-m", "deploy.cli"]
    robot = subprocess.Popen([*cli, "robot-io", "--config", str(path), "--log-level", "WARNING"])
    try:
        time.sleep(1.0)
        listener = Listener(cfg["zenoh"]["hub"], cfg["name"])
        t0 = time.time()
        learn = subprocess.run(
            [*cli, "learn", "--config", str(path), "--log-level", "WARNING"],
            capture_output=True,
            text=True,
            # a closed-loop step waits out the latency as well as the control period
            timeout=steps * (1.0 / cfg["robot"]["control_rate_hz"] + latency_ms / 1000.0) * 4 + 120,
        )
        t1 = time.time()
        if learn.returncode != 0:
            raise RuntimeError(f"learner failed: {learn.stderr[-2000:]}")
        with listener.lock:
            states, chunks = list(listener.states), list(listener.chunks)
        listener.bus.close()
    finally:
        robot.terminate()
        robot.wait(timeout=30)
    res = json.loads((tmp / "l" / "result.json").read_text())
    return {
        "wall_clock_s": t1 - t0,
        "learner_wall_clock_s": res["wall_clock_s"],
        "control_loop": {
            "target_hz": cfg["robot"]["control_rate_hz"],
            **loop_rate(states, t0, t1, cfg["robot"]["control_rate_hz"]),
        },
        "state_to_command_latency": latency(states, chunks),
        "execution": "closed_loop",
        "latency_ms": latency_ms,
        "chunk_preemptions": res["chunk_preemptions"],
        "dropped_actions": res["dropped_actions"],
        "dropped_planned": res["dropped_planned"],
        "dropped_planned_moving": res["dropped_planned_moving"],
        "retreat_preemptions": res["retreat_preemptions"],
        "retreat_dropped": res["retreat_dropped"],
        "retreat_dropped_moving": res["retreat_dropped_moving"],
        "segments": len(res["segments"]),
        "retreats": sum(s["reason"] == "retreat" for s in res["segments"]),
        "mean_H": float(np.mean([s["H"] for s in res["segments"]])) if res["segments"] else None,
        "curve": curve(res["episodes"]),
    }


def run_in_process(cfg: dict[str, Any], steps: int, tmp: Path) -> dict[str, Any]:
    from experiments.training import TrainSpec, train

    lc = cfg["learner"]
    spec = TrainSpec(
        env="NSReach-v0",
        env_kwargs={
            "motion": cfg["robot"].get("target_motion", "slow"),
            "max_episode_steps": lc["max_episode_steps"],
            "seed": lc["seed"],
            "control_rate_hz": cfg["robot"]["control_rate_hz"],
        },
        algo=lc["algo"],
        steps=steps,
        seed=lc["seed"],
        agent=lc.get("agent", {}),
        checkpoint_every=10**9,
        reseed_episodes=True,  # the stack's world: its actor reseeds the arm's target every episode
    )
    res = train(spec, tmp / "inproc", resume=False, progress=False)
    return {
        "wall_clock_s": res["wall_clock_s"],
        "segments": len(res["segments"]),
        "retreats": sum(s["reason"] == "retreat" for s in res["segments"]),
        "mean_H": float(np.mean([s["H"] for s in res["segments"]])) if res["segments"] else None,
        "curve": curve(res["episodes"]),
    }


def plot(out: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))  # 1540 px: a laptop screen
    labels = {
        "zenoh": ("over Zenoh, closed loop", "tab:blue"),
        "zenoh_plan": ("over Zenoh, plan execution (retired)", "tab:green"),  # the stack_bench_plan*.json
        "in_process": ("in-process NSReach-v0", "tab:orange"),
    }
    for name, (label, col) in labels.items():
        if name not in out:
            continue
        c = out[name]["curve"]
        for ax, key in ((axes[0], "return"), (axes[1], "final_distance")):
            x = [e["step"] for e in c]
            y = [e[key] for e in c]
            ax.plot(x, y, "o-", color=col, ms=3, lw=1, alpha=0.8, label=label)
    axes[0].set(xlabel="environment step", ylabel="episode return (-sum distance)", title="NS Reach return")
    axes[1].set(xlabel="environment step", ylabel="final distance (m)", title="distance at episode end")
    axes[1].axhline(0.05, color="g", ls="--", lw=1, label="success (5 cm)")
    for ax in axes[:2]:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    lat = out["zenoh"]["state_to_command_latency"]
    loop = out["zenoh"]["control_loop"]
    axes[2].axis("off")
    text = [
        f"algo {out['config']['algo']}, seed {out['config']['seed']}, {out['config']['steps']} steps",
        f"control loop: {loop.get('achieved_hz', float('nan')):.2f} Hz of {loop['target_hz']:.0f}",
        f"  period p50 {loop.get('period_ms_p50', float('nan')):.1f} ms,"
        f" p99 {loop.get('period_ms_p99', float('nan')):.1f} ms",
        f"state->command latency: p50 {lat.get('p50_ms', float('nan')):.1f} ms,"
        f" p99 {lat.get('p99_ms', float('nan')):.1f} ms ({lat.get('pairs', 0)} pairs)",
        f"wall clock: Zenoh {out['zenoh']['wall_clock_s']:.0f} s,"
        f" in-process {out['in_process']['wall_clock_s']:.0f} s",
        f"retreats: Zenoh {out['zenoh']['retreats']}/{out['zenoh']['segments']} segments,"
        f" in-process {out['in_process']['retreats']}/{out['in_process']['segments']}",
    ]
    if "zenoh_plan" in out:
        plan = out["zenoh_plan"]
        text += [
            f"plan execution, latency {plan['latency_ms']:.0f} ms: last-quarter",
            f"  success {plan['success_by_quarter'][-1]}"
            f" vs closed loop {out['zenoh']['success_by_quarter'][-1]}",
            f"  retreats {plan['retreats']}/{plan['segments']}, dropped at retreat"
            f" {plan['retreat_dropped']} ({plan['retreat_dropped_moving']} moving)",
        ]
    axes[2].text(0.0, 0.95, "\n".join(text), va="top", family="monospace", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "configs/sim.yaml"))
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--seed", type=int, default=None, help="override learner.seed")
    ap.add_argument("--out", default=str(ROOT / "results/stack_bench.json"))
    ap.add_argument(
        "--latency-ms", type=float, default=0.0, help="learner latency injected into the Zenoh runs"
    )
    ap.add_argument("--algo", default=None, help="override learner.algo (e.g. rkhs: fixed-H, no retreat)")
    ap.add_argument("--fixed-h", type=int, default=None, help="override learner.agent.fixed_h (algo rkhs)")
    ap.add_argument("--replot", action="store_true", help="run nothing: redraw the .png from the --out JSON")
    args = ap.parse_args()
    os.chdir(ROOT)
    if args.replot:
        path = Path(args.out)
        plot(json.loads(path.read_text()), path.with_suffix(".png"))
        print(f"wrote {path.with_suffix('.png')}")
        return 0
    cfg = compose_stack_yaml(args.config)
    if args.seed is not None:
        cfg["learner"]["seed"] = args.seed
    if args.algo is not None:
        cfg["learner"]["algo"] = args.algo
    if args.fixed_h is not None:
        cfg["learner"].setdefault("agent", {})["fixed_h"] = args.fixed_h
    lc = cfg["learner"]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        zen = run_zenoh(cfg, args.steps, tmp, args.latency_ms)
        inp = run_in_process(cfg, args.steps, tmp)
    out: dict[str, Any] = {
        "config": {
            "algo": lc["algo"],
            "seed": lc["seed"],
            "steps": args.steps,
            "agent": lc.get("agent", {}),
            "max_episode_steps": lc["max_episode_steps"],
            "chunk_len": lc["chunk_len"],
            "execution": "closed_loop",
            "latency_ms": args.latency_ms,
            "target_motion": cfg["robot"].get("target_motion"),
            "target": "sim/target_truth (ground truth both sides)",
        },
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "load": os.getloadavg()},
        "zenoh": zen,
        "in_process": inp,
    }
    runs = [name for name in ("zenoh", "in_process") if name in out]
    for name in runs:
        c = out[name]["curve"]
        out[name]["return_by_quarter"] = quarters(c, "return")
        out[name]["final_distance_by_quarter"] = quarters(c, "final_distance")
        out[name]["success_by_quarter"] = quarters(
            [{**e, "success": float(bool(e["success"]))} for e in c], "success"
        )
        out[name]["success_rate"] = float(np.mean([bool(e["success"]) for e in c])) if c else None
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1, default=float))
    plot(out, path.with_suffix(".png"))
    loop, lat = zen["control_loop"], zen["state_to_command_latency"]
    print(f"control loop: {loop.get('achieved_hz', float('nan')):.2f} Hz (target {loop['target_hz']:.0f})")
    print(f"state->command latency: p50 {lat.get('p50_ms')} ms, p99 {lat.get('p99_ms')} ms")
    for name in runs:
        o = out[name]
        print(
            f"{name:10s}: wall {o['wall_clock_s']:.0f} s, success by quarter "
            f"{[round(x, 2) if x is not None else None for x in o['success_by_quarter']]}, return by quarter "
            f"{[round(x, 2) if x is not None else None for x in o['return_by_quarter']]}, final distance by "
            f"quarter {[round(x, 3) if x is not None else None for x in o['final_distance_by_quarter']]}, "
            f"success {o['success_rate']}, retreats {o['retreats']}/{o['segments']}"
        )
    print(f"wrote {path} and {path.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
