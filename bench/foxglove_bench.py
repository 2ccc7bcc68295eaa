"""What Foxglove's view costs: disk per minute of recording, and CPU of the live server.

1. Runs ``adaptiveh up`` on ``configs/sim.yaml`` (its own name, hub and folders) for ``--seconds`` of
   learning (control rate x seconds steps) and reads the recording: bytes per channel, raw against the
   derived Foxglove channels, scaled to one minute of the recording's own span.
2. Replays that recording (``adaptiveh replay --no-monitor --speed S``) onto a hub this process owns, three
   times: with only a Zenoh subscriber here (the baseline), with the Foxglove live server
   (``monitor.foxglove.live``) and no viewer, and with the server and a viewer subscribed to every channel
   (a separate process speaking Foxglove's WebSocket protocol, so its CPU is not counted). CPU is this
   process's user + system time (every thread, the SDK's included) per minute of recorded data.

Writes ``results/foxglove_bench.json``. Run: ``python bench/foxglove_bench.py [--seconds 60] [--speed 3]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import subprocess
import sys
import tempfile
import textwrap
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import yaml
from mcap.reader import make_reader

from bus.transport import ZenohConfig, open_session
from deploy.config import compose_stack_yaml, load_stack_config
from monitor.foxglove.derive import SceneSetup, is_derived
from monitor.foxglove.live import FoxgloveLive

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]  # the tests' free-port helper (see stack_bench.py)
from loopback import free_endpoint, unique_name  # noqa: E402

VIEWER = textwrap.dedent(
    """
    import asyncio, json, sys, websockets
    async def main():
        async with websockets.connect(sys.argv[1], subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
            subscribed, n, size = set(), 0, 0
            while True:
                frame = await ws.recv()
                if isinstance(frame, str):
                    op = json.loads(frame)
                    if op["op"] == "advertise":
                        new = [c["id"] for c in op["channels"] if c["id"] not in subscribed]
                        subscribed |= set(new)
                        subs = [{"id": i, "channelId": i} for i in new]
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                else:
                    n, size = n + 1, size + len(frame)
                    if n % 200 == 0:
                        print(n, size, flush=True)
    asyncio.run(main())
    """
)


def record(seconds: float, tmp: Path) -> tuple[Path, Path]:
    """A stack run of ``seconds`` of learning; returns (its config, its recording)."""
    cfg = compose_stack_yaml(ROOT / "configs/sim.yaml")
    cfg["name"] = unique_name("fxb")
    cfg["zenoh"]["hub"] = free_endpoint()
    cfg["monitor"].update(port=0, foxglove_port=0)
    cfg["recording"]["dir"] = str(tmp / "rec")
    cfg["learner"].update(
        checkpoint_dir=str(tmp / "learner"), steps=int(seconds * cfg["robot"]["control_rate_hz"])
    )
    path = tmp / "c.yaml"
    path.write_text(yaml.safe_dump(cfg))
    summary = tmp / "summary.json"
    up = [
        sys.executable,
        "-m",
        "deploy.cli",
        "up",
        str(path),
        "--summary",
        str(summary),
        "--log-level",
        "WARNING",
    ]
    subprocess.run(up, check=True, capture_output=True, timeout=seconds * 4 + 120)
    return path, Path(json.loads(summary.read_text())["recording"])


def disk(mcap: Path) -> dict[str, Any]:
    """Bytes per channel and per minute of the recording's span, raw against derived."""
    per: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    first = last = 0
    with open(mcap, "rb") as fh:
        for _, channel, message in make_reader(fh).iter_messages():
            per[channel.topic][0] += 1
            per[channel.topic][1] += len(message.data)
            first = min(first or message.log_time, message.log_time)
            last = max(last, message.log_time)
    span = (last - first) / 1e9
    scale = 60.0 / span
    derived = sum(b for t, (_, b) in per.items() if is_derived(t))
    raw = sum(b for t, (_, b) in per.items() if not is_derived(t))
    size = mcap.stat().st_size
    return {
        "span_s": round(span, 1),
        "file_bytes": size,
        "file_mb_per_min": round(size * scale / 1e6, 2),
        "raw_payload_mb_per_min": round(raw * scale / 1e6, 2),
        "derived_payload_mb_per_min": round(derived * scale / 1e6, 2),
        "channels": {
            t.split("/", 2)[2]: {"msgs_per_s": round(n / span, 1), "kb_per_min": round(b * scale / 1e3, 1)}
            for t, (n, b) in sorted(per.items(), key=lambda kv: -kv[1][1])
        },
    }


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def replay_cpu(config: Path, mcap: Path, speed: float, mode: str) -> dict[str, Any]:
    """CPU seconds of this process while the recording is replayed onto its hub, in ``mode``."""
    stack = load_stack_config(config)
    hub = free_endpoint()
    session = open_session(ZenohConfig(listen=(hub,)))
    robot = unique_name("fxr")
    received = [0]
    sub = session.declare_subscriber(
        f"adaptiveh/{robot}/**", lambda s: received.__setitem__(0, received[0] + 1)
    )
    live = viewer = None
    if mode != "baseline":
        live = FoxgloveLive(
            session, robot, SceneSetup.from_vision(stack.vision), port=0, exclude=stack.recording.exclude
        )
    if mode == "viewer":
        viewer = subprocess.Popen([sys.executable, "-c", VIEWER, live.url], stdout=subprocess.PIPE, text=True)
        time.sleep(1.0)
    cfg = compose_stack_yaml(config)
    cfg["zenoh"]["hub"] = hub  # this process listens there; the replay joins
    rcfg = config.with_name(f"replay-{mode}.yaml")
    rcfg.write_text(yaml.safe_dump(cfg))
    cmd = [sys.executable, "-m", "deploy.cli", "replay", str(mcap), "--config", str(rcfg), "--no-monitor"]
    cmd += ["--speed", str(speed), "--as", robot, "--log-level", "WARNING"]
    c0, t0 = cpu_s(), time.monotonic()
    subprocess.run(cmd, check=True, capture_output=True, timeout=600)
    time.sleep(0.5)
    cpu, wall = cpu_s() - c0, time.monotonic() - t0
    out: dict[str, Any] = {"received": received[0], "cpu_s": round(cpu, 2), "wall_s": round(wall, 1)}
    if live is not None:
        out["forwarded"] = live.count
        live.close()
    if viewer is not None:
        viewer.terminate()
        lines = viewer.communicate(timeout=10)[0].split()
        out["viewer_frames"], out["viewer_bytes"] = (int(lines[-2]), int(lines[-1])) if lines else (0, 0)
    sub.undeclare()
    session.close()
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=60.0, help="seconds of learning to record")
    p.add_argument("--speed", type=float, default=3.0, help="replay speed for the CPU runs")
    p.add_argument("--out", default=str(ROOT / "results/foxglove_bench.json"))
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        config, mcap = record(args.seconds, Path(tmp))
        result: dict[str, Any] = {"disk": disk(mcap), "cpu": {}}
        span_min = result["disk"]["span_s"] / 60.0
        for mode in ("baseline", "server", "viewer"):
            run = replay_cpu(config, mcap, args.speed, mode)
            run["cpu_s_per_recorded_min"] = round(run["cpu_s"] / span_min, 2)
            run["cpu_percent_of_a_core_at_real_rate"] = round(100 * run["cpu_s"] / (span_min * 60), 2)
            result["cpu"][mode] = run
            print(mode, run, flush=True)
    base = result["cpu"]["baseline"]["cpu_percent_of_a_core_at_real_rate"]
    for mode in ("server", "viewer"):
        cost = result["cpu"][mode]["cpu_percent_of_a_core_at_real_rate"] - base
        result["cpu"][mode]["added_percent_of_a_core"] = round(cost, 2)
    result["setup"] = {
        "config": "configs/sim.yaml",
        "seconds": args.seconds,
        "replay_speed": args.speed,
        "machine": f"{platform.machine()}, {platform.python_version()}, shared 2-core machine",
    }
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result["disk"], indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
