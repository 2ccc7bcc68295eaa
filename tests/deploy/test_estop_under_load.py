"""E-stop under load (issue #13): with the monitor hammered over HTTP and the learner stepping at the
control rate, the operator's e-stop has the arm still within 2 control periods in 100 of 100 trials.

The whole stack runs under ``adaptiveh up`` (robot-io on the PyBullet mock, vision, the AdaptiveH learner,
the monitor) on a private config, with its operator token. The learner steers by the simulator's target
(``sim/target_truth``, every tick) so that it steps at the control rate whatever the camera's delay; the
camera runs at 5 Hz (it renders on the CPU). For the whole test a separate, niced process hammers the
monitor from several threads, each as fast as the monitor answers: GETs of ``/api/state`` (the page's
snapshot), ``/`` and ``/api/image.jpg``, and POSTs of ``/api/control`` (release, resume, pause, jog)
with a wrong or missing token, which the monitor must refuse (403) and never put on the bus (an e-stop
needs no token since issue #31: a stranger's would really stop the arm, so the hammer sends none).

Each trial waits until the learner moves the arm (joint speed above ``MOVING``), waits a random part of a
control period (so the e-stop lands at every phase of robot-io's tick), then sends the e-stop the way the
operator's page does: ``POST /api/control`` with the token, which the monitor turns into a signed
``Control`` on the bus. The arm's reaction runs from robot-io taking the e-stop (the stamp of its e-stop
safety event) to the first state in mode ``estop`` with every joint speed below ``STILL`` (test_05's
stillness, ``tests/deploy/test_robot_io_node.py``), counted in robot-io's control ticks: at most 2, the
tick in progress included. On the wall clock that is 2 periods when robot-io's ticks come on time; on
a busy host they come late (the control thread asks for ``robot.control_thread_nice``), so the wall
time is printed and bounded by ``ROBOT_MAX_S``. The operator's time,
from just before the request to that state, includes the hammered monitor's HTTP and is bounded by
``OPERATOR_MAX_S``; both distributions are printed. The arm is kept e-stopped for ``HOLD_TICKS`` more
ticks, then released, and the learner must move it again.

Asserted: every e-stop's arm still within 2 control ticks of robot-io taking it (each slow trial is reported
with the time each hop took: TCP connect to the monitor, the monitor's Control on the bus, robot-io's
e-stop event, its ticks), and within ``OPERATOR_MAX_S`` of the operator's request; while e-stopped
every state stays still and within ``HOLD_Q_RAD`` of where it
stopped, no tick that began after the e-stop plays a chunk action (the tick in progress when it came
played the action it had taken before; counted) and no chunk is accepted; every monitor request answered
within ``HANG_S`` with its expected code (no 5xx, no connection error); no refused control on the bus;
the learner's chunks were on time (``learner_ticks``: a fresh chunk in closed loop, a plan's action in
plan mode) on ``ON_TIME_MIN`` of the steady running ticks; every part the same
process at the end. ``ADAPTIVEH_ESTOP_TRIALS`` changes the number of trials. About 60-100 s.
"""

from __future__ import annotations

import contextlib
import http.client
import json
import math
import multiprocessing as mp
import os
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections import Counter
from collections.abc import MutableSequence, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import numpy as np
import pytest
from bus_probe import BusProbe
from stack_helpers import parts_of, wait_for_parts, write_stack_config

from bus import messages as m
from bus.signing import mac_key
from bus.transport import Bus, open_session
from common.proc_status import cpu_seconds
from deploy.config import load_stack_config

pytestmark = pytest.mark.slow  # ~1 min of 100 trials under load: `.ci/run` runs it after the default run

