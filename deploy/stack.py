"""``adaptiveh up``: the whole stack on one machine, each part its own process, one Zenoh bus.

The supervisor opens the first Zenoh session (it owns the loopback hub the parts join), records every
message of the robot to MCAP, starts robot-io, vision, monitor and learner as ``python -m deploy.cli <part>``
subprocesses (logs under ``<run>/logs``), prints progress, and ends when the learner finishes its
steps, on Ctrl-C or on SIGTERM, stopping the parts in reverse order. The summary combines the
learner's ``result.json`` with what the supervisor saw on the bus (retreats, safety events).
"""

from __future__ import annotations

import importlib.util
import json
import logging
import os
import secrets
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import IO, Any

import numpy as np
import zenoh

from bus import messages as m
from bus.security import IDENTITY_ENV, PART_IDENTITY, zenoh_keys
from bus.signing import mac_key
from bus.transport import Bus, open_session
from common.heap import ALLOCATOR_ENV
from deploy.config import ConfigError, StackConfig, load_stack_config
from deploy.part_env import SUPERVISOR_ENV, TOKEN_ENV
from deploy.run_report import actor_counts_path, arm_summaries, by_quarter, learning_curve
from learner.run_summary import h_stats
from learner.segments import Execution
from monitor.foxglove.derive import Deriver, SceneSetup
from monitor.recording import Recorder, parts

log = logging.getLogger(__name__)


# Each part of ``adaptiveh up`` and its ``adaptiveh`` subcommand, in start order.
PART_COMMANDS = {
    "robot_io": "robot-io",
    "actor": "act",
    "vision": "vision",
    "monitor": "monitor",
    "learner": "learn",
}
ARM_PARTS = ("robot_io", "actor", "vision")  # one of each per arm of a fleet; the rest serve all arms
STOP_ORDER = ("learner", "actor", "monitor", "vision", "robot_io")  # the learner first: it checkpoints


def part_name(part: str, arm: str) -> str:
    """A part's name in the supervisor, its log and ``running_parts``: ``robot_io``, or ``robot_io@arm0``
    for an arm of a fleet."""
    return f"{part}@{arm}" if arm else part


def base_part(name: str) -> str:
    """``robot_io`` of ``robot_io@arm0``."""
    return name.split("@", 1)[0]


def running_parts(config: str | Path) -> dict[str, int]:
    """pid of every running ``deploy.cli <part command> --config <config>`` process, by part command
    (``robot-io@arm0`` for an arm of a fleet; Linux: reads /proc): what a stack, or its orphans, has
    running on this machine. A process whose parent runs the same part is that part's fork (a child
    between fork and exec still has the parent's command line), not the part."""
    commands, found = set(PART_COMMANDS.values()), {}
    for pid in filter(str.isdigit, os.listdir("/proc")):
        command = _part_command(int(pid), str(config))
        if (
            command is not None
            and base_part(command) in commands
            and (_part_command(_parent(int(pid)), str(config)) != command)
        ):
            found[command] = int(pid)
    return found


def _part_command(pid: int, config: str) -> str | None:
    """The part command of ``pid`` if it runs ``deploy.cli <command> ... <config>``; None otherwise."""
    try:
        args = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return None
    words = [a.decode(errors="replace") for a in args]
    if config in words and "deploy.cli" in words and words.index("deploy.cli") + 1 < len(words):
        command = words[words.index("deploy.cli") + 1]
        arm = words[words.index("--arm") + 1] if "--arm" in words[:-1] else ""
        return part_name(command, arm)
    return None


def _parent(pid: int) -> int:
    """``pid``'s parent (0 when it is gone): the field after the ``(comm)`` of /proc/<pid>/stat."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return 0
    return int(stat.rsplit(")", 1)[1].split()[1])


def private_log(path: Path, append: bool) -> IO[str]:
    """A part's log, readable by its owner only (0600): logs tell how the run went, which is the
    operator's business."""
    flags = os.O_WRONLY | os.O_CREAT | (os.O_APPEND if append else os.O_TRUNC)
    fh = os.fdopen(os.open(path, flags, 0o600), "a" if append else "w")
    os.fchmod(fh.fileno(), 0o600)  # one made before, with the default mode
    return fh


