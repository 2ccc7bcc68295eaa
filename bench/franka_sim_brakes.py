"""Brakes while streaming, on franka-sim: how many end in a discontinuity reflex, at a given hold jerk.

The 10-minute learner stream (bench/franka_sim_stream.py) saw its reflexes 17-27 ms after a brake began
(2 of its 12 brakes, none in ~8000 streamed preemptions), so this bench brakes often: robot-io's franky
backend streams a joint sinusoid at 20 Hz (0.15 rad, 0.5 Hz on every joint: ~0.5 rad/s, ~1.5 rad/s^2)
for ``--stream-s``, brakes (``hold()``) and waits ``--hold-s``, ``--brakes`` times, against franka-sim
with its communication constraints and motion limits enforced. A reflex is recovered as the operator's
release would. ``--hold ACCEL,JERK`` replaces the acceleration and jerk fractions of the backend's
``HOLD_DYNAMICS``.

    bash scripts/franka_sim_venv.sh
    python bench/franka_sim_brakes.py --hold 0.8,0.3 --hold 0.8,0.1 --hold 0.5,0.3   # ~2.5 min each
    python bench/franka_sim_brakes.py --burn 3 --hold 0.8,0.3 --hold 0.4,0.3   # with 3 busy loops beside it

``--burn N`` runs N busy loops beside it: on a host without a real-time kernel that loses cycles, which is
when the reflexes come. Homing reflexes are counted apart (``home_faults``). Merged under
``franka_sim_brakes.burners_<N>`` into results/franka_bench.json, or written to ``--out`` instead.

Where and when the brake comes, to tell apart what makes a brake trip a reflex:

- by default each brake comes one period after the last streamed command (when the next one would be
  sent), at a zero crossing of the sinusoid with ``--stream-s 1`` (every joint at its peak speed, ~0.47
  rad/s, alternating direction); ``--stream-s 1.5`` alternates that with its peaks (at rest, ~1.5 rad/s^2);
- ``--hold-after-send S``: one more command is sent and the brake comes S seconds after it (mid-segment);
- ``--stop-room D``: as at a joint limit, the backend's joint limits are narrowed around the commanded
  position just for the brake, so ``hold()`` clips every joint's stop point to at most D rad beyond it
  (the natural stop at 0.47 rad/s is ~0.028 rad on); its limits are put back after.

    python bench/franka_sim_brakes.py --brakes 40 --stop-room 0 --out /tmp/brakes/stop_room_0.json
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]  # the tests' franka-sim launcher

from franka_simulators import FrankaSimServer, franky_sim_fr3_urdf  # noqa: E402

from robot_io.backends import franky_backend  # noqa: E402
from robot_io.backends.franky_config import FrankaConfig  # noqa: E402
from robot_io.config import RobotConfig  # noqa: E402

HOST = "127.0.0.64"
PERIOD = 0.05


def go_home(backend: Any, home: np.ndarray, home_faults: list[dict[str, Any]], t0: float) -> None:
    """Home the arm; a reflex on the way (a lost cycle while accelerating) is recorded, recovered, retried."""
    for _ in range(5):
        try:
            backend.reset(home, None)
            return
        except RuntimeError as exc:
            home_faults.append({"t_s": round(time.monotonic() - t0, 1), "error": str(exc).splitlines()[0]})
            backend.recover()
    raise RuntimeError("franka-sim: five reflexes in a row on the way home")


def brake(backend: Any, stop_room: float | None) -> None:
    """``hold()``; with ``stop_room``, its stop point clipped to within that of the commanded position."""
    if stop_room is None:
        backend.hold()
        return
    lower, upper = backend.lower, backend.upper
    q_d = np.asarray(backend.robot.state.q_d, float)
    backend.lower, backend.upper = np.maximum(lower, q_d - stop_room), np.minimum(upper, q_d + stop_room)
    try:
        backend.hold()
    finally:
        backend.lower, backend.upper = lower, upper


def run(
    hold: tuple[float, ...],
    brakes: int,
    stream_s: float,
    hold_s: float,
    hold_after_send: float | None = None,
    stop_room: float | None = None,
) -> dict[str, Any]:
    franky_backend.HOLD_DYNAMICS = (franky_backend.HOLD_DYNAMICS[0], *hold)
    cfg = RobotConfig(
        backend="franka",
        model="fr3",
        control_rate_hz=1 / PERIOD,
        franka=FrankaConfig(ip=HOST, realtime="ignore"),
    )
    with FrankaSimServer(HOST, urdf=franky_sim_fr3_urdf(), fifo_priority=99) as server:
        backend = franky_backend.FrankyBackend(cfg)
        home = np.asarray(cfg.home_q, float)
        faults, home_faults, t0 = [], [], time.monotonic()
        try:
            go_home(backend, home, home_faults, t0)
            for k in range(brakes):
                start = time.monotonic()

                def target(t: float, k: int = k) -> np.ndarray:
                    return home + 0.15 * np.sin(2 * np.pi * 0.5 * (t + k * stream_s))

                while (t := time.monotonic() - start) < stream_s:
                    backend.send_joint_command(target(t))
                    time.sleep(PERIOD - (time.monotonic() - start - t) % PERIOD)
                if hold_after_send is not None:
                    backend.send_joint_command(target(time.monotonic() - start))
                    time.sleep(hold_after_send)
                # A reflex while streaming (before the brake) is no brake's: told apart as "before_brake".
                before = backend.fault() is not None
                brake(backend, stop_room)
                time.sleep(hold_s)
                if (fault := backend.fault()) is not None:
                    faults.append(
                        {
                            "brake": k,
                            "t_s": round(time.monotonic() - t0, 1),
                            "kinds": list(fault.kinds),
                            "before_brake": before,
                        }
                    )
                    backend.recover()
                    go_home(backend, home, home_faults, t0)
                if k % 20 == 19:
                    print(f"  hold {hold}: {k + 1}/{brakes} brakes, {len(faults)} faults", flush=True)
            time.sleep(2 * server.stats_period_s)
            stats = dict(server.stats)
        finally:
            backend.close()
    return {
        "hold_dynamics": list(franky_backend.HOLD_DYNAMICS),
        "stream_s": stream_s,
        "hold_after_send_s": hold_after_send,
        "stop_room_rad": stop_room,
        "brakes": brakes,
        "faults": len(faults),
        "faults_before_brake": sum(f["before_brake"] for f in faults),
        "reflexes_franka_sim": [r["reason"] for r in stats.get("reflexes", [])],
        "lost_cycles": stats.get("lost_cycles"),
        "commanded_cycles": stats.get("commanded_cycles"),
        "fault_list": faults,
        "home_faults": home_faults,  # reflexes while homing (not braking): the same lost-cycle kind
        "wall_s": round(time.monotonic() - t0, 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--hold", action="append", default=[], metavar="ACCEL,JERK", help="HOLD_DYNAMICS fractions to try"
    )
    ap.add_argument("--brakes", type=int, default=100)
    ap.add_argument("--stream-s", type=float, default=1.0)
    ap.add_argument("--hold-s", type=float, default=0.4)
    ap.add_argument(
        "--burn", type=int, default=0, help="busy-loop processes beside it: lost cycles, as on a loaded host"
    )
    ap.add_argument(
        "--hold-after-send",
        type=float,
        default=None,
        metavar="S",
        help="brake S seconds after one more streamed command (default: one period after the last one)",
    )
    ap.add_argument(
        "--stop-room",
        type=float,
        default=None,
        metavar="D",
        help="clip each brake's stop point to within D rad of the commanded position, as at a joint limit",
    )
    ap.add_argument("--out", type=Path, default=None, help="write the result here, not into results/")
    args = ap.parse_args()
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.burn)]
    try:
        return report(args, burners)
    finally:
        for b in burners:
            b.kill()


def report(args: argparse.Namespace, burners: list[subprocess.Popen]) -> int:
    out = {
        "command": "python bench/franka_sim_brakes.py " + " ".join(sys.argv[1:]),
        "machine": {"cpus": os.cpu_count(), "load_at_start": os.getloadavg(), "burners": len(burners)},
        "runs": [
            run(
                tuple(float(x) for x in h.split(",")),
                args.brakes,
                args.stream_s,
                args.hold_s,
                args.hold_after_send,
                args.stop_room,
            )
            for h in (args.hold or [",".join(map(str, franky_backend.HOLD_DYNAMICS[1:]))])
        ],
    }
    for r in out["runs"]:
        reflexes = r["reflexes_franka_sim"]
        print(
            f"hold {r['hold_dynamics']} (stop room {r['stop_room_rad']}, "
            f"after send {r['hold_after_send_s']}): "
            f"{r['faults']} faults in {r['brakes']} brakes ({r['faults_before_brake']} before the brake), "
            f"{len(r['home_faults'])} homing; {r['lost_cycles']} cycles lost; {reflexes}"
        )
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(out, indent=1))
        return 0
    path = ROOT / "results" / "franka_bench.json"
    data = json.loads(path.read_text()) if path.exists() else {}
    data.setdefault("franka_sim_brakes", {})[f"burners_{len(burners)}"] = out
    path.write_text(json.dumps(data, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