TRIALS = int(os.environ.get("ADAPTIVEH_ESTOP_TRIALS", "100"))
MOVING = 0.3  # rad/s: the arm is moving (test_05 waits for this joint speed before its e-stop)
STILL = 0.01  # rad/s: the arm is still (test_05's criterion)
HOLD_TICKS = 3  # ticks the arm is kept e-stopped after it is still
HOLD_Q_RAD = 2e-3  # rad: how far a joint may creep while held (still: < STILL * period = 5e-4 a tick)
ROBOT_MAX_S = 0.5  # s: from robot-io taking the e-stop to the arm still, on the wall clock (late ticks)
OPERATOR_MAX_S = 1.0  # s: from the operator's request to the arm still, through the hammered monitor
HANG_S = 5.0  # s: a monitor request without an answer by then hangs
ON_TIME_MIN = 0.8  # of the steady running ticks, the share on time (learner_ticks: per execution mode)
# The hammer's threads: what each one requests, back to back.
HAMMER = ("state", "state", "state", "page", "image", "refused", "refused")
EXPECTED = {"state": {200}, "page": {200}, "image": {200, 204}, "refused": {403}}
REFUSED_COMMANDS = ("release", "resume", "pause", "jog")


# -- the hammer (its own process: the operator's requests and the test's clock keep their own GIL) -------
def _hammer_request(url: str, kind: str, i: int, token: str) -> urllib.request.Request:
    if kind == "state":
        return urllib.request.Request(url + "api/state")
    if kind == "page":
        return urllib.request.Request(url)
    if kind == "image":
        return urllib.request.Request(url + "api/image.jpg")
    body: dict[str, Any] = {"command": REFUSED_COMMANDS[i % len(REFUSED_COMMANDS)], "jog": [0.0, 0.01, 0.0]}
    headers = {"Content-Type": "application/json"}
    if i % 3 == 0:
        body["token"] = "not-" + token  # a wrong token in the body
    elif i % 3 == 1:
        headers["X-Token"] = token[:-1] + ("x" if token[-1] != "x" else "y")  # one character off
    # i % 3 == 2: no token at all
    return urllib.request.Request(url + "api/control", json.dumps(body).encode(), headers, method="POST")


def _hammer_thread(url: str, kind: str, token: str, stop: Any, out: dict[str, Any]) -> None:
    codes: Counter[int] = Counter()
    latencies: list[float] = []
    errors: list[str] = []
    i = 0
    while not stop.is_set():
        t0 = time.perf_counter()
        try:
            with urllib.request.urlopen(_hammer_request(url, kind, i, token), timeout=HANG_S) as r:
                r.read()
                codes[r.status] += 1
        except urllib.error.HTTPError as exc:
            exc.read()
            codes[exc.code] += 1
        except (urllib.error.URLError, OSError) as exc:  # refused, reset, timed out: not answered
            errors.append(f"{type(exc).__name__}: {exc}")
        latencies.append(time.perf_counter() - t0)
        i += 1
    out.update(kind=kind, codes=codes, errors=errors, latencies=latencies)


def hammer(url: str, token: str, kinds: Sequence[str], stop: Any, ready: Any, path: str) -> None:
    """Request ``kinds`` (one thread each) from the monitor at ``url`` until ``stop`` is set; write the
    count, codes, errors and latency quantiles of each kind to ``path`` (JSON)."""
    os.nice(10)  # the load is the monitor's: its clients stand in for browsers on other machines
    results: list[dict[str, Any]] = [{} for _ in kinds]
    threads = [
        threading.Thread(target=_hammer_thread, args=(url, k, token, stop, out), daemon=True)
        for k, out in zip(kinds, results, strict=True)
    ]
    t0 = time.time()
    for t in threads:
        t.start()
    ready.set()
    stop.wait()
    for t in threads:
        t.join(timeout=2 * HANG_S)
    summary: dict[str, Any] = {"t0": t0, "t1": time.time(), "kinds": {}}
    for kind in dict.fromkeys(kinds):
        mine = [r for r in results if r.get("kind") == kind]
        codes = sum((r["codes"] for r in mine), Counter())
        errors = [e for r in mine for e in r["errors"]]
        lat = np.asarray([x for r in mine for x in r["latencies"]] or [0.0])
        summary["kinds"][kind] = {
            "n": sum(codes.values()) + len(errors),
            "codes": {str(c): n for c, n in codes.items()},
            "errors": errors,
            "p50_s": float(np.percentile(lat, 50)),
            "p95_s": float(np.percentile(lat, 95)),
            "max_s": float(lat.max()),
        }
    Path(path).write_text(json.dumps(summary, indent=1))