def check(
    config: str | Path, probe_arm: bool = False, policy_from: str | None = None
) -> tuple[bool, list[str]]:
    """Validate every section, look for the drivers the config needs and check the policy it would start
    from (``learner.policy_from``, or ``policy_from``); moves nothing."""
    try:
        cfg = load_stack_config(config, learner={"policy_from": policy_from})
    except ConfigError as exc:
        return False, [f"config error: {exc}"]
    camera = f"vision camera {cfg.vision.camera}" if cfg.vision is not None else "no vision"
    lines, ok = [f"config {config}: every section valid (robot backend {cfg.robot.backend}, {camera})"], True
    needs: list[tuple[str, str]] = []
    if cfg.robot.backend == "franka":  # model, driver, and the arm's version when it answers
        from robot_io.backends.franky_model import probe_arm as probe
        from robot_io.backends.realtime_host import host_report

        arm_ok, arm_lines = probe(cfg.robot.franka.ip, cfg.robot.model, connect=probe_arm)
        host_ok, host_lines = host_report(cfg.robot.franka)
        ok &= arm_ok and host_ok
        lines += arm_lines + host_lines
    if cfg.vision is not None and cfg.vision.camera == "realsense":
        needs.append(("pyrealsense2", "vision camera realsense: pip install pyrealsense2"))
    if cfg.zenoh.tls is not None or cfg.zenoh.auth is not None:  # each part's certificate and password
        parts = ["robot_io", "learner"] + [p for p in ("vision", "monitor") if getattr(cfg, p) is not None]
        parts += ["actor"] if cfg.learner.execution == Execution.ACTOR else []
        for identity in ["supervisor", *(PART_IDENTITY[p] for p in parts)]:
            try:
                zenoh_keys(cfg.zenoh, identity)
                lines.append(f"zenoh identity {identity}: certificate and credentials found")
            except ConfigError as exc:
                ok = False
                lines.append(f"MISSING for zenoh identity {identity}: {exc}")
    if cfg.learner.policy_from is not None:
        policy_ok, policy_line = _policy_report(cfg)
        ok &= policy_ok
        lines.append(policy_line)
    for module, why in needs:
        if importlib.util.find_spec(module) is None:
            ok = False
            lines.append(f"MISSING driver {module}: needed by {why}")
        else:
            lines.append(f"driver {module}: installed")
    lines.append("nothing was started and nothing moved" + ("" if ok else "; fix the MISSING items first"))
    return ok, lines


def _policy_report(cfg: StackConfig) -> tuple[bool, str]:
    """Whether the learner would start from ``learner.policy_from``, as it will check it, and the line
    that says so."""
    from deploy.handoff import REFUSED, check_policy_source

    source = cfg.learner.policy_from
    try:
        came = check_policy_source(cfg)
    except REFUSED as exc:  # as run() refuses it
        return False, f"MISSING a policy the learner accepts at {source}: {exc}"
    if came is None:
        return True, f"policy {source}: not used, the learner resumes {cfg.learner.checkpoint_dir}"
    arm = f", arm {came['arm']}" if came["arm"] else ""
    return True, f"policy {source}: accepted ({came['trained_on']}, {came['steps']} steps{arm})"


