"""The Franka path on franky-sim: how streamed IK targets become motion, and how fast holds and recovery act.

For each ``franka.stream`` mode the controller plays a chunk (a 4 cm circle, 20 Hz) on a franky-sim FR3
while a thread samples the robot state; all times are the robot's own clock (``RobotState.time``), since
franky-sim runs slower than real time on a loaded machine (its real-time factor is reported). Measured:

- command -> motion: from rest, one target sent (joint 1 + 0.05 rad); robot time until the commanded
  joint speed exceeds 0.01 rad/s and the measured end effector 5 mm/s;
- tracking: end effector (measured) one period after each command vs that command's IK target;
- smoothness of the commanded motion: RMS joint jerk and "dips" (samples mid-stream where the commanded
  joint speed falls below 30 % of its median: the stop-and-go that streaming can cause);
- hold -> still: commanded speed < 0.01 rad/s, and end effector < 5 mm/s;
- recovery: the server killed and restarted, time for ``recover()`` (reconnect + model check).

    python bench/franka_bench.py            # writes results/franka_bench.json (about a minute)
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# The root first: tests/robot_io, tests/tasks, ... would otherwise shadow our packages as namespace packages.
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]  # the tests' franky-sim launcher
from franka_simulators import FrankySimServer  # noqa: E402

from robot_io.backends.franky_config import FrankaConfig  # noqa: E402
from robot_io.config import RobotConfig  # noqa: E402
from tasks.sim_world import robot_controller  # noqa: E402

HOST = "127.0.0.61"
PERIOD = 0.05


class Sampler(threading.Thread):
    """Polls the robot state as fast as Python allows (robot time stamps make the rate irrelevant)."""

    def __init__(self, robot) -> None:
        super().__init__(daemon=True)
        self.robot, self.rows, self.stop = robot, [], threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            try:
                s = self.robot.state
            except Exception:
                return
            self.rows.append((s.time.to_sec(), np.array(s.q_d), np.array(s.dq_d), np.array(s.q)))
            time.sleep(0.001)


def pct(x, q) -> float:
    return round(float(np.percentile(np.asarray(x, float), q)), 5) if len(x) else float("nan")


def circle_chunk(n: int = 80, radius: float = 0.04) -> np.ndarray:
    theta = np.linspace(0, 2 * np.pi, n + 1)
    path = radius * np.stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)], 1)
    return np.diff(path, axis=0)


def run_mode(stream: str) -> dict:
    cfg = RobotConfig(
        backend="franka", model="fr3", franka=FrankaConfig(ip=HOST, stream=stream, home_dynamics=0.5)
    )
    c = robot_controller(cfg)
    c.reset()
    robot, b = c.backend.robot, c.backend
    # command -> motion, from rest
    lat_cmd, lat_meas = [], []
    for k in range(3):
        q = b.read_state().q
        t0 = robot.state.time.to_sec()
        b.send_joint_command(q + np.array([0.05 * (-1) ** k, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
        got_cmd = got_meas = None
        deadline = time.monotonic() + 2
        while time.monotonic() < deadline and (got_cmd is None or got_meas is None):
            s = robot.state
            t = s.time.to_sec() - t0
            if got_cmd is None and np.max(np.abs(s.dq_d)) > 0.01:
                got_cmd = t
            # measured: end-effector speed (franky-sim's joint 7 may report a residual spin at rest)
            if got_meas is None and np.linalg.norm(c.kin.ee_velocity(np.array(s.q), np.array(s.dq))) > 0.005:
                got_meas = t
        lat_cmd.append(got_cmd)
        lat_meas.append(got_meas)
        b.hold()
        time.sleep(1.0)
    c.reset()
    # streaming a circle
    sampler = Sampler(robot)
    sampler.start()
    chunk = circle_chunk()
    c.obey("bench")  # the bench is the learner (robot_io.command_gate)
    c.push_chunk("bench", 0, chunk, time.monotonic())
    targets, track = [], []
    next_tick = time.monotonic()
    t_start = robot.state.time.to_sec()
    for _ in range(len(chunk)):
        r = c.tick(time.monotonic())
        if targets:
            track.append(float(np.linalg.norm(r.state.ee_pos - targets[-1])))
        q_cmd = b.read_state().q_cmd
        targets.append(c.kin.ee_position(q_cmd) if q_cmd is not None else r.state.ee_pos)
        next_tick += PERIOD
        time.sleep(max(0.0, next_tick - time.monotonic()))
    t_end = robot.state.time.to_sec()
    wall = len(chunk) * PERIOD
    # hold -> still
    t_hold = robot.state.time.to_sec()
    b.hold()
    cmd_still = ee_still = None
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and ee_still is None:
        s = robot.state
        t = s.time.to_sec() - t_hold
        if cmd_still is None and np.max(np.abs(s.dq_d)) < 0.01:
            cmd_still = t
        ee_v = c.kin.ee_velocity(np.array(s.q), np.array(s.dq))
        if ee_still is None and np.linalg.norm(ee_v) < 0.005:
            ee_still = t
    sampler.stop.set()
    sampler.join()
    rows = [r for r in sampler.rows if t_start + 0.5 <= r[0] <= t_end]
    t = np.array([r[0] for r in rows])
    dq_d = np.array([r[2] for r in rows])
    keep = np.diff(t, prepend=-1) > 0  # one sample per robot tick
    t, dq_d = t[keep], dq_d[keep]
    acc = np.diff(dq_d, axis=0) / np.diff(t)[:, None]
    jerk = np.diff(acc, axis=0) / np.diff(t[1:])[:, None]
    speed = np.linalg.norm(dq_d, axis=1)
    c.close()
    return {
        "stream": stream,
        "sim_realtime_factor": round((t_end - t_start) / wall, 3),
        "command_to_motion_ms": {
            "commanded": [round(1000 * x, 1) if x is not None else None for x in lat_cmd],
            "measured": [round(1000 * x, 1) if x is not None else None for x in lat_meas],
        },
        "tracking_error_m": {
            "p50": pct(track[5:], 50),
            "p95": pct(track[5:], 95),
            "max": pct(track[5:], 100),
        },
        "commanded_joint_jerk_rad_s3": {
            "rms": round(float(np.sqrt(np.mean(jerk**2))), 1),
            "p99": pct(np.abs(jerk), 99),
        },
        "speed_dips_fraction": round(float(np.mean(speed < 0.3 * np.median(speed))), 3),
        "samples": int(len(t)),
        "hold_to_still_ms": {
            "commanded": round(1000 * cmd_still, 1) if cmd_still is not None else None,
            "end_effector": round(1000 * ee_still, 1) if ee_still is not None else None,
        },
    }


def recovery(server: FrankySimServer) -> dict:
    cfg = RobotConfig(backend="franka", model="fr3", franka=FrankaConfig(ip=HOST))
    c = robot_controller(cfg)
    server.kill()
    t0 = time.monotonic()
    while c.backend.fault() is None:
        c.backend.read_state()
        time.sleep(0.01)
    detect = time.monotonic() - t0
    server.start()
    t1 = time.monotonic()
    ok = c.backend.recover()
    out = {
        "fault": str(c.backend.fault() or "cleared"),
        "loss_detected_s": round(detect, 3),
        "recover_s": round(time.monotonic() - t1, 3),
        "recovered": ok,
    }
    c.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="results/franka_bench.json")
    args = parser.parse_args()
    server = FrankySimServer(HOST).start()
    try:
        modes = [run_mode(stream) for stream in ("rest", "velocity")]
        rec = recovery(server)
    finally:
        server.kill()
    result = {
        "simulator": "franky-sim 1.0.4 (MuJoCo FR3), franky-control 2.0.0, 20 Hz control, shared 2 cores",
        "modes": modes,
        "recovery_after_server_restart": rec,
    }
    out = Path(args.out)
    kept = json.loads(out.read_text()) if out.exists() else {}  # bench/franka_sim_stream.py's key stays
    out.write_text(json.dumps({**kept, **result}, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
