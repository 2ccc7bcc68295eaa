"""The learner's chunks streamed to an FR3 on franka-sim: reflexes and control_command_success_rate.

franka-sim (PyPI; ``scripts/franka_sim_venv.sh`` makes its own virtualenv) serves libfranka's protocol
like franky-sim, and also emulates the FCI's communication constraints (a command that misses its 1 ms
cycle is lost and extrapolated, 20 lost in a row are a ``communication_constraints_violation``) and its
motion limits (position, velocity, acceleration and jerk of the commanded signal: a violation is a
``*_discontinuity`` reflex), both enforced here. The stack is the real one: robot-io's node (its
controller, IK and franky backend, connected to franka-sim on a loopback address) runs in this process,
so the robot state libfranka receives can be sampled, and ``adaptiveh learn`` (and ``adaptiveh act``, the
actor beside robot-io, in the default execution) run as their own processes with
``configs/franka_sim.yaml``'s learner (AdaptiveH on the reach task against robot-io's scripted target, read
from the simulator's truth: vision is not run), sending plans over Zenoh; no plan within FIRST_CHUNK_S is
an error, not a quiet run. Any fault is counted and released as an operator would, so the
run goes on.

Reported: reflexes (franka-sim's aborts, and the faults robot-io saw), ``control_command_success_rate``
(libfranka's robot state, sampled while a motion runs; and franka-sim's own count of every commanded
cycle), the commanded motion (peak joint speed; peak acceleration and jerk as franka-sim measured them
against its limits, the commands a reflex rejected included), tracking, and what the learner did.
franka-sim's own FR3 URDF is offered first to robot-io's model check (see
``model_check_franka_sim_urdf``); accepted, it is what the run serves (its limits lie within 0.01 rad
of Franka's documented ones, which ``fr3`` uses), otherwise the FR3 URDF franky-sim ships. The physics
is franky-sim's FR3 MJCF, the limit tables franka-sim's. Merged under ``franka_sim_stream`` into
results/franka_bench.json.

    bash scripts/franka_sim_venv.sh                 # once
    python bench/franka_sim_stream.py               # 10 minutes (--minutes N)
    python bench/franka_sim_stream.py --quick       # about a minute, to try
    python bench/franka_sim_stream.py --disturb-s 60 --lock-memory off --key KEY   # a checkout beside it
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
import uuid
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]  # the tests' franka-sim launcher

from franka_simulators import FrankaSimServer, franky_sim_fr3_urdf  # noqa: E402

from common.proc_status import status_field  # noqa: E402
from deploy.config import StackConfig, compose_stack_yaml, load_stack_config  # noqa: E402
from deploy.robot_io_node import RobotIONode  # noqa: E402
from learner.segments import Execution  # noqa: E402
from robot_io.backends.franky_config import FrankaConfig  # noqa: E402
from robot_io.backends.franky_model import ModelMismatch  # noqa: E402
from robot_io.config import RobotConfig  # noqa: E402

HOST = "127.0.0.64"  # franka-sim's loopback address (libfranka always dials port 1337)
SAMPLE_HZ = 100.0
LISTED = 40  # reflexes and faults listed one by one (all are counted)
FIRST_CHUNK_S = 120.0  # the learner's start and first snapshot take ~10-20 s; none by then is a failure


def fifo_threads() -> list[int]:
    """Real-time priorities of this process's SCHED_FIFO threads (fields 40-41 of /proc/.../stat)."""
    found = []
    for task in Path("/proc/self/task").iterdir():
        try:
            stat = (task / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        if fields[38] == "1":
            found.append(int(fields[37]))
    return found


def free_endpoint() -> str:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def pct(x: Any, q: float) -> float | None:
    x = np.asarray(x, float)
    return round(float(np.percentile(x, q)), 5) if x.size else None


def model_check_with_franka_sim_urdf(host: str) -> dict[str, Any]:
    """Connect robot-io's franky backend (model fr3) to franka-sim serving its own FR3 URDF."""
    from robot_io.backends.franky_backend import FrankyBackend

    with FrankaSimServer(host):
        try:
            b = FrankyBackend(RobotConfig(backend="franka", model="fr3", franka=FrankaConfig(ip=host)))
        except ModelMismatch as exc:
            return {"accepted": False, "error": str(exc)}
        b.close()
        return {"accepted": True, "report": str(b.report)}


class Sampler(threading.Thread):
    """libfranka's robot state, as robot-io's franky connection receives it, at SAMPLE_HZ."""

    def __init__(self, node: RobotIONode) -> None:
        super().__init__(daemon=True, name="franka-sim-sampler")
        self.node = node
        self.stop = threading.Event()
        self.rows: list[tuple] = []

    def run(self) -> None:
        period = 1.0 / SAMPLE_HZ
        next_t = time.monotonic()
        while not self.stop.is_set():
            robot = self.node.controller.backend.robot
            try:
                s = robot.state
                self.rows.append(
                    (
                        time.monotonic(),
                        s.time.to_sec(),
                        float(s.control_command_success_rate),
                        s.robot_mode.name,
                        np.array(s.q_d),
                        np.array(s.dq_d),
                        np.array(s.ddq_d),
                        np.array(s.q),
                    )
                )
            except Exception:  # between a lost connection and its recovery
                pass
            next_t += period
            time.sleep(max(0.0, next_t - time.monotonic()))


class Counts:
    """What went through robot-io's controller: chunks, played actions, resets, safety events."""

    def __init__(self, node: RobotIONode) -> None:
        c = node.controller
        self.lock = threading.Lock()
        self.chunks = self.played = self.ticks = self.resets = 0
        self.events: list[tuple[float, str, str]] = []
        # When the backend began braking (a hold while streaming), and resumed streaming after one.
        self.holds: list[float] = []
        self.resumes: list[float] = []
        push, tick, react, reset = c.push_chunk, c.tick, c.react, c.reset
        backend, hold, send = c.backend, c.backend.hold, c.backend.send_joint_command

        def on_hold() -> None:
            # A brake is a hold while our motion runs; a fault ends the motion (the backend sets _stopping),
            # so the hold robot-io makes for it is not counted (it was: each reflex looked 0 s after a brake).
            if not backend._stopping:
                with self.lock:
                    self.holds.append(time.monotonic())
            hold()

        def on_send(q: Any) -> None:
            if backend._stopping:
                with self.lock:
                    self.resumes.append(time.monotonic())
            send(q)

        def on_push(*args: Any, **kw: Any) -> Any:
            with self.lock:
                self.chunks += 1
            return push(*args, **kw)

        def on_result(result: Any, ticked: bool) -> Any:
            with self.lock:
                self.ticks += ticked
                self.played += ticked and result.applied is not None
                self.events += [(time.monotonic(), e.kind, e.detail) for e in result.events]
            return result

        def on_reset(*args: Any, **kw: Any) -> Any:
            with self.lock:
                self.resets += 1
            return reset(*args, **kw)

        c.push_chunk = on_push
        c.tick = lambda now: on_result(tick(now), True)
        c.react = lambda now: on_result(react(now), False)
        c.reset = on_reset
        backend.hold = on_hold
        backend.send_joint_command = on_send

    @staticmethod
    def since(times: list[float], t: float) -> float | None:
        """Seconds from the newest of ``times`` before ``t`` (None: none was)."""
        before = [h for h in times if h <= t]
        return round(t - before[-1], 3) if before else None


def stack_config(args: argparse.Namespace, tmp: Path) -> Path:
    cfg = compose_stack_yaml(ROOT / args.config)
    rate = cfg["robot"]["control_rate_hz"]
    cfg["name"] = f"fsim{uuid.uuid4().hex[:10]}"
    cfg["zenoh"] = {**cfg.get("zenoh", {}), "hub": free_endpoint()}
    cfg["robot"]["franka"]["ip"] = args.host
    if args.lock_memory != "config":
        cfg["robot"]["franka"]["lock_memory"] = args.lock_memory == "on"
    cfg["learner"].update(
        steps=int(args.minutes * 60 * rate * 2) + 1000,  # more than the run can take: it is stopped
        checkpoint_dir=str(tmp / "learner"),
        checkpoint_every=10**9,
    )
    # The arm's command stream is measured, not vision: the target is the simulator's truth, the CPU the
    # 1 kHz loop's.
    cfg["learner"]["target_topic"] = "sim/target_truth"
    cfg["vision"] = None
    cfg.pop("monitor", None)
    cfg.pop("recording", None)
    path = tmp / "franka_sim_stream.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def motion_stats(rows: list[tuple], node: RobotIONode) -> dict[str, Any]:
    moving = [r for r in rows if r[3] == "Move"]
    if len(moving) < 3:
        return {"samples_in_motion": len(moving)}
    rate = np.array([r[2] for r in moving])
    started = rate > 0  # 0 until a motion's first command is in (libfranka: "zero if no loop is running")
    q_d = np.array([r[4] for r in moving])
    dq_d = np.array([r[5] for r in moving])
    ddq_d = np.array([r[6] for r in moving])
    q = np.array([r[7] for r in moving])
    kin = node.controller.kin
    vlim = kin.description.limits.velocity
    sub = slice(None, None, max(1, len(moving) // 20000))  # FK on at most ~20k samples
    ee_err = np.array(
        [
            np.linalg.norm(kin.ee_position(a) - kin.ee_position(b))
            for a, b in zip(q_d[sub], q[sub], strict=True)
        ]
    )
    ee_speed = np.array(
        [np.linalg.norm(kin.ee_velocity(a, b)) for a, b in zip(q_d[sub], dq_d[sub], strict=True)]
    )
    wall = rows[-1][0] - rows[0][0]
    return {
        "sim_realtime_factor": round((rows[-1][1] - rows[0][1]) / wall, 3) if wall > 0 else None,
        "samples": len(rows),
        "samples_in_motion": len(moving),
        "control_command_success_rate_libfranka": {
            "samples": int(started.sum()),
            "samples_at_a_motion_start_reading_0": int((~started).sum()),
            "mean": round(float(rate[started].mean()), 5),
            "min": round(float(rate[started].min()), 3),
            "p1": pct(rate[started], 1),
            "p50": pct(rate[started], 50),
            "fraction_of_samples_below_1": round(float(np.mean(rate[started] < 1.0)), 4),
            "fraction_of_samples_below_0.95": round(float(np.mean(rate[started] < 0.95)), 4),
        },
        "commanded_joint_speed_peak_rad_s": np.round(np.abs(dq_d).max(0), 3).tolist(),
        "commanded_joint_speed_peak_fraction_of_limit": round(float((np.abs(dq_d) / vlim).max()), 3),
        "commanded_joint_acceleration_peak_rad_s2": np.round(np.abs(ddq_d).max(0), 2).tolist(),
        "commanded_ee_speed_m_s": {
            "p50": pct(ee_speed, 50),
            "p99": pct(ee_speed, 99),
            "max": pct(ee_speed, 100),
        },
        "tracking_ee_error_m": {"p50": pct(ee_err, 50), "p99": pct(ee_err, 99), "max": pct(ee_err, 100)},
        "tracking_joint_error_rad_max": round(float(np.abs(q_d - q).max()), 4),
    }


def summary_line(elapsed: float, total: float, counts: Counts, server: FrankaSimServer, rows: list) -> str:
    st = server.stats
    recent = [r[2] for r in rows[-int(SAMPLE_HZ * 10) :] if r[3] == "Move"]
    rtf = ""
    if len(rows) > SAMPLE_HZ * 5:
        a, b = rows[-int(SAMPLE_HZ * 5)], rows[-1]
        rtf = f"  sim x{(b[1] - a[1]) / max(1e-6, b[0] - a[0]):.2f}"
    with counts.lock:
        c = f"chunks {counts.chunks}  actions {counts.played}  resets {counts.resets}"
    lost = f"lost cycles {st.get('lost_cycles', 0)}/{st.get('commanded_cycles', 0)}"
    return (
        f"[{int(elapsed) // 60:2d}:{int(elapsed) % 60:02d}/{int(total) // 60}:{int(total) % 60:02d}] {c}"
        f"  success rate (10 s) min {min(recent) if recent else float('nan'):.2f}  {lost}"
        f" (max {st.get('max_consecutive_lost', 0)} in a row)  reflexes {len(st.get('reflexes', []))}{rtf}"
    )


class Disturbance(threading.Thread):
    """Every ``every_s`` seconds, what ran beside the quiet repeat's one reflex: ``git worktree add`` of
    HEAD into a temporary folder (a checkout: disk writes and both cores busy), then its removal."""

    def __init__(self, every_s: float) -> None:
        super().__init__(daemon=True)
        self.every_s = every_s
        self.stop = threading.Event()
        self.times: list[tuple[float, float]] = []  # (start, seconds) on the monotonic clock
        self.failed: list[str] = []  # a checkout that did not happen is no disturbance

    def run(self) -> None:
        while not self.stop.wait(self.every_s):
            with tempfile.TemporaryDirectory() as d:
                t = time.monotonic()
                tree = str(Path(d) / "tree")
                for cmd in (["add", "--detach", tree, "HEAD"], ["remove", "--force", tree]):
                    done = subprocess.run(["git", "worktree", *cmd], cwd=ROOT, capture_output=True, text=True)
                    if done.returncode != 0:
                        self.failed.append(f"git worktree {cmd[0]}: {done.stderr.strip()}")
                        break
                else:
                    self.times.append((t, time.monotonic() - t))


def part_names(cfg: StackConfig) -> list[str]:
    """The learner, and the actor beside robot-io when the config's execution is the actor's (without it
    nothing would send a plan)."""
    return ["learn"] + (["act"] if cfg.learner.execution == Execution.ACTOR else [])


def start_parts(cfg: StackConfig, cfg_path: Path, tmp: Path) -> dict[str, subprocess.Popen]:
    """``part_names``, each its own process logging to ``tmp``."""
    parts = {}
    for name in part_names(cfg):
        cmd = [sys.executable, "-m", "deploy.cli", name, "--config", str(cfg_path), "--log-level", "WARNING"]
        with (tmp / f"{name}.log").open("w") as log:
            parts[name] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
    return parts


def stop_parts(parts: dict[str, subprocess.Popen]) -> None:
    for proc in parts.values():
        if proc.poll() is None:
            proc.terminate()
    for proc in parts.values():
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def part_log(tmp: Path, part: str) -> str:
    return (tmp / f"{part}.log").read_text()


def vm_locked_kb() -> int:
    """This process's locked memory (``mlockall`` by franka.lock_memory), from /proc/self/status."""
    return int(status_field("VmLck") or 0)


def run(args: argparse.Namespace) -> dict[str, Any]:
    print(f"model check against franka-sim's own FR3 URDF ({args.host}) ...", flush=True)
    model_check = model_check_with_franka_sim_urdf(args.host)
    print(
        f"  {'accepted' if model_check['accepted'] else 'refused'}: {model_check.get('error', '')}",
        flush=True,
    )
    total = args.minutes * 60.0
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        cfg_path = stack_config(args, tmp)
        cfg = load_stack_config(cfg_path)
        fifo = args.sim_fifo_priority or None
        served = None if model_check["accepted"] else franky_sim_fr3_urdf()
        server = FrankaSimServer(args.host, urdf=served, fifo_priority=fifo).start()
        print(
            f"franka-sim on {args.host}:1337 (communication constraints and motion limits enforced)",
            flush=True,
        )
        node, parts = None, {}
        try:
            node = RobotIONode(cfg)  # connects robot-io's franky backend to franka-sim (model check passes)
            counts = Counts(node)
            sampler = Sampler(node)
            node.start()
            sampler.start()
            parts = start_parts(cfg, cfg_path, tmp)
            t0 = time.monotonic()
            releases = 0
            disturbance = Disturbance(args.disturb_s) if args.disturb_s > 0 else None
            if disturbance is not None:
                disturbance.start()
            next_report = t0 + args.report_s
            while (now := time.monotonic()) - t0 < total:
                for part, proc in parts.items():
                    if proc.poll() is not None:
                        raise RuntimeError(f"adaptiveh {part} exited:\n" + part_log(tmp, part)[-3000:])
                if counts.chunks == 0 and now - t0 > FIRST_CHUNK_S:
                    logs = "\n".join(f"-- {part}:\n{part_log(tmp, part)[-1500:]}" for part in parts)
                    raise RuntimeError(f"no chunk reached robot-io in {FIRST_CHUNK_S:.0f} s:\n{logs}")
                if node.controller.safety.mode == "fault":  # the operator's release: recover, go on
                    time.sleep(0.5)
                    node.controller.operator("release")
                    node.wake()
                    releases += 1
                if now >= next_report:
                    print(summary_line(now - t0, total, counts, server, sampler.rows), flush=True)
                    next_report += args.report_s
                time.sleep(0.2)
            wall = time.monotonic() - t0
            if disturbance is not None:
                disturbance.stop.set()
                disturbance.join(timeout=120)
            fifo_robot_io = fifo_threads()
            locked_kb = vm_locked_kb()
            stop_parts(parts)
            sampler.stop.set()
            sampler.join(timeout=5)
            time.sleep(2 * server.stats_period_s)  # franka-sim's last counts
            stats = dict(server.stats)
            learner_log = part_log(tmp, "learn")
        finally:
            stop_parts(parts)
            if node is not None:
                node.stop()
                node.close()
            server.kill()
    rows = sampler.rows
    faults = [(t - t0, k, d) for t, k, d in counts.events if k == "driver_error"]
    reflexes = stats.get("reflexes", [])
    t_server0 = time.time() - (time.monotonic() - t0)
    cycles, lost = stats.get("commanded_cycles", 0), stats.get("lost_cycles", 0)
    return {
        "command": "python bench/franka_sim_stream.py"
        + (f" --minutes {args.minutes:g}" if args.minutes != 10 else "")
        + (f" --config {args.config}" if args.config != "configs/franka_sim.yaml" else "")
        + (f" --sim-fifo-priority {args.sim_fifo_priority}" if args.sim_fifo_priority != 99 else "")
        + (f" --disturb-s {args.disturb_s:g}" if args.disturb_s > 0 else "")
        + (f" --lock-memory {args.lock_memory}" if args.lock_memory != "config" else "")
        + (f" --key {args.key}" if args.key != "franka_sim_stream" else ""),
        "disturbance": None
        if disturbance is None
        else {
            "every_s": args.disturb_s,
            "what": "git worktree add --detach <tmp> HEAD; git worktree remove --force <tmp>",
            "at_s": [round(t - t0, 1) for t, _ in disturbance.times],
            "took_s": [round(d, 1) for _, d in disturbance.times],
            "failed": disturbance.failed,
        },
        "simulator": "franka-sim 1.1.7 (MuJoCo 3.2, franky-sim's FR3 MJCF), --enforce-comm-constraints and "
        "--enforce-motion-limits; franky-control 2.0.0 (libfranka 0.21.2)",
        "served_urdf": "franka-sim's own fr3.urdf (accepted by the model check, below)"
        if model_check["accepted"]
        else "franky-sim's fr3_clean.urdf (franka-sim's own is refused by the model check, below)",
        "model_check_franka_sim_urdf": model_check,
        "route": "robot-io node (controller, IK, franky backend) in the bench process; "
        + " and ".join(f"`adaptiveh {part}`" for part in parts)
        + f" each its own process ({args.config}: AdaptiveH, reach task, plans over Zenoh; the target the"
        " simulator's truth, no vision)",
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "load": os.getloadavg()},
        "scheduling": f"franka-sim SCHED_FIFO {args.sim_fifo_priority} (0: SCHED_OTHER); robot-io: "
        f"{len(fifo_robot_io)} SCHED_FIFO threads (priorities {sorted(set(fifo_robot_io))}: franky's 1 kHz "
        "loop), the rest SCHED_OTHER; no PREEMPT_RT kernel here",
        "memory_locked_kb": locked_kb,  # VmLck of the robot-io process (robot.franka.lock_memory)
        "wall_clock_s": round(wall, 1),
        "reflexes": len(reflexes),
        "reflex_kinds": dict(Counter(r["reason"].split(":")[0] for r in reflexes).most_common()),
        "reflex_reasons": [
            {"t_s": round(r["time"] - t_server0, 1), "reason": r["reason"]} for r in reflexes[:LISTED]
        ],
        "faults_seen_by_robot_io": [
            {
                "t_s": round(t, 1),
                "s_after_brake": counts.since(counts.holds, t + t0),
                "s_after_resume": counts.since(counts.resumes, t + t0),
                "detail": d.splitlines()[0],
            }
            for t, _, d in faults[:LISTED]
        ],
        "brakes": len(counts.holds),
        "resumes_after_brake": len(counts.resumes),
        "operator_releases": releases,
        "control_command_success_rate_franka_sim": {
            "commanded_cycles": cycles,
            "lost_cycles": lost,
            "overall": round(1 - lost / cycles, 5) if cycles else None,
            "max_consecutive_lost": stats.get("max_consecutive_lost"),
            "connections": stats.get("connections"),
        },
        "peak_fraction_of_limit_franka_sim": stats.get("peak_fraction_of_limit"),
        **motion_stats(rows, node),
        "stack": {
            "chunks_received": counts.chunks,
            "actions_played": counts.played,
            "control_ticks": counts.ticks,
            "control_rate_hz": round(counts.ticks / wall, 2),
            "resets": counts.resets,
            "safety_events": dict(Counter(k for _, k, _ in counts.events)),
            "learner_log_tail": learner_log.strip().splitlines()[-5:],
        },
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--quick", action="store_true", help="about a minute, to try (same as --minutes 1)")
    ap.add_argument("--config", default="configs/franka_sim.yaml")
    ap.add_argument("--host", default=HOST, help="franka-sim's loopback address")
    ap.add_argument("--out", default="results/franka_bench.json", help="merged under --key")
    ap.add_argument("--report-s", type=float, default=15.0, help="progress every this many seconds")
    ap.add_argument(
        "--sim-fifo-priority",
        type=int,
        default=99,
        help="run franka-sim SCHED_FIFO at this priority, as the arm is a real-time machine of its own "
        "(0: SCHED_OTHER, sharing the cores with everything else)",
    )
    ap.add_argument("--disturb-s", type=float, default=0.0, help="a git checkout beside it every this many s")
    ap.add_argument(
        "--lock-memory", choices=("config", "on", "off"), default="config", help="override franka.lock_memory"
    )
    ap.add_argument(
        "--key", default="franka_sim_stream", help="the key of results/franka_bench.json to write"
    )
    args = ap.parse_args()
    if args.quick:
        args.minutes = 1.0
    os.chdir(ROOT)
    result = run(args)
    path = Path(args.out)
    merged = json.loads(path.read_text()) if path.exists() else {}
    merged.pop("franka_sim_streaming", None)  # the old "not run" placeholder
    merged[args.key] = result
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(merged, indent=2) + "\n")
    r = result
    rate = r.get("control_command_success_rate_libfranka", {})
    fs = r["control_command_success_rate_franka_sim"]
    print(
        f"\nfranka-sim stream, {r['wall_clock_s'] / 60:.1f} min ({r['stack']['chunks_received']} chunks, "
        f"{r['stack']['actions_played']} actions played, {r['stack']['resets']} resets)"
    )
    print(
        f"  reflexes: {r['reflexes']} {r['reflex_kinds']}"
        + "".join(f"\n    {x['t_s']} s: {x['reason']}" for x in r["reflex_reasons"])
    )
    print(
        f"  control_command_success_rate (libfranka, while moving): mean {rate.get('mean')}, "
        f"min {rate.get('min')}, p1 {rate.get('p1')}"
    )
    print(
        f"  franka-sim: {fs['lost_cycles']} of {fs['commanded_cycles']} commanded cycles lost "
        f"(overall {fs['overall']}, at most {fs['max_consecutive_lost']} in a row; 20 is a reflex)"
    )
    peaks = r["peak_fraction_of_limit_franka_sim"]
    print(f"  peak commanded acceleration / jerk, fraction of the FR3's limit: {peaks}")
    print(
        f"  tracking (end effector, commanded vs measured): {r.get('tracking_ee_error_m')}; "
        f"simulator at x{r.get('sim_realtime_factor')} real time"
    )
    print(f"merged under {args.key} into {path}")
    return 0 if r["reflexes"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
