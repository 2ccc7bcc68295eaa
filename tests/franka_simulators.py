"""Simulators speaking libfranka's network protocol, each as a child process on a loopback address: a
test and bench helper (imported by name, as ``loopback``; the benches put tests/ on ``sys.path``).

Tests and the benches run the simulator in its own process, as the real arm is its own machine: it can
be killed and restarted (a lost connection), and its Python 1 kHz loop does not share a GIL with
robot-io. libfranka always dials port 1337, so each server binds its own 127.x.y.z address and several
can run at once; a non-loopback address is refused.

- ``FrankySimServer``: PyPI ``franky-sim`` (MuJoCo FR3), installed in the main environment.
  ``franky-sim -s mujoco --hostname <address>`` is the package's own CLI (``-s mujoco`` because its
  ``auto`` choice fails when the optional genesis simulator is absent).
- ``FrankaSimServer``: PyPI ``franka-sim``, which also emulates the FCI's communication constraints
  (``control_command_success_rate``, the ``communication_constraints_violation`` reflex after 20 lost
  cycles in a row) and its motion limits (velocity, acceleration and jerk discontinuity reflexes). It
  pins numpy 1.26 and mujoco 3.2, so it runs from its own virtualenv (``scripts/franka_sim_venv.sh``
  makes ``.venv-franka-sim``). Its CLI binds all interfaces, so ``FRANKA_SIM_SERVE`` builds the server
  itself on the loopback address (its state socket too); ``$FR3_MJCF`` names the physics model, by
  default the FR3 that franky-sim ships. The child prints ``FRANKA_SIM_STATS {json}`` every
  ``stats_period_s``: commanded cycles, lost cycles and the longest run of them, the reflexes it aborted
  motions with, the peak commanded joint acceleration and jerk as fractions of its limits, and the
  published ``control_command_success_rate``; ``stats`` holds the latest.
"""

from __future__ import annotations

import importlib.util
import ipaddress
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
FRANKA_SIM_VENV = ROOT / ".venv-franka-sim"
STATS_PREFIX = "FRANKA_SIM_STATS "


def franky_sim_command(hostname: str) -> list[str]:
    exe = shutil.which("franky-sim") or str(Path(sys.executable).parent / "franky-sim")
    return [exe, "-s", "mujoco", "--hostname", hostname]