# -- the operator ---------------------------------------------------------------------------------------
def post_control(url: str, token: str, command: str) -> tuple[int, dict[str, Any], float]:
    """What the monitor page's buttons do: POST /api/control with the operator token. Returns the HTTP
    code, the reply and how long the TCP connect took (a full listen queue shows as a 1 s SYN retry)."""
    parts = urlsplit(url)
    conn = http.client.HTTPConnection(parts.hostname or "127.0.0.1", parts.port, timeout=HANG_S)
    try:
        t0 = time.perf_counter()
        conn.connect()
        connect_s = time.perf_counter() - t0
        body = json.dumps({"command": command})
        conn.request("POST", "/api/control", body, {"Content-Type": "application/json", "X-Token": token})
        r = conn.getresponse()
        data = r.read()
        return r.status, json.loads(data) if r.status == 200 else {"error": data.decode()}, connect_s
    finally:
        conn.close()


def speed(s: m.RobotState) -> float:
    return max((abs(v) for v in s.dq), default=0.0)


def mode(s: m.RobotState) -> str:
    return m.label(s, "mode")


@dataclass
class Trial:
    """One e-stop; times in s from just before the operator's request (robot-io's stamps: wall clock)."""

    stop_s: float  # the robot's stamp on the first still e-stopped state
    stop_arrival_s: float  # that state's arrival here
    connect_s: float  # the operator's TCP connect to the monitor (not from the request's start)
    reply_s: float  # the monitor's answer
    control_s: float  # the monitor's stamp on its Control (put on the bus); NaN: it never arrived here
    event_s: float  # robot-io's stamp on its e-stop safety event (the e-stop taken); NaN: never arrived
    during_tick: bool  # the e-stop was taken while a tick computed: that tick did not brake
    in_progress_played: bool  # and that tick played the chunk action it had taken before the e-stop
    tick_gap_s: float  # the longest gap between robot-io's ticks from the request to the still state
    ticks_to_still: int  # ticks from the newest one before the request to the still one
    estop_ticks: int  # control ticks from robot-io taking the e-stop to the still state
    speed_at_request: float  # rad/s, the newest state's joint speed when the request went out
    held_chunks: int = 0  # learner chunks robot-io refused as held, from the e-stop to the release
    release_to_moving_s: float = 0.0  # release request -> the learner moving the arm again
    violations: list[str] = field(default_factory=list)

    @property
    def robot_stop_s(self) -> float:
        """From robot-io taking the e-stop (its event's stamp) to the still state: the arm's reaction."""
        return self.stop_s - self.event_s

    def why_slow(self, period: float) -> tuple[str, str]:
        """(cause, detail): the hop that took the time, from the timings (the first that applies)."""
        if self.connect_s > 0.5:
            return (
                "listen queue",
                f"TCP connect to the monitor took {self.connect_s:.3f} s (SYN dropped, retried)",
            )
        if self.control_s > period:
            return (
                "monitor",
                f"the monitor put the Control on the bus {self.control_s:.3f} s after the request",
            )
        if self.event_s - self.control_s > period:
            return (
                "robot-io take",
                f"robot-io took the e-stop {self.event_s - self.control_s:.3f} s after the bus",
            )
        if self.during_tick:
            return (
                "during tick",
                "the e-stop came while a tick computed, and that tick stepped without braking",
            )
        if self.tick_gap_s > 1.5 * period:
            return "late ticks", f"robot-io's ticks came late (a gap of {self.tick_gap_s:.3f} s)"
        return "unattributed", "no single hop above a period"


