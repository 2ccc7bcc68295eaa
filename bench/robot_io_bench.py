"""Robot-interface benchmark: IK solve time, chunk round trip over Zenoh, state rate, e-stop latency.

Starts ``adaptiveh robot-io`` (PyBullet mock) as a separate process on loopback and drives it from this
one, so the numbers include two processes, Zenoh and the control loop's period. Writes
``results/robot_io_bench.json``. Run: ``python bench/robot_io_bench.py [--quick]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import mink
import numpy as np
import yaml

from bus import messages as m
from bus.learner_session import LearnerSession
from bus.transport import Bus, ZenohConfig, open_session
from robot_io.config import RobotConfig
from tasks.sim_world import robot_controller

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run as a script: our packages before anything of the same name
sys.path.insert(0, str(ROOT / "tests"))  # free ports and unique names: the tests' helper
from loopback import free_port, unique_name  # noqa: E402


def pct(xs: list[float]) -> dict[str, float]:
    a = np.asarray(xs) * 1000.0
    return {
        "p50_ms": round(float(np.percentile(a, 50)), 3),
        "p99_ms": round(float(np.percentile(a, 99)), 3),
        "max_ms": round(float(a.max()), 3),
        "n": len(xs),
    }


def _timed(owner: object, name: str, into: list[float]) -> None:
    """Wrap ``owner.name`` so each call's duration is appended to ``into`` (a bench probe, not a mock)."""
    call = getattr(owner, name)

    def timed(*args: object, **kwargs: object) -> object:
        t = time.perf_counter()
        try:
            return call(*args, **kwargs)
        finally:
            into.append(time.perf_counter() - t)

    setattr(owner, name, timed)


