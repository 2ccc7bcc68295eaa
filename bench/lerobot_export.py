"""How long ``adaptiveh export lerobot`` takes on a 6000-step recording with video.

1. The recording: ``--recording FILE`` or, by default, the one under ``runs/bench_lerobot/`` made by an
   earlier run of this bench; when there is none, this bench makes it: ``adaptiveh up`` on
   ``configs/sim.yaml`` (its own name, hub and folders) for ``--steps`` learning steps, with the
   operator's annotated camera image at the control rate (``vision.annotated.rate_hz`` = 20; the shipped
   2 Hz would give a video of mostly repeated images), so the video has a new image at about every
   tick. Making it takes the run's real time (6000 steps at 20 Hz: 5 minutes and more).
2. The export, timed: wall-clock seconds of ``monitor.lerobot_export.export`` (importing LeRobot and
   torch, reading, decoding and aligning the recording, LeRobot's writer with its mp4 encoding), into a
   fresh folder.

Writes ``results/lerobot_export.json``. Run: ``python bench/lerobot_export.py [--recording FILE]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]  # the tests' free-port helper (see stack_bench.py)
from loopback import free_endpoint, unique_name  # noqa: E402

from deploy.config import compose_stack_yaml  # noqa: E402

HOME = ROOT / "runs" / "bench_lerobot"
GOAL_S = 60.0


def make_recording(steps: int, home: Path = HOME) -> Path:
    """Run the stack for ``steps`` learning steps with the annotated image at 20 Hz; the recording."""
    cfg = compose_stack_yaml(str(ROOT / "configs" / "sim.yaml"))
    cfg["name"] = unique_name("lrbench")
    cfg["zenoh"]["hub"] = free_endpoint()
    cfg["learner"].update({"steps": steps, "checkpoint_dir": str(home / "learner")})
    cfg["vision"]["annotated"]["rate_hz"] = 20.0
    cfg["monitor"].update({"port": 0, "foxglove_port": 0})
    cfg["recording"]["dir"] = str(home / "recordings")
    home.mkdir(parents=True, exist_ok=True)
    path = home / "config.yaml"
    path.write_text(yaml.safe_dump(cfg))
    summary = home / "summary.json"
    cmd = [sys.executable, "-m", "deploy.cli", "up", str(path), "--summary", str(summary)]
    print(f"making the recording: {' '.join(cmd[2:])} ({steps} steps)", flush=True)
    subprocess.run([*cmd, "--log-level", "WARNING"], check=True, cwd=ROOT)
    return Path(json.loads(summary.read_text())["recording"])


def existing_recording(home: Path = HOME) -> Path | None:
    """The recording an earlier run of this bench made, if its run finished."""
    summary = home / "summary.json"
    if not summary.exists():
        return None
    path = Path(json.loads(summary.read_text())["recording"])
    return path if path.exists() else None


def measure(recording: Path, vcodec: str) -> dict[str, Any]:
    """Export ``recording`` into a fresh folder; wall-clock seconds and what was written."""
    from monitor.lerobot_export import export
    from tasks.reach import OBSERVATION_NAMES

    out = Path(tempfile.mkdtemp(prefix="lerobot_bench_")) / "dataset"
    try:
        t0 = time.perf_counter()
        report = export([recording], out, vcodec=vcodec, learner_names=OBSERVATION_NAMES)
        seconds = time.perf_counter() - t0
        size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    finally:
        shutil.rmtree(out.parent, ignore_errors=True)
    report.pop("out")  # a temporary folder, gone
    return {"seconds": round(seconds, 2), "dataset_mb": round(size / 1e6, 2), **report}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--recording", type=Path, default=None, help="export this recording instead")
    parser.add_argument("--steps", type=int, default=6000, help="steps of the recording this bench makes")
    parser.add_argument("--vcodec", default="libsvtav1", help="LeRobot's video codec (libsvtav1, h264)")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "lerobot_export.json")
    args = parser.parse_args()
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its whole configuration at every episode
    recording = args.recording or existing_recording() or make_recording(args.steps)
    result = {
        "recording": str(recording.relative_to(ROOT) if recording.is_relative_to(ROOT) else recording),
        "recording_mb": round(recording.stat().st_size / 1e6, 1),
        **measure(recording, args.vcodec),
        "goal_s": GOAL_S,
        "machine": {
            "cpu": platform.processor() or platform.machine(),
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "load_at_end": [round(x, 2) for x in os.getloadavg()],
        },
    }
    print(json.dumps(result, indent=1))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
