"""Parts started alone on one machine reach each other over the loopback hub with no router.

Zenoh peers in the default ``peer_to_peer`` routing never forward for each other: before the fix a third
process that merely connected to the hub heard the hub's owner but never the other joiner. Each test
starts real processes on a free loopback hub port.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import yaml
from loopback import unique_name
from stack_helpers import learn_one_episode

from deploy.config import compose_stack_yaml

PROBE = r"""
import sys, time, threading
from bus.transport import ZenohConfig, open_session
hub, robot, me, others = sys.argv[1], sys.argv[2], sys.argv[3], set(sys.argv[4].split(","))
session = open_session(ZenohConfig(hub=hub))
heard, lock = set(), threading.Lock()
def on(sample):
    with lock:
        heard.add(sample.payload.to_bytes().decode())
sub = session.declare_subscriber(f"adaptiveh/{robot}/probe/*", on)
pub = session.declare_publisher(f"adaptiveh/{robot}/probe/{me}")
deadline, done_at = time.monotonic() + float(sys.argv[5]), None
while time.monotonic() < deadline:
    pub.put(me.encode())
    with lock:
        if others <= heard and done_at is None:
            done_at = time.monotonic()
    if done_at is not None and time.monotonic() - done_at > 2.0:  # keep talking so the others hear us
        break
    time.sleep(0.1)
print(",".join(sorted(heard - {me})), flush=True)
session.close()
"""


def test_three_processes_reach_each_other_without_a_router(endpoint):
    hub, robot = endpoint, unique_name("lp")
    names = ["a", "b", "c"]
    procs = []
    for name in names:
        others = ",".join(n for n in names if n != name)
        procs.append(
            subprocess.Popen(
                [sys.executable, "-c", PROBE, hub, robot, name, others, "20"],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
        )
        time.sleep(0.5)  # a takes the hub; b and c find it taken and join
    outs = [p.communicate(timeout=60) for p in procs]
    heard = {n: set(filter(None, o.strip().split(","))) for n, (o, _) in zip(names, outs, strict=True)}
    for n, p, (_, err) in zip(names, procs, outs, strict=True):
        assert p.returncode == 0, err[-2000:]
        assert heard[n] == set(names) - {n}, (n, heard, err[-1000:])


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "deploy.cli", *args]


def test_parts_started_alone_reach_each_other(tmp_path: Path, endpoint: str):
    """robot-io takes the hub; vision, monitor and learner join. Vision's target reaches the learner and
    the learner's retreats reach the monitor: joiner to joiner, which the old hub never carried."""
    cfg = compose_stack_yaml("configs/sim.yaml")
    cfg["name"] = unique_name("alone")
    cfg["zenoh"]["hub"] = endpoint
    cfg["vision"]["rate_hz"] = 5.0
    # The learner drives the arm itself here (closed loop): these are the parts a learner-side test needs.
    cfg["learner"].update(steps=60, checkpoint_dir=str(tmp_path / "l"), execution="closed_loop")
    cfg["monitor"]["port"] = 0
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(cfg))
    c = str(path)
    parts = [subprocess.Popen(_cli("robot-io", "--config", c, "--log-level", "WARNING"))]
    try:
        time.sleep(1.0)
        parts.append(subprocess.Popen(_cli("vision", "--config", c, "--log-level", "WARNING")))
        monitor = subprocess.Popen(
            _cli("monitor", "--config", c, "--log-level", "WARNING"), stdout=subprocess.PIPE, text=True
        )
        parts.append(monitor)
        url = monitor.stdout.readline().split(" ", 1)[1].split("?")[0].strip()
        res = learn_one_episode(Path(c), tmp_path / "l")
        with urllib.request.urlopen(url + "api/state", timeout=5) as r:
            state = json.loads(r.read())
        assert state["robot"]["mode"] in ("running", "held")  # robot-io -> monitor
        assert state["target"]  # vision -> monitor
        assert state["counts"]["segments"] >= len(res["segments"]) > 0  # learner -> monitor
        assert state["learner"]["step"] >= 50 and state["learner"]["algo"] == cfg["learner"]["algo"]
    finally:
        for p in reversed(parts):
            p.terminate()
            p.wait(timeout=20)
