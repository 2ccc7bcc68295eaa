"""Does the hand stay inside ``robot.workspace`` on franky-sim? robot-io clips each *goal* into the box;
the hand follows the command with a lag and can overshoot it.

A scripted reacher (no learner) drives robot-io's controller in this process, through franky, against
franky-sim: each period it steps ``robot.max_step_m`` from the measured hand toward a goal, six goals in
turn (80 periods each), four of them 7-10 cm above the box's floor, as a policy heads for a low target.
Settings: the robot sections of ``configs/franka_sim.yaml`` (the rehearsal: franky's full dynamics) and of
``configs/gaps/franka_limits.yaml`` (the real arm's motion settings, ``franka_realsense.yaml``'s), each as
shipped and with the other ``franka.stream`` or a shorter ``command_lead_m``. Per setting: the share of
ticks the hand was more than 1 cm outside the box and how far at most, its lowest point, the periods to
come within 2 cm of each goal (``null``: not in 80), and the hand's largest distance from a goal once it
had arrived. Then homing while the hand moves down (from ``HIGH`` toward the table, robot-io's reset as the
hand passes ``HOMING_AT_Z``, as an episode that ends mid-motion): how far the hand went on down, out of
the box, and the seconds homing took.

    python bench/franky_box.py            # ~1 min a setting; results/franky_box.json, key burners_0
    python bench/franky_box.py --burn 2   # beside 2 busy loops (a loaded 2-core host): key burners_2

Load matters: the same settings beside a learning stack left the hand outside far more often (the note of
session 24: 58 % of ticks at the real arm's settings with the velocity stream, 2-4 % on a quiet host).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "bench")]
from franka_simulators import FrankySimServer  # noqa: E402
from handoff import outside_box  # noqa: E402  (a hand out of the box, counted as the handoff bench does)

from deploy.config import load_stack_config  # noqa: E402
from robot_io.config import RobotConfig  # noqa: E402
from robot_io.controller import RobotController  # noqa: E402

HOST = "127.0.77.9"
OUT = ROOT / "results" / "franky_box.json"
ARRIVED_M = 0.02
PERIODS = 80
GOALS = [(0.55, 0.25, 0.15), (0.4, -0.25, 0.4), (0.6, 0.2, 0.13), (0.35, 0.0, 0.45), (0.6, -0.25, 0.12)]
GOALS += [(0.45, 0.25, 0.35)]
HIGH, TABLE = (0.5, 0.0, 0.3), (0.6, 0.3, 0.0)
HOMING_AT_Z = 0.15  # 10 cm above the box's floor, where a hand heading down still has room
SETTINGS: dict[str, tuple[str, dict[str, Any]]] = {
    "rehearsal (franka_sim.yaml: stream rest, command_lead_m 0.05)": ("configs/franka_sim.yaml", {}),
    "rehearsal as until 2026-12-07 (stream velocity, command_lead_m 0.1)": (
        "configs/franka_sim.yaml",
        {"stream": "velocity", "command_lead_m": 0.1},
    ),
    "rehearsal, stream velocity, command_lead_m 0.05": (
        "configs/franka_sim.yaml",
        {"stream": "velocity", "command_lead_m": 0.05},
    ),
    "rehearsal, stream rest, command_lead_m 0.1": (
        "configs/franka_sim.yaml",
        {"stream": "rest", "command_lead_m": 0.1},
    ),
    "real arm's settings (franka_limits.yaml, stream rest)": ("configs/gaps/franka_limits.yaml", {}),
    "real arm's, stream velocity": ("configs/gaps/franka_limits.yaml", {"stream": "velocity"}),
    "real arm's, stream velocity, command_lead_m 0.05": (
        "configs/gaps/franka_limits.yaml",
        {"stream": "velocity", "command_lead_m": 0.05},
    ),
}


def robot_config(path: str, change: dict[str, Any]) -> RobotConfig:
    """The setting's robot section on franky-sim's address, with ``change`` (a stream or a command lead);
    no scripted target (the goals are the reacher's)."""
    robot = load_stack_config(ROOT / path).robot
    stream = {"stream": change["stream"]} if "stream" in change else {}
    franka = robot.franka.model_copy(update={"ip": HOST, "simulated_target": False, **stream})
    lead = {"command_lead_m": change["command_lead_m"]} if "command_lead_m" in change else {}
    return robot.model_copy(update={"franka": franka, **lead})


def step_toward(controller: RobotController, config: RobotConfig, goal: np.ndarray) -> np.ndarray:
    """One period of the scripted reacher: a step of ``max_step_m`` from the measured hand toward ``goal``;
    the hand after it."""
    t0 = time.monotonic()
    away = goal - controller.state().ee_pos
    controller.step_action(away * min(1.0, config.max_step_m / max(np.linalg.norm(away), 1e-9)))
    time.sleep(max(0.0, config.period - (time.monotonic() - t0)))
    return controller.state().ee_pos.copy()


def reach(
    controller: RobotController, config: RobotConfig, goals: list = GOALS
) -> tuple[np.ndarray, list, list[float]]:
    """The hand each period, the periods to arrive at each goal, and its distances to a goal once there."""
    hands, arrivals, after = [], [], []
    for goal in np.asarray(goals):
        arrived = None
        for k in range(PERIODS):
            hand = step_toward(controller, config, goal)
            hands.append(hand)
            if arrived is None and np.linalg.norm(goal - hand) < ARRIVED_M:
                arrived = k + 1
            if arrived is not None:
                after.append(float(np.linalg.norm(goal - hand)))
        arrivals.append(arrived)
    return np.array(hands), arrivals, after


def home_while_moving_down(controller: RobotController, config: RobotConfig) -> dict[str, Any]:
    """From ``HIGH``, step toward the table until the hand is down to ``HOMING_AT_Z``, then home (robot-io's
    reset) at once: how far the hand went on down, and the seconds homing took."""
    reach(controller, config, [HIGH])
    while step_toward(controller, config, np.asarray(TABLE))[2] > HOMING_AT_Z:
        pass
    start = controller.state()
    hands = [start.ee_pos.copy()]
    t0 = time.monotonic()
    controller.reset(while_homing=lambda state: hands.append(state.ee_pos.copy()))
    arm = np.array(hands)
    box = outside_box(arm, list(config.workspace.lo), list(config.workspace.hi))
    return {
        "hand_z_at_reset_m": round(float(start.ee_pos[2]), 3),
        "hand_down_speed_m_s": round(float(-start.ee_vel[2]), 3),
        "hand_min_z_m": round(float(arm[:, 2].min()), 3),
        "outside_box_max_m": box["hand_outside_box_max_m"],
        "seconds": round(time.monotonic() - t0, 1),
    }


def run(label: str, path: str, change: dict[str, Any]) -> dict[str, Any]:
    config = robot_config(path, change)
    controller = RobotController(config)
    try:
        controller.reset()
        hands, arrivals, after = reach(controller, config)
        homing = home_while_moving_down(controller, config)
    finally:
        controller.close()
    box = outside_box(hands, list(config.workspace.lo), list(config.workspace.hi))
    return {
        "setting": label,
        "config": path,
        "change": change,
        "command_lead_m": config.command_lead_m,
        "stream": config.franka.stream,
        "dynamics": list(config.franka.dynamics),
        **box,
        "hand_min_z_m": round(float(hands[:, 2].min()), 3),
        "box_floor_z_m": float(config.workspace.lo[2]),
        "periods_to_2cm": arrivals,
        "after_arrival_max_m": round(max(after), 3) if after else None,
        "homing_while_moving_down": homing,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", default=[], help="the settings whose names hold one of these")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--burn", type=int, default=0, help="busy loops beside the bench, as a loaded host")
    args = ap.parse_args()
    todo = {k: v for k, v in SETTINGS.items() if not args.only or any(w in k for w in args.only)}
    rows = []
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.burn)]
    try:
        for n, (label, (path, change)) in enumerate(todo.items(), 1):
            rows.append(run_on_franky_sim(n, len(todo), label, path, change))
    finally:
        for b in burners:
            b.kill()
    out = json.loads(args.out.read_text()) if args.out.exists() else {}
    out = {k: v for k, v in out.items() if k.startswith("burners_")}  # an older file's rows are gone
    out[f"burners_{args.burn}"] = {
        "command": " ".join(["python bench/franky_box.py", *sys.argv[1:]]),
        "rows": rows,
    }
    homing = {"homing_from": HIGH, "homing_toward": TABLE, "homing_at_z_m": HOMING_AT_Z}
    summary = {"periods_per_goal": PERIODS, "goals": GOALS, **homing}
    args.out.write_text(json.dumps(summary | dict(sorted(out.items())), indent=1))
    print(f"wrote {args.out}")
    return 0


def run_on_franky_sim(n: int, of: int, label: str, path: str, change: dict[str, Any]) -> dict[str, Any]:
    print(f"[{n}/{of}] {label}", flush=True)
    with FrankySimServer(HOST):  # each setting from the same start
        r = run(label, path, change)
    print(
        f"  outside the box {r['hand_outside_box_share']:.1%} of ticks, at most"
        f" {r['hand_outside_box_max_m'] * 100:.1f} cm; lowest z {r['hand_min_z_m']:.3f} m; periods to"
        f" 2 cm {r['periods_to_2cm']}; after arriving at most {r['after_arrival_max_m']} m",
        flush=True,
    )
    h = r["homing_while_moving_down"]
    print(
        f"  homing from z {h['hand_z_at_reset_m']:.3f} m, moving down at {h['hand_down_speed_m_s']} m/s:"
        f" lowest z {h['hand_min_z_m']:.3f} m, out of the box at most {h['outside_box_max_m'] * 100:.1f} cm,"
        f" {h['seconds']} s",
        flush=True,
    )
    return r


if __name__ == "__main__":
    raise SystemExit(main())