def bench_tick(n: int) -> dict:
    """The control tick's work in-process (PyBullet mock, as robot-io builds it), its parts timed in one
    run, and beside it one bare mink QP on the same problem (same model, tasks, limits), interleaved tick
    by tick so both see the same machine. The IK makes ``ik.iterations`` QPs a command."""
    cfg = RobotConfig()
    controller = robot_controller(cfg)
    parts: dict[str, list[float]] = {k: [] for k in ("ik", "command_check", "send", "physics_step", "state")}
    _timed(controller.ik, "solve", parts["ik"])
    _timed(controller.kin, "check", parts["command_check"])
    _timed(controller.backend, "send_joint_command", parts["send"])
    _timed(controller.backend, "step", parts["physics_step"])
    _timed(controller, "state", parts["state"])
    ik = controller.ik
    bare = mink.Configuration(ik.model)
    tasks, h = [ik.ee_task, ik.posture_task], cfg.period / cfg.ik.iterations
    rng = np.random.default_rng(0)
    tick, bare_qp = [], []
    controller.reset(seed=0)
    for k in range(n):
        if k % 40 == 0:  # a new direction every 2 s, steps up to the action bound
            direction = rng.uniform(-1, 1, 3) * cfg.max_step_m / np.sqrt(3)
        t = time.perf_counter()
        controller.step_action(direction)
        tick.append(time.perf_counter() - t)
        bare.update(controller.backend.read_state().q)
        t = time.perf_counter()
        mink.solve_ik(bare, tasks, h, cfg.ik.solver, damping=cfg.ik.damping, limits=ik.limits)
        bare_qp.append(time.perf_counter() - t)
    controller.close()
    skip = 10  # first calls warm caches
    out = {name: pct(times[skip:]) for name, times in parts.items()}
    out["tick_without_physics"] = pct(
        [t - s for t, s in zip(tick, parts["physics_step"], strict=True)][skip:]
    )
    out["bare_mink_qp"] = pct(bare_qp[skip:])
    out["ik_qps_per_command"] = cfg.ik.iterations
    out["ik_p99_over_bare_qp_p99"] = round(out["ik"]["p99_ms"] / out["bare_mink_qp"]["p99_ms"], 2)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer samples (a smoke run)")
    ap.add_argument("--out", default=str(ROOT / "results" / "robot_io_bench.json"))
    args = ap.parse_args()
    n_rt, n_estop, rate_s = (40, 3, 3.0) if args.quick else (300, 15, 10.0)

    tick = bench_tick(500 if args.quick else 3000)
    print("tick", json.dumps(tick), flush=True)

    port, name = free_port(), unique_name("bench")
    rate = 20.0
    cfg = {
        "name": name,
        "zenoh": {"listen": [f"tcp/127.0.0.1:{port}"]},
        "robot": {
            "backend": "pybullet",
            "control_rate_hz": rate,
            "target_motion": "slow",
            "watchdog_timeout_s": 5.0,
        },
    }
    cfg_path = Path(tempfile.mkdtemp()) / "bench.yaml"
    cfg_path.write_text(yaml.safe_dump(cfg))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "deploy.cli",
            "robot-io",
            "--config",
            str(cfg_path),
            "--watch",
            "",
            "--log-level",
            "WARNING",
        ],
        cwd=ROOT,
    )
    bus = Bus(open_session(ZenohConfig(connect=(f"tcp/127.0.0.1:{port}",))), name)
    lock = threading.Lock()
    states: list[tuple[float, m.RobotState]] = []
    status: dict[int, tuple[float, m.ChunkStatus]] = {}
    estops: list[tuple[float, m.SafetyEvent]] = []

    def on_state(s):
        with lock:
            states.append((time.time(), s))

    def on_status(s):
        if s.executed == 1 and s.chunk_seq not in status:
            with lock:
                status[s.chunk_seq] = (time.time(), s)

    def on_safety(e):
        if e.kind == m.SafetyEvent.ESTOP:
            with lock:
                estops.append((time.time(), e))

    bus.subscribe(m.STATE, on_state)
    bus.subscribe(m.CHUNK_STATUS, on_status)
    bus.subscribe(m.EVENTS_SAFETY, on_safety)
    learner = LearnerSession(bus)  # the bench is the learner: robot-io obeys its session after the reset
    control_pub = bus.publisher(m.CONTROL)
    try:
        deadline = time.monotonic() + 60
        while not states and time.monotonic() < deadline:
            time.sleep(0.05)
        if not states:
            raise RuntimeError("robot-io did not start")
        time.sleep(1.0)
        reply = learner.reset(-1, timeout=30)
        if not reply.ok:
            raise RuntimeError(f"robot-io refused the bench's reset: {reply.detail}")

        # State rate: messages received over a window.
        with lock:
            n0 = len(states)
        time.sleep(rate_s)
        with lock:
            window = states[n0:]
        state_rate = (len(window) - 1) / (window[-1][0] - window[0][0])
        gaps = np.diff([t for t, _ in window])

        # Round trip: chunk sent -> first action applied (status stamp) -> status received here.
        rng = random.Random(0)
        sent: dict[int, float] = {}
        for _ in range(n_rt):
            time.sleep(rng.uniform(0.055, 0.105))  # random phase against the 50 ms period, one tick apart
            t_sent = time.time()
            sent[learner.send(m.ActionChunk(actions=[0.0, 0.0, 0.0], opened_by=m.ActionChunk.FIRST))[0]] = (
                t_sent
            )
        time.sleep(0.5)
        applied = [status[s][1].stamp - sent[s] for s in sent if s in status]
        round_trip = [status[s][0] - sent[s] for s in sent if s in status]

        # E-stop: while moving, estop sent -> safety event received; and -> joint speed below 0.01 rad/s.
        estop_event, estop_still = [], []
        for i in range(n_estop):
            direction = 1.0 if i % 2 == 0 else -1.0
            learner.send(
                m.ActionChunk(
                    actions=np.tile([0.0, 0.04 * direction, 0.0], 30).tolist(), opened_by=m.ActionChunk.FIRST
                )
            )
            t_wait = time.monotonic() + 3
            while time.monotonic() < t_wait:
                with lock:
                    moving = max(abs(v) for v in states[-1][1].dq) > 0.3
                if moving:
                    break
                time.sleep(0.005)
            with lock:
                k_events = len(estops)
            t0 = time.time()
            control_pub(m.Control(command=m.Control.ESTOP, jog=[0.0, 0.0, 0.0]))
            t_wait = time.monotonic() + 2
            while time.monotonic() < t_wait:
                with lock:
                    ev = estops[k_events:]
                    still = [
                        t
                        for t, s in states
                        if t > t0 and s.mode == m.RobotState.ESTOP and max(abs(v) for v in s.dq) < 0.01
                    ]
                if ev and still:
                    estop_event.append(ev[0][0] - t0)
                    estop_still.append(still[0] - t0)
                    break
                time.sleep(0.002)
            control_pub(m.Control(command=m.Control.RELEASE, jog=[0.0, 0.0, 0.0]))
            time.sleep(0.3)
    finally:
        bus.close()
        proc.terminate()
        proc.wait(timeout=10)

    result = {
        "machine": {
            "platform": platform.platform(),
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
        },
        "control_rate_hz": rate,
        "tick_in_process": tick,
        "chunk_sent_to_first_command_applied": pct(applied),
        "chunk_round_trip_to_status_received": pct(round_trip),
        "state_rate_hz": {
            "achieved": round(state_rate, 3),
            "target": rate,
            "gap_p99_ms": round(float(np.percentile(gaps, 99) * 1000), 3),
        },
        "estop_sent_to_event_received": pct(estop_event),
        "estop_sent_to_joint_speed_below_0.01": pct(estop_still),
        "notes": (
            "Two processes on loopback Zenoh (peer mode). Chunk latency includes the wait for the next "
            "control tick (period 50 ms), so it is dominated by the control rate; e-stop wakes the "
            "control thread at once. tick_in_process: the tick's parts in one process, without Zenoh; "
            "bare_mink_qp is one mink/daqp QP on the same problem, timed between ticks."
        ),
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