class Stack:
    """Start, watch and stop the parts; ``run()`` returns the summary dict."""

    def __init__(
        self,
        config: str | Path,
        run_dir: str | Path | None = None,
        token: str | None = None,
        steps: int | None = None,
        progress: bool = True,
        policy_from: str | None = None,
        python: str = sys.executable,
        arms: list[str] | None = None,
    ) -> None:
        """``arms``: run only these arms' parts (another machine's share of a fleet: no learner, no
        monitor); [] the learner and monitor only; None everything."""
        self.config = str(config)
        self.cfg = load_stack_config(config, learner={"policy_from": policy_from})
        for arm in arms or []:
            self.cfg.for_arm(arm)  # a ConfigError names an arm the fleet lacks
        self.arms = self.cfg.arm_names if arms is None else arms
        self.serves_fleet = arms is None or not arms  # the learner and monitor run here
        self.policy_from = policy_from
        self.name = self.cfg.name
        self.token = token or secrets.token_urlsafe(12)
        self.steps = steps
        self.progress = progress
        self.python = python
        self.recording = self.cfg.recording
        self.learner_dir = Path(self.cfg.learner.checkpoint_dir)
        self.run_dir = Path(run_dir) if run_dir else self.learner_dir.parent
        self.procs: dict[str, subprocess.Popen] = {}
        self.restarts: dict[str, int] = {}
        self.gave_up = ""  # the part that used its restarts, which ended the run
        self._stop = threading.Event()
        # What the summary needs, not the messages (kept, they grew the supervisor ~4 MB an hour).
        self.segment_h: Counter[int] = Counter()  # segments by length H (bounded: H <= h_max)
        self.reasons: Counter[str] = Counter()  # segments by why they closed
        self.safety_kinds: Counter[str] = Counter()
        self.telemetry: m.LearnerTelemetry | None = None  # the newest
        self.monitor_url = ""
        self.foxglove_url = ""  # the monitor's Foxglove live view, when it serves one
        self.recording_path: Path | None = None
        self.recording_lost: int | None = None  # messages the recorder missed and could not get back
        self.limits = self.cfg.view_limits()
        self.bus: Bus | None = None  # the supervisor's own, while it runs
        self.handoff: dict[str, Any] | None = None  # what learner.policy_from hands over (checked at start)

    def part_commands(self) -> dict[str, list[str]]:
        """Each part's command line, in start order (an arm's parts per arm). The token is not on it
        (``ps`` shows argv to every local user): it reaches the parts through their environment
        (``part_environment``)."""
        actor = self.cfg.learner.execution == Execution.ACTOR
        wanted = {
            "robot_io": True,
            "actor": actor,
            "vision": self.cfg.vision is not None,
            "monitor": self.cfg.monitor is not None and self.serves_fleet,
            "learner": self.serves_fleet,
        }
        extra: dict[str, list[str]] = {part: [] for part in PART_COMMANDS}
        if actor:  # the actor commands the arm; the learner may come and go
            extra["robot_io"] += ["--watch", "actor"]
        if self.steps is not None:
            extra["learner"] += ["--steps", str(self.steps)]
        if self.policy_from is not None:
            for part in ("learner", "actor"):
                extra[part] += ["--policy-from", self.policy_from]
        cmds: dict[str, list[str]] = {}
        for arm in self.arms:
            for part in ARM_PARTS:
                if wanted[part]:
                    cmds[part_name(part, arm)] = [
                        PART_COMMANDS[part],
                        *extra[part],
                        *(["--arm", arm] if arm else []),
                    ]
        for part in ("monitor", "learner"):
            if wanted[part]:
                cmds[part] = [PART_COMMANDS[part], *extra[part]]
        base = [self.python, "-m", "deploy.cli"]
        tail = ["--config", self.config, "--log-level", "WARNING"]
        return {part: [*base, *args, *tail] for part, args in cmds.items()}

    def part_environment(self, part: str | None = None) -> dict[str, str]:
        """The parts' environment; ``part``'s own Zenoh identity (its certificate on a secured bus). The
        allocator settings (``common.heap``) apply unless this process's environment sets them."""
        env = {
            **ALLOCATOR_ENV,
            **os.environ,
            "PYTHONUNBUFFERED": "1",
            SUPERVISOR_ENV: str(os.getpid()),
            TOKEN_ENV: self.token,
        }
        if part is not None:
            env[IDENTITY_ENV] = PART_IDENTITY[base_part(part)]
        return env

    def spawn(self, part: str) -> None:
        """Start ``part`` with its output in ``<run>/logs/<part>.log``, 0600 in a 0700 folder when new."""
        logs = self.run_dir / "logs"
        logs.mkdir(mode=0o700, parents=True, exist_ok=True)
        with private_log(logs / f"{part}.log", append=part in self.restarts) as fh:  # the child has its copy
            self.procs[part] = subprocess.Popen(
                self.part_commands()[part],
                stdout=fh,
                stderr=subprocess.STDOUT,
                env=self.part_environment(part),
                start_new_session=True,
            )
        nice = self.cfg.supervisor.nice.get(base_part(part), 0)
        if nice and hasattr(os, "setpriority"):
            os.setpriority(os.PRIO_PROCESS, self.procs[part].pid, nice)
        log.info("started %s (pid %d, nice %d)", part, self.procs[part].pid, nice)

    def _restart_or_end(self, part: str, code: int) -> bool:
        """Bring back a part that exited (True), after a doubling back-off; False once it used its restarts.

        Meanwhile the arm is safe on its own: robot-io holds while the learner's liveliness token is
        gone, and without a valid target the learner does not step. The recording shows the gap.
        """
        used = self.restarts.get(part, 0)
        sup = self.cfg.supervisor
        if used >= sup.max_restarts:
            log.error("%s exited (code %s) and used its %d restarts; ending the run", part, code, used)
            return False
        wait = min(sup.backoff_s * 2**used, sup.backoff_max_s)
        n = sup.max_restarts
        log.warning("%s exited (code %s); restart %d of %d in %.1f s", part, code, used + 1, n, wait)
        print(f"{part} exited (code {code}); restarting in {wait:.1f} s", flush=True)
        self.restarts[part] = used + 1
        if self._stop.wait(wait):
            return False
        self.spawn(part)
        return True

    def request_stop(self) -> None:
        self._stop.set()

    def _wait_monitor_url(self, timeout: float = 30.0) -> None:
        """The page's and Foxglove's URLs from monitor.log, any query dropped: the URL printed here gets
        copied into bookmarks and notes, so it must never carry a token."""
        path = self.run_dir / "logs" / "monitor.log"
        deadline = time.monotonic() + timeout
        live = self.cfg.monitor is not None and self.cfg.monitor.foxglove_port is not None
        while time.monotonic() < deadline and not (self.monitor_url and (self.foxglove_url or not live)):
            if self.procs["monitor"].poll() is not None:
                return  # it died at start: the main loop restarts it or ends the run
            for line in path.read_text().splitlines() if path.exists() else []:
                if line.startswith("monitor: ") and not self.monitor_url:
                    self.monitor_url = line.split(" ", 1)[1].split("?")[0]
                    deadline = min(deadline, time.monotonic() + 2.0)  # its Foxglove URL follows, if started
                elif line.startswith("foxglove: "):
                    self.foxglove_url = line.split(" ", 1)[1]
            time.sleep(0.2)

    def run(self) -> dict[str, Any]:
        from deploy.handoff import REFUSED, check_policy_source  # the learner's own check, loaded when run

        try:
            self.handoff = check_policy_source(self.cfg)
        except REFUSED as exc:
            raise RuntimeError(str(exc)) from None
        zc = self.cfg.zenoh
        if not (zc.connect or zc.listen) and zc.mode == "peer" and self.serves_fleet:
            # The supervisor owns the loopback hub; the parts join through it and gossip makes a full mesh
            # of peers (bus.transport). A hub already taken means another stack is running here. A
            # supervisor of some arms only joins the hub of the one that runs the learner.
            zc = zc.model_copy(update={"listen": (zc.hub,)})
        try:
            session = open_session(zc)
        except zenoh.ZError as exc:
            raise RuntimeError(
                f"cannot open the Zenoh bus ({exc}); if {zc.hub} is taken another stack runs here:"
                " stop it or set zenoh.hub to a free port"
            ) from None
        # With the stack's key: the progress line and the summary believe only what the parts signed.
        bus = self.bus = Bus(session, self.name, mac_key(self.token))
        recorder = None
        if self.recording.enabled:
            self.recording_path = (
                Path(self.recording.dir) / f"{self.name}-{time.strftime('%Y%m%d-%H%M%S')}.mcap"
            )
            recorder = Recorder(
                bus.session,
                self.name,
                self.recording_path,
                self.recording.exclude,
                deriver=Deriver(self.name, SceneSetup.from_vision(self.cfg.vision), self.limits),
                flush_s=self.recording.flush_s,
                split_s=self.recording.split_s,
                key=bus.signing_key,
                arms=tuple(a for a in self.cfg.arm_names if a),
            )
        bus.subscribe(m.EVENTS_RETREAT, self._on_segment, check=self.limits.problem)
        bus.subscribe(m.EVENTS_SAFETY, lambda e: self.safety_kinds.update([m.label(e, "kind")]))
        bus.subscribe(m.TELEMETRY_LEARNER, self._on_telemetry)
        t0 = time.monotonic()
        try:
            for part in self.part_commands():
                self.spawn(part)
                if part == "monitor":
                    self._wait_monitor_url()
                    print(f"monitor: {self.monitor_url}", flush=True)
                    if self.foxglove_url:
                        print(f"foxglove: {self.foxglove_url} (Foxglove: Open connection)", flush=True)
            last = 0.0
            while not self._stop.is_set():
                if "learner" in self.procs and self.procs["learner"].poll() == 0:
                    break  # the learner did its steps: the run is complete
                dead = [(p, proc.returncode) for p, proc in self.procs.items() if proc.poll() is not None]
                self.gave_up = next((part for part, code in dead if not self._restart_or_end(part, code)), "")
                if self.gave_up:
                    log.error("see %s", self.run_dir / "logs")
                    break
                if self.progress and time.monotonic() - last > 5.0:
                    last = time.monotonic()
                    print(self._progress_line(time.monotonic() - t0), flush=True)
                self._stop.wait(0.2)
        finally:
            self.stop_parts()
            if recorder is not None:
                recorder.close()
                self.recording_lost = recorder.lost
            bus.close()
        return self._write_report(self.summary(time.monotonic() - t0))

    def _write_report(self, summary: dict[str, Any]) -> dict[str, Any]:
        """The summary as JSON and the learning curve as PNG, beside the recording (else the run's folder)."""
        stem = self.recording_path.with_suffix("") if self.recording_path else self.run_dir / self.name
        result_path = Path(summary["learner_result"])
        result = json.loads(result_path.read_text()) if result_path.exists() else {}
        curve = learning_curve(result, stem.with_name(stem.name + ".learning.png"))
        summary["learning_curve"] = str(curve) if curve else None
        path = summary["summary_file"] = str(stem.with_name(stem.name + ".summary.json"))
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps(summary, indent=1))
        return summary

    def _on_segment(self, e: m.RetreatEvent) -> None:
        self.segment_h.update([e.H])
        self.reasons.update([m.label(e, "reason")])

    def _on_telemetry(self, t: m.LearnerTelemetry) -> None:
        if self.telemetry is None or t.global_step >= self.telemetry.global_step:
            self.telemetry = t

    def _progress_line(self, elapsed: float) -> str:
        tel, segments = self.telemetry, self.segment_h.total()
        retreats = self.reasons["retreat"]
        if tel is None:
            return f"[{elapsed:5.0f} s] waiting for the first episode; segments {segments}"
        return (
            f"[{elapsed:5.0f} s] step {tel.global_step} episode {tel.episode} return {tel.episode_return:.2f}"
            f" success {tel.success} | retreats {retreats} of {segments} segments"
            f" | safety events {self.safety_kinds.total()}"
        )

    def stop_parts(self) -> None:
        """SIGTERM learner first (it checkpoints), then the rest; SIGKILL whatever ignores it."""
        for part in sorted(self.procs, key=lambda name: STOP_ORDER.index(base_part(name))):
            proc = self.procs[part]
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    log.warning("%s ignored SIGTERM; killing it", part)
                    proc.kill()
                    proc.wait()

    def summary(self, wall: float) -> dict[str, Any]:
        result_path = self.learner_dir / "result.json"
        result = json.loads(result_path.read_text()) if result_path.exists() else {}
        actors = {arm: _read_json(actor_counts_path(self.learner_dir, arm)) for arm in self.arms}
        actor = actors.get("", {})  # execution actor, one arm: the plans' account is the actor's
        eps = result.get("episodes", [])
        succ = [bool(e.get("success")) for e in eps]
        H = sorted(self.segment_h.elements())
        fleet_counts = _summed(list(actors.values())) if self.cfg.fleet is not None else actor
        return {
            "wall_clock_s": wall,
            "episodes": len(eps),
            "global_step": result.get("global_step", 0),
            "success_rate_by_quarter": by_quarter(succ),
            "success_rate": float(np.mean(succ)) if succ else None,
            "segments": len(H),
            "reasons": dict(self.reasons),
            "H": h_stats(H) if H else None,
            "dropped_actions": fleet_counts.get("dropped_planned", result.get("dropped_actions")),
            "retreat_preemptions": fleet_counts.get("retreat_preemptions", result.get("retreat_preemptions")),
            "retreat_dropped": fleet_counts.get("retreat_dropped", result.get("retreat_dropped")),
            "arms": arm_summaries(eps, actors) if self.cfg.fleet is not None else None,
            "actor": actor or None,
            "started_from": result.get("started_from") or self.handoff,
            "safety_events": dict(self.safety_kinds),
            # Unsigned, replayed, undecodable or out-of-range messages the supervisor did not count
            "rejected_messages": dict(self.bus.bad_messages) if self.bus is not None else {},
            "recording": str(self.recording_path) if self.recording_path else None,
            "recording_parts": [str(p) for p in parts(self.recording_path)] if self.recording_path else None,
            "recording_lost": self.recording_lost,
            "learner_result": str(result_path),
            "exit_codes": {p: proc.returncode for p, proc in self.procs.items()},
            "restarts": dict(self.restarts),
            "gave_up": self.gave_up or None,
        }


def _read_json(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text()) if path.exists() else {}


def _summed(counts: list[dict[str, Any]]) -> dict[str, int]:
    """The integer counts of several arms' actors, added up."""
    total: Counter[str] = Counter()
    for c in counts:
        total.update({k: v for k, v in c.items() if isinstance(v, int) and not isinstance(v, bool)})
    return dict(total)