class SimServerProcess:
    """``start()`` waits until the child prints ``ready_marker``; ``kill()`` ends it without a goodbye."""

    name = "simulator"
    ready_marker = ""

    def __init__(self, hostname: str = "127.0.0.1", startup_timeout_s: float = 60.0) -> None:
        if not ipaddress.ip_address(hostname).is_loopback:
            raise ValueError(f"{self.name} serves on loopback addresses only, not {hostname}")
        self.hostname = hostname
        self.startup_timeout_s = startup_timeout_s
        self.proc: subprocess.Popen[str] | None = None
        self.output: list[str] = []

    def command(self) -> list[str]:
        raise NotImplementedError

    def env(self) -> dict[str, str] | None:
        return None  # inherit

    def on_line(self, line: str) -> bool:
        """Handle one output line; False keeps it out of ``output``."""
        return True

    def start(self) -> SimServerProcess:
        self.proc = subprocess.Popen(
            self.command(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=self.env()
        )
        ready = threading.Event()

        def read(proc: subprocess.Popen[str]) -> None:
            for line in proc.stdout:  # keep draining, so the server never blocks on a full pipe
                line = line.rstrip()
                if self.on_line(line):
                    self.output.append(line)
                if self.ready_marker in line:
                    ready.set()

        threading.Thread(target=read, args=(self.proc,), daemon=True).start()
        if not ready.wait(self.startup_timeout_s):
            self.kill()
            raise RuntimeError(f"{self.name} did not start:\n" + "\n".join(self.output[-30:]))
        return self

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self.proc = None

    def __enter__(self) -> SimServerProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.kill()


class FrankySimServer(SimServerProcess):
    """franky-sim (MuJoCo FR3), from the main environment."""

    name = "franky-sim"
    ready_marker = "Connect to the server"

    def command(self) -> list[str]:
        return franky_sim_command(self.hostname)


# Run by .venv-franka-sim's Python: argv = host, port, enforce (1/0), stats period (s), URDF path or "".
FRANKA_SIM_SERVE = r"""
import json, logging, socket, sys, threading, time
import franka_sim.comm_constraints as cc
import franka_sim.limits.checker as checker
import franka_sim.server.state_stream as state_stream
from franka_sim import FrankaSimServer

host, port, enforce, period, urdf = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1", float(sys.argv[4]), \
    sys.argv[5]
logging.basicConfig(level=logging.WARNING, stream=sys.stdout,
                    format="%(asctime)s %(levelname)s %(name)s: %(message)s")


class LoopbackSockets:
    # The state socket is left unbound by franka-sim (the kernel binds it to all interfaces on the
    # first send); bind it to the server's loopback address instead.
    def __getattr__(self, name):
        return getattr(socket, name)

    def socket(self, family=socket.AF_INET, type=socket.SOCK_STREAM, *args, **kwargs):
        sock = socket.socket(family, type, *args, **kwargs)
        if type == socket.SOCK_DGRAM:
            sock.bind((host, 0))
        return sock


state_stream.socket = LoopbackSockets()
stats = {"commanded_cycles": 0, "lost_cycles": 0, "max_consecutive_lost": 0, "reflexes": [], "connections": 0}
tick = cc.CommConstraintTracker.tick


def counted_tick(self, published_id):
    out = tick(self, published_id)
    if out.active:
        stats["commanded_cycles"] += 1
        if out.lost:
            stats["lost_cycles"] += 1
            stats["max_consecutive_lost"] = max(stats["max_consecutive_lost"], out.consecutive_lost)
    return out


cc.CommConstraintTracker.tick = counted_tick
peaks = stats["peak_fraction_of_limit"] = {"acceleration": 0.0, "jerk": 0.0}
units = {"rad/s^2": "acceleration", "rad/s^3": "jerk"}
check_per_joint = checker.MotionLimitChecker._check_per_joint


def peak_per_joint(self, values, limits, error_index, signal, unit):
    # the joint position interface's commanded signal, as the checker differences it, against its limits
    if signal == "q_c" and unit in units:
        key = units[unit]
        peaks[key] = max(peaks[key], max(abs(v) / lim for v, lim in zip(values, limits)))
    return check_per_joint(self, values, limits, error_index, signal, unit)


checker.MotionLimitChecker._check_per_joint = peak_per_joint


class Server(FrankaSimServer):
    def run_server(self):
        print("franka-sim ready on %s:%d" % (self.host, self.port), flush=True)
        super().run_server()

    def handle_client(self, client_socket):
        stats["connections"] += 1
        super().handle_client(client_socket)

    def _abort_with_error(self, error_index, reason, motion_id=0):
        if not motion_id or motion_id == self._motion_generation:  # else franka-sim ignores it
            stats["reflexes"].append({"time": time.time(), "reason": str(reason)})
        super()._abort_with_error(error_index, reason, motion_id)


srv = Server(host=host, port=port, enable_gripper=False, enforce_comm_constraints=enforce,
             enforce_motion_limits=enforce, urdf_path=urdf or None)


def report():
    while True:
        time.sleep(period)
        state = srv.robot_state.state
        rate = float(state.get("control_command_success_rate", 0.0))
        snap = dict(stats, reflexes=list(stats["reflexes"]), peak_fraction_of_limit=dict(peaks),
                    time=time.time(), control_command_success_rate=rate,
                    robot_mode=int(state.get("robot_mode", -1)))
        print("FRANKA_SIM_STATS " + json.dumps(snap), flush=True)


threading.Thread(target=report, daemon=True).start()
try:
    srv.start()
finally:
    srv.stop()
"""


def franky_sim_assets() -> Path:
    spec = importlib.util.find_spec("franky_sim")
    if spec is None or spec.origin is None:
        raise RuntimeError("franky-sim is not installed: set FR3_MJCF to a local FR3 MJCF instead")
    return Path(spec.origin).parent / "assets"


def franky_sim_fr3_urdf() -> Path:
    """The hand-less FR3 URDF franky-sim serves libfranka (the limits robot-io's fr3 description has)."""
    return franky_sim_assets() / "fr3_clean.urdf"


def franky_sim_fr3_mjcf(directory: Path) -> Path:
    """franky-sim's FR3 MJCF (arm and hand), written to ``directory`` with its mesh folder made absolute
    (the file names ``meshdir="assets"``; franky-sim rewrites it to ``assets/meshes`` when it loads it)."""
    assets = franky_sim_assets()
    text, n = re.subn(r'meshdir="[^"]*"', f'meshdir="{assets / "meshes"}"', (assets / "fr3.xml").read_text())
    if n != 1:
        raise RuntimeError(f"unexpected {assets / 'fr3.xml'}: {n} meshdir attributes")
    path = directory / "fr3.xml"
    path.write_text(text)
    return path


class FrankaSimServer(SimServerProcess):
    """franka-sim with the FCI's communication constraints and motion limits enforced (``enforce``).

    ``urdf`` is the arm model it hands libfranka (``GetRobotModel``); by default its own FR3 URDF
    (franka_description's, which libfranka ships as a test fixture). Its motion-limit tables are its own
    either way. ``fifo_priority`` runs it SCHED_FIFO (``chrt -f``; needs CAP_SYS_NICE): the arm is a
    real-time machine of its own, which a simulator sharing the robot PC's cores is not otherwise."""

    name = "franka-sim"
    ready_marker = "franka-sim ready on"

    def __init__(
        self,
        hostname: str = "127.0.0.1",
        startup_timeout_s: float = 90.0,
        venv: Path = FRANKA_SIM_VENV,
        enforce: bool = True,
        stats_period_s: float = 1.0,
        port: int = 1337,
        urdf: Path | None = None,
        fifo_priority: int | None = None,
    ) -> None:
        super().__init__(hostname, startup_timeout_s)
        self.python = Path(venv) / "bin" / "python"
        if not self.python.exists():
            raise RuntimeError(f"{self.python} is missing: run scripts/franka_sim_venv.sh")
        self.enforce = enforce
        self.stats_period_s = stats_period_s
        self.port = port
        self.urdf = urdf
        self.fifo_priority = fifo_priority
        self.stats: dict[str, Any] = {}
        self._mjcf_dir: tempfile.TemporaryDirectory[str] | None = None

    def command(self) -> list[str]:
        args = [self.hostname, str(self.port), "1" if self.enforce else "0", str(self.stats_period_s)]
        args.append(str(self.urdf) if self.urdf is not None else "")
        serve = [str(self.python), "-c", FRANKA_SIM_SERVE, *args]
        return serve if self.fifo_priority is None else ["chrt", "-f", str(self.fifo_priority), *serve]

    def env(self) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
        if not env.get("FR3_MJCF"):
            self._mjcf_dir = tempfile.TemporaryDirectory(prefix="franka-sim-")
            env["FR3_MJCF"] = str(franky_sim_fr3_mjcf(Path(self._mjcf_dir.name)))
        return env

    def on_line(self, line: str) -> bool:
        if line.startswith(STATS_PREFIX):
            self.stats = json.loads(line[len(STATS_PREFIX) :])
            return False
        return True

    def kill(self) -> None:
        super().kill()
        if self._mjcf_dir is not None:
            self._mjcf_dir.cleanup()
            self._mjcf_dir = None