class Stack:
    """``adaptiveh up`` on a private config; its token, monitor URL, parts, and a probe on its bus."""

    def __init__(self, tmp_path: Path) -> None:
        # The learner steers by the simulator's target (robot-io publishes it every tick), so it steps at the
        # control rate however late the camera is: the sim camera renders on the CPU (50-130 ms a frame),
        # and on 2 shared cores a starved camera made the learner wait for a fresh fix (24 s of 83, measured).
        # The camera still runs, at 5 Hz (as in the monitor's browser test), as part of the load.
        self.path, _ = write_stack_config(
            tmp_path, "es", vision_rate_hz=5.0, steps=10**7, target_topic="sim/target_truth"
        )
        self.cfg = load_stack_config(self.path)
        self.period = self.cfg.robot.period
        self.up = subprocess.Popen(
            [sys.executable, "-m", "deploy.cli", "up", str(self.path)],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        self.lines: list[str] = []
        self._monitor = threading.Event()
        threading.Thread(target=self._drain, daemon=True).start()
        self.probe: BusProbe | None = None
        self.states: MutableSequence[Any] = []
        self.telemetry: MutableSequence[Any] = []
        self.controls: MutableSequence[Any] = []
        self.safety: MutableSequence[Any] = []
        self.statuses: MutableSequence[Any] = []
        self.learner_log = tmp_path / "logs" / "learner.log"  # adaptiveh up: <run dir>/logs/<part>.log

    def _drain(self) -> None:
        assert self.up.stdout is not None
        for line in self.up.stdout:  # read to the end: a full pipe would block the supervisor
            self.lines.append(line.rstrip("\n"))
            if line.startswith("monitor: "):
                self._monitor.set()

    def start(self) -> BusProbe:
        assert self._monitor.wait(90), f"no monitor URL from adaptiveh up: {self.lines}"
        self.token = self.lines[0].removeprefix("operator token: ")
        self.url = next(x for x in self.lines if x.startswith("monitor: ")).split(" ")[1].split("?")[0]
        assert len(self.token) >= 12 and self.url.startswith("http://127.0.0.1:"), self.lines
        self.pids = wait_for_parts(self.path, self.up)  # join once the supervisor holds the loopback hub
        self.restarts = 0  # learners that died and were restarted during the trials
        self.probe = BusProbe(Bus(open_session(self.cfg.zenoh), self.cfg.name, mac_key(self.token)))
        # With the stack's key: only what the stack signed (states, controls, learner progress).
        self.states = self.probe.collect(m.STATE)
        self.telemetry = self.probe.collect(m.TELEMETRY_LEARNER)
        self.controls = self.probe.collect(m.CONTROL)
        self.safety = self.probe.collect(m.EVENTS_SAFETY)
        self.statuses = self.probe.collect(m.CHUNK_STATUS)
        return self.probe

    def learner_error(self) -> str:
        """The last line of the learner's log that names an error or a warning, or its last line."""
        lines = (
            [x for x in self.learner_log.read_text().splitlines() if x.strip()]
            if self.learner_log.exists()
            else []
        )
        errors = [x for x in lines if "Error" in x or "WARNING" in x or "ERROR" in x]
        return (errors or lines or ["(no learner log)"])[-1][-300:]

    def stop(self) -> None:
        if self.probe is not None:
            self.probe.bus.close()
        self.up.send_signal(signal.SIGTERM)
        try:
            self.up.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.up.kill()
        for pid in parts_of(self.path).values():
            os.kill(pid, signal.SIGKILL)


def run_trial(stack: Stack, probe: BusProbe, rng: np.random.Generator) -> Trial:
    states, period = stack.states, stack.period
    # 1. The learner moves the arm; then a random phase of robot-io's tick.
    while True:
        probe.wait(lambda: moving_state(states[-1][1]), 10.0, "the learner moving the arm")
        time.sleep(rng.uniform(0.0, period))
        with probe.lock:
            last = states[-1][1]
            n_states, n_controls, n_events = len(states), len(stack.controls), len(stack.safety)
        if mode(last) == "running" and speed(last) > MOVING:  # not, e.g., an episode's reset meanwhile
            break
    # 2. The operator's e-stop.
    t_req = time.time()
    code, reply, connect_s = post_control(stack.url, stack.token, "estop")
    reply_s = time.time() - t_req
    assert code == 200 and reply.get("ok"), (code, reply)

    def still() -> tuple[float, m.RobotState] | None:
        return next(((t, s) for t, s in states[n_states:] if mode(s) == "estop" and speed(s) < STILL), None)

    t_still, s_still = probe.wait(still, 5.0, "a still e-stopped state")
    probe.wait(lambda: states[-1][1].tick >= s_still.tick + HOLD_TICKS, 5.0, "ticks while held")
    # The monitor's Control and robot-io's e-stop event, for the timings (a lost one is reported).
    controls = lambda: [c for _, c in stack.controls[n_controls:] if m.label(c, "command") == "estop"]  # noqa: E731
    events = lambda: [e for _, e in stack.safety[n_events:] if m.label(e, "kind") == "estop"]  # noqa: E731
    for what in (controls, events):
        with contextlib.suppress(AssertionError):
            probe.wait(what, 1.0, "the Control and the e-stop event")
    with probe.lock:
        before = [s for _, s in states[:n_states]]
        after = [s for _, s in states[n_states:]]
        control, event = next(iter(controls()), None), next(iter(events()), None)
    # 3. Held: a tick's own state is the first with its number; a state published between ticks (the
    # e-stop's, at once) repeats the number and what that tick played.
    i_estop = next(i for i, s in enumerate(after) if mode(s) == "estop")
    first_estop, held = after[i_estop], after[i_estop:]
    seen = {s.tick for s in before} | {s.tick for s in after[:i_estop]}
    during_tick = first_estop.tick not in seen
    violations: list[str] = []
    in_progress_played = False
    for s in held:
        if mode(s) != "estop":
            violations.append(f"tick {s.tick}: mode {mode(s)} while e-stopped")
        if s.tick not in seen:  # a tick that ended with the arm e-stopped
            seen.add(s.tick)
            if s.played_chunk >= 0 and s is first_estop:
                # The tick in progress when the e-stop came: robot-io took its action from the queue before
                # (a take checks the e-stop under the controller's lock), and played it. Reported, not a
                # violation; what it costs shows in the stop time.
                in_progress_played = True
            elif s.played_chunk >= 0:  # a tick that began after the e-stop was taken
                violations.append(f"tick {s.tick}: played chunk {s.played_chunk}[{s.played_index}] e-stopped")
        if s.chunk_seq != first_estop.chunk_seq or s.queue_len:
            violations.append(f"tick {s.tick}: chunk {s.chunk_seq} (queue {s.queue_len}) taken e-stopped")
    q_still = np.asarray(s_still.q)
    for s in held[held.index(s_still) :]:
        creep = float(np.abs(np.asarray(s.q) - q_still).max())
        if speed(s) >= STILL or creep > HOLD_Q_RAD:  # a jump at zero speed: the arm was put elsewhere
            ee = f"{np.round(s_still.ee_pos, 3).tolist()} -> {np.round(s.ee_pos, 3).tolist()} m"
            violations.append(
                f"tick {s.tick}: moved while e-stopped ({speed(s):.4f} rad/s, {creep:.3f} rad, {ee})"
            )
    ticks: dict[int, float] = {last.tick: last.stamp}
    for s in after[: after.index(s_still) + 1]:
        ticks.setdefault(s.tick, s.stamp)
    stamps = sorted(ticks.values())
    trial = Trial(
        stop_s=s_still.stamp - t_req,
        stop_arrival_s=t_still - t_req,
        connect_s=connect_s,
        reply_s=reply_s,
        control_s=control.stamp - t_req if control is not None else math.nan,
        event_s=event.stamp - t_req if event is not None else math.nan,
        during_tick=during_tick,
        in_progress_played=in_progress_played,
        tick_gap_s=float(np.diff(stamps).max()) if len(stamps) > 1 else 0.0,
        ticks_to_still=s_still.tick - last.tick,
        estop_ticks=s_still.tick - (first_estop.tick - during_tick),
        speed_at_request=speed(last),
        violations=violations,
    )
    # 4. Release: the learner moves the arm again.
    t_rel = time.time()
    with probe.lock:
        n_states = len(states)
        trial.held_chunks = sum(
            1 for t, c in stack.statuses if t >= t_req and m.label(c, "verdict") == "held"
        )
    code, reply, _ = post_control(stack.url, stack.token, "release")
    assert code == 200 and reply.get("ok"), (code, reply)
    again = lambda: any(moving_state(s) for _, s in states[n_states:])  # noqa: E731
    try:
        probe.wait(again, 30.0, "the learner moving the arm again")
    except AssertionError:
        learner = parts_of(stack.path).get("learn")
        if learner == stack.pids["learn"]:
            raise AssertionError(
                f"the learner did not move the arm 30 s after a release: {stack.learner_error()}"
            ) from None
        # The learner died (adaptiveh up restarts it): say why, and go on with the restarted one.
        trial.violations.append(f"the learner died after the release: {stack.learner_error()}")
        probe.wait(again, 90.0, "the restarted learner moving the arm")
        stack.pids["learn"] = parts_of(stack.path).get("learn", -1)
        stack.restarts += 1
    trial.release_to_moving_s = time.time() - t_rel
    return trial


def moving_state(s: m.RobotState) -> bool:
    """The learner moves the arm: running, playing a chunk of the obeyed session, faster than ``MOVING``."""
    return mode(s) == "running" and s.session != "" and s.played_chunk >= 0 and speed(s) > MOVING


def learner_ticks(
    states: Sequence[tuple[float, m.RobotState]], t0: float, t1: float, plan_mode: bool
) -> tuple[int, int, int]:
    """(running ticks, steady ones, steady ones on time) of the ticks that arrived between ``t0`` and
    ``t1``. In closed loop the learner sends one chunk a step and robot-io plays its first action at the
    next tick, so a tick playing a chunk's action 0 is a learner step on time (action 1 or more: the
    learner was late and the chunk's tail played). In plan mode a plan plays on by design: a tick is on
    time when it plays any action of a learner's plan (not a hold: the plan ran out before the next came).
    A tick is steady when the tick before it ran and played an action: not the first after a release (the
    learner's chunks were refused while held; it sends the next one on seeing ``running``) or after an
    episode's reset."""
    first: dict[int, m.RobotState] = {}
    for t, s in states:
        if t0 <= t <= t1 and s.tick not in first:
            first[s.tick] = s
    running = [s for s in first.values() if mode(s) == "running"]
    steady = [
        s
        for s in running
        if (p := first.get(s.tick - 1)) is not None and mode(p) == "running" and p.played_chunk >= 0
    ]
    fresh = [s for s in steady if s.played_chunk >= 0 and (plan_mode or s.played_index == 0)]
    return len(running), len(steady), len(fresh)


def listen_overflows() -> int:
    """The kernel's count of connections dropped on a full listen queue (this network namespace)."""
    rows = [x.split() for x in Path("/proc/net/netstat").read_text().splitlines() if x.startswith("TcpExt:")]
    return int(dict(zip(rows[0], rows[1], strict=True)).get("ListenOverflows", 0))


def quantiles(xs: Sequence[float]) -> dict[str, float]:
    """min, p50, p95, max of ``xs`` (NaN, a message that never arrived, left out)."""
    a = np.asarray([x for x in xs if not math.isnan(x)] or [math.nan], float)
    return {
        k: round(float(np.percentile(a, p)), 4)
        for k, p in (("min", 0), ("p50", 50), ("p95", 95), ("max", 100))
    }


def missing_ticks(states: Sequence[tuple[float, m.RobotState]]) -> int:
    """Ticks whose state never arrived here (robot-io publishes one a tick; Zenoh may drop under load)."""
    ticks = {s.tick for _, s in states}
    return max(ticks) - min(ticks) + 1 - len(ticks) if ticks else 0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_estop_under_load_stills_the_arm_within_two_periods_every_time(tmp_path: Path) -> None:
    t_test = time.monotonic()
    stack = Stack(tmp_path)
    ctx = mp.get_context("spawn")  # not fork: this process runs Zenoh's threads
    stop, ready = ctx.Event(), ctx.Event()
    hammer_out = tmp_path / "hammer.json"
    proc: Any = None
    trials: list[Trial] = []
    try:
        probe = stack.start()
        telemetry = stack.telemetry
        probe.wait(lambda: any(t.global_step > 20 for _, t in telemetry), 120, "the learner stepping")
        proc = ctx.Process(target=hammer, args=(stack.url, stack.token, HAMMER, stop, ready, str(hammer_out)))
        proc.start()
        assert ready.wait(60), "the hammer did not start"
        time.sleep(1.0)  # under load before the first trial
        rng = np.random.default_rng(13)
        pids = {**stack.pids, "supervisor": stack.up.pid, "hammer": proc.pid, "test": os.getpid()}
        cpu0, load0 = {k: cpu_seconds(p) or 0.0 for k, p in pids.items()}, os.getloadavg()[0]
        overflows0, t0 = listen_overflows(), time.time()
        with probe.lock:
            step0 = telemetry[-1][1].global_step
        for _ in range(TRIALS):
            trials.append(run_trial(stack, probe, rng))
        t1 = time.time()
        with probe.lock:
            step1 = telemetry[-1][1].global_step
            plan_mode = stack.cfg.learner.execution == "actor"  # plans play on by design
            running, steady, on_time = learner_ticks(list(stack.states), t0, t1, plan_mode)
            commands = Counter(m.label(c, "command") for _, c in stack.controls)
            lost_ticks = missing_ticks(list(stack.states))
        overflows = listen_overflows() - overflows0
        cpu = {k: round(((cpu_seconds(p) or 0.0) - cpu0[k]) / (t1 - t0), 3) for k, p in pids.items()}
        load1 = os.getloadavg()[0]
        stop.set()
        proc.join(timeout=4 * HANG_S)
        assert proc.exitcode == 0, f"the hammer ended with {proc.exitcode}"
        assert stack.up.poll() is None, f"adaptiveh up ended: {stack.lines[-20:]}"
        pids_after = parts_of(stack.path)
    finally:
        stop.set()
        if proc is not None and proc.is_alive():
            proc.join(timeout=4 * HANG_S)
            proc.kill()
        stack.stop()
    load = json.loads(hammer_out.read_text())
    bound = 2 * stack.period
    summary = {
        "trials": len(trials),
        "within_2_ticks": sum(t.estop_ticks <= 2 for t in trials),
        "within_2_periods_wall": sum(t.robot_stop_s <= bound for t in trials),
        "estop_ticks": dict(sorted(Counter(t.estop_ticks for t in trials).items())),
        "bound_s": bound,
        "robot_stop_s": quantiles([t.robot_stop_s for t in trials]),
        "stop_s": quantiles([t.stop_s for t in trials]),
        "stop_arrival_s": quantiles([t.stop_arrival_s for t in trials]),
        "connect_s": quantiles([t.connect_s for t in trials]),
        "monitor_reply_s": quantiles([t.reply_s for t in trials]),
        "control_on_bus_s": quantiles([t.control_s for t in trials]),
        "estop_event_s": quantiles([t.event_s for t in trials]),
        "estop_during_tick": sum(t.during_tick for t in trials),
        "estop_during_tick_played": sum(t.in_progress_played for t in trials),
        "tick_gap_s": quantiles([t.tick_gap_s for t in trials]),
        "ticks_to_still": dict(sorted(Counter(t.ticks_to_still for t in trials).items())),
        "release_to_moving_s": quantiles([t.release_to_moving_s for t in trials]),
        "monitor_requests_per_s": sum(k["n"] for k in load["kinds"].values()) / (load["t1"] - load["t0"]),
        "monitor": load["kinds"],
        "listen_overflows": overflows,
        "controls_on_bus": dict(commands),
        "learner_steps_per_s": (step1 - step0) / (t1 - t0),
        "learner_steps_per_running_s": (step1 - step0) / max(running * stack.period, 1e-9),
        "running_ticks": running,
        "steady_ticks": steady,
        "on_time_ticks": on_time,
        "lost_here": {
            "estop_controls": sum(math.isnan(t.control_s) for t in trials),
            "estop_events": sum(math.isnan(t.event_s) for t in trials),
            "tick_states": lost_ticks,
        },
        "held_chunks_per_estop": quantiles([t.held_chunks for t in trials]),
        "learner_restarts": stack.restarts,
        "cpu_cores_during_trials": cpu,  # each process's CPU time over the trials' wall time
        "machine_load_1min": [load0, load1],  # at the first and the last trial: 2 cores here
        "trials_s": t1 - t0,
        "test_s": time.monotonic() - t_test,
    }
    (tmp_path / "summary.json").write_text(json.dumps(summary, indent=1))
    (tmp_path / "trials.json").write_text(json.dumps([asdict(t) for t in trials], indent=1))
    print(json.dumps(summary, indent=1))
    failures: list[str] = []
    slow = [(i, *t.why_slow(stack.period), t) for i, t in enumerate(trials) if t.estop_ticks > 2]
    if slow:
        causes = dict(Counter(cause for _, cause, _, _ in slow))
        failures.append(
            f"{len(slow)} of {len(trials)} e-stops: the arm not still within 2 control ticks of robot-io"
            f" taking the e-stop (wall p50 {summary['robot_stop_s']['p50']:.3f} s, p95 "
            f"{summary['robot_stop_s']['p95']:.3f} s, max {summary['robot_stop_s']['max']:.3f} s); by cause "
            f"{causes}; e.g. "
            + "; ".join(f"#{i} {t.robot_stop_s:.3f} s: {detail}" for i, _, detail, t in slow[:6])
        )
    late = [t.stop_s for t in trials if t.stop_s > OPERATOR_MAX_S]
    if late:
        failures.append(f"{len(late)} e-stops still only {max(late):.3f} s after the operator's request")
    starved = [t.robot_stop_s for t in trials if not t.robot_stop_s <= ROBOT_MAX_S]
    if starved:
        failures.append(f"{len(starved)} e-stops still only {max(starved):.3f} s after robot-io took them")
    bad = [(i, t.violations) for i, t in enumerate(trials) if t.violations]
    if bad:
        failures.append(f"{len(bad)} trials with the arm not held while e-stopped: {bad[:5]}")
    for kind, s in load["kinds"].items():
        if not s["n"] or s["errors"]:
            failures.append(f"monitor {kind}: {len(s['errors'])} of {s['n']} not answered: {s['errors'][:3]}")
        if not {int(c) for c in s["codes"]} <= EXPECTED[kind]:
            failures.append(f"monitor {kind}: codes {s['codes']}, expected {sorted(EXPECTED[kind])}")
    if commands != {"estop": len(trials), "release": len(trials)}:
        failures.append(f"controls on the bus {dict(commands)}: not only the operator's")
    if on_time < ON_TIME_MIN * steady:
        failures.append(
            f"the learner's chunks were on time on only {on_time} of {steady} steady running ticks"
        )
    if pids_after != stack.pids or stack.restarts:
        failures.append(f"parts restarted ({stack.restarts} learner deaths): {stack.pids} -> {pids_after}")
    assert not failures, "\n".join(failures)
