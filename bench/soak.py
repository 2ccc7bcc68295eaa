"""Soak (issue #13): the whole simulated stack for an hour, watched from a separate Zenoh peer.

Run: ``python bench/soak.py [--duration 3600] [--interval 10] [--keep]`` (a 120 s try: ``--duration 120``).

Starts ``adaptiveh up`` on ``configs/sim.yaml`` made private (its own robot name and free hub port, the
monitor on port 0, recording and checkpoints under a temporary run directory, more learner steps than the
run can do) as a subprocess, and joins its hub as one more peer, so the bench observes the stack as any
operator would. Every ``--interval`` s it samples each process's memory and CPU (/proc), the load
average, message rates and per-publisher ``seq`` gaps on every key, latencies (publisher stamp to
arrival; a chunk's stamp to the robot tick that played its first action; that tick to the learner's next
chunk), the learner's steps, episodes and success, restarts and safety events. Then it stops the stack
with SIGTERM, checks the MCAP recording for ``seq`` gaps on the same keys, fits each process's RSS slope
over each half of the run, prints a summary and writes ``results/soak.json`` and ``results/soak.png``.
``--replot`` runs nothing and redraws the figure from the JSON at ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.reader import make_reader

from bus import messages as m
from bus.transport import Bus, ZenohConfig, open_session, wait_listening
from deploy.config import compose_stack_yaml
from deploy.stack import PART_COMMANDS, running_parts
from monitor.recording import REJECTED, parts

ROOT = Path(__file__).resolve().parents[1]
PARTS = {command: part for part, command in PART_COMMANDS.items()}  # robot-io -> robot_io, ...
# Every key of the schema but raw camera frames (not published by the sim camera, not recorded).
WATCHED = [t for t in m.TOPICS.values() if t is not m.CAMERA]
RESET_PAIR_S = 1.0  # a state-to-chunk wait longer than this is an episode reset, counted apart
CLK_TCK = os.sysconf("SC_CLK_TCK")


# -- the stack ----------------------------------------------------------------------------------------
def free_endpoint() -> str:
    """A loopback Zenoh endpoint on a port the kernel just handed out (free at this moment)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def private_config(run_dir: Path, steps: int, options: dict[str, Any]) -> tuple[Path, dict[str, Any]]:
    """``configs/sim.yaml`` made private to this run, so it never meets another stack on this machine;
    ``options``: extra Zenoh config keys for every part (experiments; the soak is of the stock config)."""
    cfg = compose_stack_yaml(ROOT / "configs/sim.yaml")
    cfg["name"] = f"soak{uuid.uuid4().hex[:12]}"
    cfg["zenoh"]["hub"] = free_endpoint()
    if options:
        cfg["zenoh"]["options"] = {**cfg["zenoh"].get("options", {}), **options}
    cfg["monitor"]["port"] = 0
    cfg["monitor"]["foxglove_port"] = 0
    cfg["recording"]["dir"] = str(run_dir / "rec")
    cfg["learner"].update(steps=steps, checkpoint_dir=str(run_dir / "learner"))
    path = run_dir / "soak.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path, cfg


def start_stack(config: Path, run_dir: Path) -> subprocess.Popen:
    """``adaptiveh up`` as a subprocess; its output goes to ``<run>/up.log``."""
    cmd = [sys.executable, "-m", "deploy.cli", "up", str(config), "--summary", str(run_dir / "summary.json")]
    with open(run_dir / "up.log", "w") as log:  # the child keeps its own copy of the descriptor
        return subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)


def stop_stack(proc: subprocess.Popen, timeout: float = 180.0) -> int:
    """SIGTERM (a clean stop: the learner checkpoints, the recording is finished); SIGKILL if it hangs."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


def parts_of(config: Path) -> dict[str, int]:
    """pid of each part of the stack, by its name here (robot_io, learner, ...)."""
    return {PARTS[command]: pid for command, pid in running_parts(config).items()}


# -- /proc --------------------------------------------------------------------------------------------
def proc_stats(pid: int) -> dict[str, float] | None:
    """RSS and peak RSS (MB), threads, open fds and CPU time (s) of ``pid``; None once it is gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text().splitlines()
        stat = Path(f"/proc/{pid}/stat").read_text()
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None
    fields = dict(line.split(":", 1) for line in status if ":" in line)
    kb = {k: int(fields[k].split()[0]) for k in ("VmRSS", "VmHWM") if k in fields}
    ticks = stat.rsplit(")", 1)[1].split()  # after the command name: state is field 3, utime 14, stime 15
    return {
        "rss_mb": kb.get("VmRSS", 0) / 1024,
        "hwm_mb": kb.get("VmHWM", 0) / 1024,
        "threads": int(fields.get("Threads", "0")),
        "fds": fds,
        "cpu_s": (int(ticks[11]) + int(ticks[12])) / CLK_TCK,
    }


# -- seq continuity -----------------------------------------------------------------------------------
@dataclass
class SeqTrack:
    """Per-publisher ``seq`` continuity on one key: a gap is a message its publisher numbered that never
    arrived. The first message of a stream only says how many went before we joined (not loss); a seq
    far below the last is a restarted publisher (numbering again from the start)."""

    first: int = 1
    last: dict[str, int] = field(default_factory=dict)
    received: int = 0
    gaps: int = 0
    gap_events: int = 0
    missed_at_join: int = 0
    out_of_order: int = 0
    publisher_restarts: int = 0
    examples: list[dict[str, Any]] = field(default_factory=list)

    def feed(self, stream: str, seq: int, when: float) -> int:
        """Account for ``seq`` of ``stream``; the number of messages skipped just before it."""
        self.received += 1
        last = self.last.get(stream)
        self.last[stream] = seq if last is None else max(last, seq)
        if last is None:
            self.missed_at_join += max(0, seq - self.first)
        elif seq > last + 1:
            self.gaps += seq - last - 1
            self.gap_events += 1
            if len(self.examples) < 20:
                self.examples.append({"t": when, "stream": stream[:16], "after": last, "got": seq})
            return seq - last - 1
        elif seq <= last:
            if self.restarted(seq, last):
                self.publisher_restarts += 1
                self.last[stream] = seq
            else:
                self.out_of_order += 1
        return 0

    def restarted(self, seq: int, last: int) -> bool:
        """``seq`` far below the stream's ``last``: its publisher started numbering again."""
        return seq <= self.first + 10 < last

    def report(self) -> dict[str, Any]:
        return {
            "received": self.received,
            "gaps": self.gaps,
            "gap_events": self.gap_events,
            "missed_at_join": self.missed_at_join,
            "out_of_order_or_duplicate": self.out_of_order,
            "publisher_restarts": self.publisher_restarts,
            "streams": len(self.last),
            "gap_examples": self.examples,
        }


def stream_of(topic: m.Topic[Any], msg: m.Message) -> str:
    """The publisher a message comes from: each numbers its own messages on a key."""
    if topic is m.CMD_CHUNK:
        return msg.session  # a learner session numbers its chunks from 0
    if topic is m.EVENTS_SAFETY:
        return "vision" if msg.detail.startswith("vision: ") else "robot_io"
    return ""


def seq_track(topic: m.Topic[Any]) -> SeqTrack:
    return SeqTrack(first=0 if topic is m.CMD_CHUNK else 1)


def pct(values: list[float] | np.ndarray) -> dict[str, float] | None:
    """p50/p95/p99/max and the count, in ms (values in s); None without values."""
    a = np.asarray(values, float) * 1e3
    if not len(a):
        return None
    p50, p95, p99 = np.percentile(a, [50, 95, 99])
    return {"p50_ms": p50, "p95_ms": p95, "p99_ms": p99, "max_ms": float(a.max()), "n": len(a)}


# -- the observer -------------------------------------------------------------------------------------
class Observer:
    """A peer on the stack's bus: counts, checks and times every message of the watched keys.

    Zenoh calls the handlers on its own threads; one lock guards all state, and ``window()`` hands the
    sampler what arrived since the last sample.
    """

    def __init__(self, zenoh: ZenohConfig, robot: str) -> None:
        self.bus = Bus(open_session(zenoh), robot)  # no key: it reads, never verifies
        self.lock = threading.Lock()
        self.seq = {t.name: seq_track(t) for t in WATCHED}
        self.count: Counter[str] = Counter()
        self.win_count: Counter[str] = Counter()
        self.win_gaps: Counter[str] = Counter()
        self.arrival: dict[str, list[float]] = {t.name: [] for t in WATCHED}  # stamp -> here, s
        names = ("state_arrival", "chunk_to_play", "state_to_chunk", "target_age")
        self.lat: dict[str, list[float]] = {name: [] for name in names}
        self.win_lat: dict[str, list[float]] = {}
        self.reset_pairs = 0
        self.unpaired_chunks = 0
        self.played: dict[str, dict[int, float]] = {}  # session -> chunk -> stamp of the tick playing it
        self.state_stamps: deque[float] = deque(maxlen=4000)
        self.modes: Counter[str] = Counter()
        self.win_modes: Counter[str] = Counter()
        self.telemetry: m.LearnerTelemetry | None = None
        self.episodes: list[dict[str, Any]] = []
        self.retreats: Counter[str] = Counter()
        self.safety: Counter[str] = Counter()
        self.safety_log: list[dict[str, Any]] = []
        self.verdicts: Counter[str] = Counter()
        self.dropped_actions = 0
        for topic in WATCHED:
            self.bus.subscribe(topic, self._handler(topic))

    def _handler(self, topic: m.Topic[Any]) -> Any:
        special = {
            m.STATE: self._state,
            m.CMD_CHUNK: self._chunk,
            m.TARGET: self._target,
            m.TELEMETRY_LEARNER: self._telemetry,
            m.EVENTS_RETREAT: self._retreat,
            m.EVENTS_SAFETY: self._safety,
            m.CHUNK_STATUS: self._status,
        }.get(topic)

        def on(msg: m.Message) -> None:
            now = time.time()
            with self.lock:
                self.count[topic.name] += 1
                self.win_count[topic.name] += 1
                self.win_gaps[topic.name] += self.seq[topic.name].feed(stream_of(topic, msg), msg.seq, now)
                self.arrival[topic.name].append(now - msg.stamp)
                if special is not None:
                    special(msg, now)

        return on

    def _lat(self, name: str, value: float) -> None:
        self.lat[name].append(value)
        self.win_lat.setdefault(name, []).append(value)

    def _state(self, s: m.RobotState, now: float) -> None:
        self.state_stamps.append(s.stamp)
        self._lat("state_arrival", now - s.stamp)
        mode = m.label(s, "mode")
        self.modes[mode] += 1
        self.win_modes[mode] += 1
        if s.played_chunk < 0 or s.played_index != 0:
            return
        played = self.played.setdefault(s.session, {})
        if s.played_chunk not in played:  # the first tick that played this chunk's first action
            played[s.played_chunk] = s.stamp
            self._lat("chunk_to_play", s.stamp - s.played_stamp)
            for old in [c for c in played if c < s.played_chunk - 50]:
                del played[old]

    def _chunk(self, c: m.ActionChunk, now: float) -> None:
        tick = self.played.get(c.session, {}).get(c.seq - 1)
        if tick is None:
            self.unpaired_chunks += 1
        elif c.stamp - tick > RESET_PAIR_S:
            self.reset_pairs += 1
        else:
            self._lat("state_to_chunk", c.stamp - tick)

    def _target(self, t: m.Target, now: float) -> None:
        if t.valid:
            self._lat("target_age", t.stamp - t.frame_stamp)

    def _telemetry(self, t: m.LearnerTelemetry, now: float) -> None:
        last = self.telemetry
        if last is not None and t.episode > last.episode:
            self.episodes.append(
                {
                    "t": now,
                    "episode": t.episode,
                    "step": t.global_step,
                    "success": t.success,
                    "return": t.episode_return,
                }
            )
        self.telemetry = t

    def _retreat(self, e: m.RetreatEvent, now: float) -> None:
        self.retreats[m.label(e, "reason")] += 1

    def _safety(self, e: m.SafetyEvent, now: float) -> None:
        kind = m.label(e, "kind")
        self.safety[kind] += 1
        if len(self.safety_log) < 200:
            self.safety_log.append({"t": now, "kind": kind, "detail": e.detail[:200], "held": e.held})

    def _status(self, s: m.ChunkStatus, now: float) -> None:
        self.verdicts[m.label(s, "verdict")] += 1
        if s.preempted_by >= 0:
            self.dropped_actions += s.dropped

    def window(self) -> dict[str, Any]:
        """What arrived since the last call (counts, gaps, latencies, modes), and resets it."""
        with self.lock:
            out = {
                "count": dict(self.win_count),
                "gaps": dict(self.win_gaps),
                "lat": {k: list(v) for k, v in self.win_lat.items()},
                "modes": dict(self.win_modes),
                "state_stamps": list(self.state_stamps),
            }
            self.win_count, self.win_gaps, self.win_modes = Counter(), Counter(), Counter()
            self.win_lat = {}
            self.state_stamps.clear()
        return out

    def close(self) -> None:
        self.bus.close()


# -- sampling -----------------------------------------------------------------------------------------
@dataclass
class Sampler:
    """Takes one sample of every process and of the observer's window every interval."""

    config: Path
    supervisor: int
    observer: Observer
    t0: float
    period: float
    late_s: float  # a state period longer than this is a late control tick (1.5 periods)
    last_t: float = 0.0
    last_cpu: dict[str, tuple[int, float]] = field(default_factory=dict)
    pids: dict[str, list[int]] = field(default_factory=dict)
    last_step: tuple[float, int] | None = None
    samples: list[dict[str, Any]] = field(default_factory=list)

    def processes(self, dt: float) -> dict[str, dict[str, float]]:
        """Memory and CPU of every part, the supervisor and this observer; notes each new pid."""
        pids = {**parts_of(self.config), "supervisor": self.supervisor, "observer": os.getpid()}
        out = {}
        for name, pid in pids.items():
            st = proc_stats(pid)
            if st is None:
                continue
            if pid not in self.pids.setdefault(name, []):
                self.pids[name].append(pid)
            prev = self.last_cpu.get(name)
            st["cpu_pct"] = 100 * (st["cpu_s"] - prev[1]) / dt if prev and prev[0] == pid and dt > 0 else None
            self.last_cpu[name] = (pid, st["cpu_s"])
            out[name] = {"pid": pid, **st}
        return out

    def learner(self, now: float) -> dict[str, Any]:
        with self.observer.lock:
            tel = self.observer.telemetry
            eps = list(self.observer.episodes)
        if tel is None:
            return {}
        rate = None
        if self.last_step is not None and now > self.last_step[0]:
            rate = (tel.global_step - self.last_step[1]) / (now - self.last_step[0])
        self.last_step = (now, tel.global_step)
        recent = [e["success"] for e in eps[-50:]]
        return {
            "global_step": tel.global_step,
            "steps_per_s": rate,
            "episodes": tel.episode,
            "success_last50": float(np.mean(recent)) if recent else None,
            "success_all": float(np.mean([e["success"] for e in eps])) if eps else None,
            "paused": tel.paused,
        }

    def sample(self) -> dict[str, Any]:
        now = time.monotonic()
        dt = now - self.last_t if self.last_t else self.period
        self.last_t = now
        win = self.observer.window()
        stamps = np.diff(np.sort(win["state_stamps"]))
        with self.observer.lock:
            safety, gaps = (
                sum(self.observer.safety.values()),
                {k: v.gaps for k, v in self.observer.seq.items()},
            )
        s = {
            "t": now - self.t0,
            "wall": time.time(),
            "load": os.getloadavg(),
            "proc": self.processes(dt),
            "rate_hz": {k: v / dt for k, v in win["count"].items()},
            "gaps_window": win["gaps"],
            "gaps_total": sum(gaps.values()),
            "latency": {k: pct(v) for k, v in win["lat"].items()},
            "state_period_ms_p99": float(np.percentile(stamps, 99) * 1e3) if len(stamps) else None,
            "state_late_pct": float(100 * np.mean(stamps > self.late_s)) if len(stamps) else None,
            "modes": win["modes"],
            "learner": self.learner(now),
            "safety_total": safety,
            "restarts": {k: len(v) - 1 for k, v in self.pids.items() if len(v) > 1},
        }
        self.samples.append(s)
        return s


def progress_line(s: dict[str, Any]) -> str:
    mem = " ".join(f"{k[:8]} {v['rss_mb']:.0f}" for k, v in s["proc"].items())
    r = s["rate_hz"]
    lat = s["latency"]
    play = (lat.get("chunk_to_play") or {}).get("p99_ms")
    react = (lat.get("state_to_chunk") or {}).get("p99_ms")
    ln = s["learner"]
    succ = ln.get("success_last50")
    rate, nan = ln.get("steps_per_s"), float("nan")
    return (
        f"[{s['t']:6.0f} s] load {s['load'][0]:.2f} | RSS MB {mem} | state {r.get('state', 0):.1f}/s"
        f" target {r.get('target', 0):.1f}/s chunk {r.get('cmd/chunk', 0):.1f}/s"
        f" | gaps {s['gaps_total']} | p99 play {play or nan:.0f} ms react {react or nan:.0f} ms"
        f" | step {ln.get('global_step', 0)} ({rate or 0:.1f}/s) ep {ln.get('episodes', 0)}"
        f" succ50 {'-' if succ is None else f'{100 * succ:.0f}%'}"
        f" | safety {s['safety_total']} restarts {sum(s['restarts'].values())}"
    )


# -- the recording ------------------------------------------------------------------------------------
def recording_check(path: Path, robot: str) -> dict[str, Any]:
    """``seq`` gaps per key in the MCAP (every part of it), and the recorder's own arrival latency
    (stamp -> log time).

    Streams the files with a topic filter rather than ``monitor.recording.read``, which holds every
    message (derived Foxglove channels too) in memory at once: an hour is a few hundred MB of it. The
    seqs are checked in their publishers' order: what the recorder got back after missing it (from the
    publishers' caches, ``Topic.kept``) is logged when it came, later than its neighbours.
    """
    keys = {m.key(robot, t.name): t for t in WATCHED}
    got: dict[str, list[tuple[str, int, float]]] = {t.name: [] for t in WATCHED}
    arrival: dict[str, list[float]] = {t.name: [] for t in WATCHED}
    rejected = 0
    files = parts(path)
    for part in files:
        with open(part, "rb") as fh:
            wanted = [*keys, *(REJECTED + k for k in keys)]  # not the derived Foxglove channels
            for _, channel, msg in make_reader(fh).iter_messages(topics=wanted, log_time_order=True):
                topic = keys.get(channel.topic)
                if topic is None:
                    rejected += 1
                    continue
                decoded = topic.decode(msg.data)
                got[topic.name].append((stream_of(topic, decoded), decoded.seq, msg.log_time / 1e9))
                arrival[topic.name].append(msg.log_time / 1e9 - decoded.stamp)
    seq = {t.name: seq_track(t) for t in WATCHED}
    for name, entries in got.items():
        track = seq[name]
        # Each stream in its publisher's order; a publisher restarted (numbering from the start again,
        # seen in arrival order) begins a new epoch, fed after the one before.
        top: dict[str, int] = {}
        epoch: dict[str, int] = {}
        keyed = []
        for stream, number, when in entries:
            if track.restarted(number, top.get(stream, 0)):
                epoch[stream] = epoch.get(stream, 0) + 1
                top[stream] = number
            top[stream] = max(top.get(stream, 0), number)
            keyed.append((stream, epoch.get(stream, 0), number, when))
        for stream, _, number, when in sorted(keyed, key=lambda e: e[:3]):
            track.feed(stream, number, when)
    return {
        "path": str(path),
        "parts": len(files),
        "size_mb": sum(f.stat().st_size for f in files) / 2**20,
        "rejected": rejected,
        "keys": {k: {**v.report(), "arrival": pct(arrival[k])} for k, v in seq.items() if v.received},
    }


# -- analysis -----------------------------------------------------------------------------------------
def slope_mb_per_h(t: np.ndarray, y: np.ndarray) -> float | None:
    if len(t) < 3 or np.ptp(t) <= 0:
        return None
    return float(np.polyfit(t / 3600, y, 1)[0])


def memory_report(samples: list[dict[str, Any]], pids: dict[str, list[int]]) -> dict[str, Any]:
    """Per process: RSS at start and end, peak, and the RSS slope over each half of the run."""
    out = {}
    half = samples[-1]["t"] / 2 if samples else 0
    for name in pids:
        pts = [
            (s["t"], s["proc"][name]["rss_mb"], s["proc"][name]["hwm_mb"])
            for s in samples
            if name in s["proc"]
        ]
        if not pts:
            continue
        t, rss, hwm = (np.array(c) for c in zip(*pts, strict=True))
        out[name] = {
            "rss_start_mb": rss[0],
            "rss_end_mb": rss[-1],
            "rss_max_mb": rss.max(),
            "hwm_end_mb": hwm[-1],
            "slope_first_half_mb_per_h": slope_mb_per_h(t[t < half], rss[t < half]),
            "slope_second_half_mb_per_h": slope_mb_per_h(t[t >= half], rss[t >= half]),
            "pids": pids[name],
        }
    return out


def learner_report(obs: Observer, summary: dict[str, Any]) -> dict[str, Any]:
    eps = obs.episodes
    succ = [e["success"] for e in eps]
    q = max(1, len(succ) // 4)
    tel = obs.telemetry
    return {
        "global_step": tel.global_step if tel else 0,
        "episodes": tel.episode if tel else 0,
        "episodes_seen_ending": len(eps),
        "success_rate": float(np.mean(succ)) if succ else None,
        "success_by_quarter": [float(np.mean(succ[i * q : (i + 1) * q])) for i in range(4)]
        if len(succ) >= 4
        else None,
        "retreats": dict(obs.retreats),
        "chunk_verdicts": dict(obs.verdicts),
        "dropped_actions": obs.dropped_actions,
        "supervisor_summary": {
            k: summary.get(k) for k in ("global_step", "episodes", "success_rate", "success_rate_by_quarter")
        },
        "episodes_over_time": eps,
    }


def learner_result(path: Path) -> dict[str, Any]:
    """The learner's own counts from its ``result.json`` (waits for the target, refused chunks, ...)."""
    if not path.exists():
        return {}
    res = json.loads(path.read_text())
    keep = (
        "steps_this_session",
        "wall_clock_s",
        "target_waits",
        "chunk_preemptions",
        "dropped_actions",
        "refused_chunks",
        "suspended_ticks",
        "retreat_preemptions",
        "retreat_dropped",
        "summary",
    )
    return {k: res.get(k) for k in keep}


def mean_rates(samples: list[dict[str, Any]]) -> dict[str, float]:
    """Each key's mean rate over the samples after the first minute (startup excluded)."""
    steady = [s for s in samples if s["t"] > 60] or samples
    keys = {k for s in steady for k in s["rate_hz"]}
    return {k: float(np.mean([s["rate_hz"].get(k, 0.0) for s in steady])) for k in sorted(keys)}


# -- figure -------------------------------------------------------------------------------------------
def plot(out: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    samples = out["samples"]
    t = np.array([s["t"] for s in samples]) / 60
    fig, ax = plt.subplots(2, 3, figsize=(16, 9))  # 1600 px: a laptop screen
    _plot_memory(ax[0, 0], samples, t)
    _plot_cpu(ax[1, 0], samples, t)
    _plot_rates(ax[0, 1], samples, t)
    _plot_latency(ax[1, 1], samples, t)
    _plot_learner(ax[0, 2], samples, t)
    _plot_text(ax[1, 2], out)
    for a in ax.flat[:5]:
        a.set_xlabel("minutes")
        a.grid(alpha=0.3)
    fig.suptitle(f"soak: whole sim stack, {out['duration_s']:.0f} s, {out['machine']['cpus']} cores (shared)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _series(samples: list[dict[str, Any]], get: Any) -> np.ndarray:
    vals = []
    for s in samples:
        try:
            v = get(s)
        except (KeyError, TypeError):
            v = None
        vals.append(np.nan if v is None else v)
    return np.array(vals, float)


def _plot_memory(ax: Any, samples: list[dict[str, Any]], t: np.ndarray) -> None:
    for name in sorted({k for s in samples for k in s["proc"]}):
        ax.plot(t, _series(samples, lambda s, n=name: s["proc"][n]["rss_mb"]), label=name)
    ax.set(ylabel="RSS (MB)", title="resident memory per process")
    ax.legend(fontsize=8)


def _plot_cpu(ax: Any, samples: list[dict[str, Any]], t: np.ndarray) -> None:
    for name in sorted({k for s in samples for k in s["proc"]}):
        ax.plot(t, _series(samples, lambda s, n=name: s["proc"][n]["cpu_pct"]), label=name, lw=1)
    ax.set(ylabel="% of one core", title="CPU per process; load average")
    ax.legend(fontsize=8, loc="upper left")
    tw = ax.twinx()
    tw.plot(t, _series(samples, lambda s: s["load"][0]), "k--", lw=1, label="load average (1 min)")
    tw.set_ylabel("load average")
    tw.legend(fontsize=8, loc="upper right")


def _plot_rates(ax: Any, samples: list[dict[str, Any]], t: np.ndarray) -> None:
    for key in sorted({k for s in samples for k in s["rate_hz"]}):
        ax.plot(t, _series(samples, lambda s, k=key: s["rate_hz"].get(k, 0.0)), label=key, lw=1)
    ax.set(ylabel="messages/s (observer)", title="rates per key; seq gaps (live)")
    ax.set_yscale("symlog")
    ax.legend(fontsize=7, ncol=2, loc="upper left")
    tw = ax.twinx()
    tw.plot(t, _series(samples, lambda s: s["gaps_total"]), "r--", lw=1.2, label="seq gaps, all keys")
    tw.set_ylabel("messages lost (cumulative)", color="r")
    tw.legend(fontsize=7, loc="lower right")


def _plot_latency(ax: Any, samples: list[dict[str, Any]], t: np.ndarray) -> None:
    names = [
        ("state_arrival", "state stamp -> observer"),
        ("chunk_to_play", "chunk stamp -> tick playing it"),
        ("state_to_chunk", "tick -> next chunk (learner)"),
    ]
    for (name, label), col in zip(names, ("tab:blue", "tab:orange", "tab:green"), strict=True):
        for p, style in (("p50_ms", "-"), ("p99_ms", ":")):
            y = _series(samples, lambda s, n=name, p=p: s["latency"][n][p])
            ax.plot(t, y, style, color=col, lw=1, label=f"{label} {p[:3]}")
    ax.set(ylabel="ms", title="latency per window (p50 -, p99 :)", yscale="log")
    ax.legend(fontsize=7)


def _plot_learner(ax: Any, samples: list[dict[str, Any]], t: np.ndarray) -> None:
    ax.plot(t, _series(samples, lambda s: s["learner"]["success_last50"]), label="success, last 50 episodes")
    ax.plot(t, _series(samples, lambda s: s["learner"]["success_all"]), label="success, all so far")
    ax.set(ylabel="success rate", ylim=(-0.02, 1.02), title="learner")
    tw = ax.twinx()
    tw.plot(t, _series(samples, lambda s: s["learner"]["steps_per_s"]), color="grey", lw=0.8, label="steps/s")
    tw.set_ylabel("steps/s")
    ax.legend(fontsize=8, loc="upper left")
    tw.legend(fontsize=8, loc="lower right")


def _plot_text(ax: Any, out: dict[str, Any]) -> None:
    ax.axis("off")
    ax.text(0.0, 1.0, "\n".join(summary_lines(out)), va="top", family="monospace", fontsize=7)


# -- report -------------------------------------------------------------------------------------------
def pc(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def summary_lines(out: dict[str, Any]) -> list[str]:
    lines = [f"duration {out['duration_s']:.0f} s, exit {out['exit_code']}, load mean {out['load_mean']:.2f}"]
    lines.append("memory (MB): start -> end, slope 1st / 2nd half (MB/h)")
    for name, r in out["memory"].items():
        s1, s2 = r["slope_first_half_mb_per_h"], r["slope_second_half_mb_per_h"]
        lines.append(
            f"  {name:10s} {r['rss_start_mb']:6.0f} -> {r['rss_end_mb']:6.0f}  "
            f"{'-' if s1 is None else f'{s1:+.1f}':>7} / {'-' if s2 is None else f'{s2:+.1f}':>7}"
        )
    lines.append("latency p50 / p95 / p99 / max (ms)")
    for name, p in out["latency"].items():
        if p:
            lines.append(
                f"  {name:16s} {p['p50_ms']:6.1f} {p['p95_ms']:6.1f} {p['p99_ms']:7.1f} {p['max_ms']:7.0f}"
            )
    lines.append("seq gaps per key: live / recording (msgs live, recorded)")
    rec = out["loss"]["recording"].get("keys", {})
    for k, v in out["loss"]["live"].items():
        r = rec.get(k, {})
        got = f"({v['received']}, {r.get('received', '-')})"
        lines.append(f"  {k:18s} {v['gaps']:4d} / {r.get('gaps', '-')!s:4s} {got}")
    ln = out["learner"]
    rate, quarters = ln["success_rate"], ln["success_by_quarter"]
    lines.append(f"learner: step {ln['global_step']}, {ln['episodes']} episodes, success {pc(rate)}")
    lines.append(f"  success by quarter {' / '.join(pc(q) for q in quarters or [])}")
    restarts = {k: v for k, v in out["restarts"]["pid_changes"].items() if v}
    lines.append(f"restarts: {restarts or 'none'} (supervisor: {out['restarts']['supervisor'] or 'none'})")
    lines.append("safety events:")
    lines += [f"  {k:16s} {v}" for k, v in sorted(out["safety_events"].items(), key=lambda kv: -kv[1])]
    return lines


def finish(args: argparse.Namespace, ctx: dict[str, Any]) -> dict[str, Any]:
    """Everything measured, as the results JSON."""
    obs, sampler, summary = ctx["observer"], ctx["sampler"], ctx["summary"]
    samples = sampler.samples
    with obs.lock:
        latency = {k: pct(v) for k, v in obs.lat.items()}
        latency["target_arrival"] = pct(obs.arrival["target"])
        live = {k: v.report() for k, v in obs.seq.items() if v.received}
        arrival = {k: pct(v) for k, v in obs.arrival.items() if v}
    return {
        "command": " ".join(["python bench/soak.py", *sys.argv[1:]]),
        "git_at_start": ctx["git"],
        "config": ctx["cfg"],
        "duration_s": ctx["duration"],
        "requested_duration_s": args.duration,
        "interval_s": args.interval,
        "exit_code": ctx["exit_code"],
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "host": platform.node()},
        "load_mean": float(np.mean([s["load"][0] for s in samples])) if samples else 0.0,
        "memory": memory_report(samples, sampler.pids),
        "rates_hz": mean_rates(samples),
        "latency": latency,
        "arrival_by_key": arrival,
        "latency_notes": {
            "reset_pairs_excluded": obs.reset_pairs,
            "unpaired_chunks": obs.unpaired_chunks,
            "state_modes": dict(obs.modes),
        },
        "loss": {"live": live, "recording": ctx["recording"]},
        "restarts": {
            "pid_changes": {k: len(v) - 1 for k, v in sampler.pids.items()},
            "supervisor": summary.get("restarts"),
        },
        "safety_events": dict(obs.safety),
        "safety_events_supervisor": summary.get("safety_events"),
        "safety_log": obs.safety_log,
        "bad_messages_at_observer": dict(obs.bus.bad_messages),
        "learner": {**learner_report(obs, summary), "result_json": ctx["learner_result"]},
        "supervisor_summary": summary,
        "samples": samples,
    }


def git_state() -> dict[str, Any]:
    """The commit the stack ran from and the files that differed from it (others may edit meanwhile)."""
    run = lambda *a: subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True).stdout  # noqa: E731
    return {"commit": run("rev-parse", "HEAD").strip(), "modified": run("status", "--short").splitlines()}


def parse_option(text: str) -> tuple[str, Any]:
    key, _, value = text.partition("=")
    return key, json.loads(value)


# -- main ---------------------------------------------------------------------------------------------
def soak(args: argparse.Namespace, run_dir: Path) -> dict[str, Any]:
    """Run the stack for ``args.duration`` s while sampling; stop it; check the recording."""
    git = git_state()
    options = dict(parse_option(o) for o in args.zenoh_option)
    path, cfg = private_config(run_dir, args.steps, options)
    proc = start_stack(path, run_dir)
    observer = None
    try:
        wait_listening(cfg["zenoh"]["hub"], alive=lambda: proc.poll() is None)
        observer = Observer(ZenohConfig.model_validate(cfg["zenoh"]), cfg["name"])  # as the parts join
        t0 = time.monotonic()
        print(
            f"stack {cfg['name']} up (pid {proc.pid}), hub {cfg['zenoh']['hub']}, run dir {run_dir}",
            flush=True,
        )
        late = 1.5 / cfg["robot"]["control_rate_hz"]
        sampler = Sampler(path, proc.pid, observer, t0, args.interval, late)
        while time.monotonic() - t0 < args.duration and proc.poll() is None:
            time.sleep(max(0.0, args.interval - (time.monotonic() - t0) % args.interval))
            print(progress_line(sampler.sample()), flush=True)
        duration = time.monotonic() - t0
        if proc.poll() is not None:
            print(f"adaptiveh up ended early (exit {proc.returncode}); see {run_dir}/up.log", flush=True)
        code = stop_stack(proc)
        time.sleep(1.0)  # the last messages of the shutdown reach the observer
    finally:
        stop_stack(proc, timeout=30)
        if observer is not None:
            observer.close()
    summary_path = run_dir / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    rec = Path(summary["recording"]) if summary.get("recording") else None
    recording = recording_check(rec, cfg["name"]) if rec and rec.exists() else {"error": "no recording"}
    ctx = {
        "git": git,
        "learner_result": learner_result(run_dir / "learner" / "result.json"),
        "observer": observer,
        "sampler": sampler,
        "summary": summary,
        "cfg": cfg,
        "duration": duration,
        "exit_code": code,
        "recording": recording,
    }
    return finish(args, ctx)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=3600.0, help="seconds of running stack")
    ap.add_argument("--interval", type=float, default=10.0, help="seconds between samples")
    ap.add_argument("--steps", type=int, default=10**9, help="learner.steps: more than the run can do")
    ap.add_argument("--out", default=str(ROOT / "results/soak.json"))
    ap.add_argument(
        "--zenoh-option",
        action="append",
        default=[],
        metavar="KEY=JSON",
        help="extra Zenoh config key for every part and the observer (an experiment, not the soak)",
    )
    ap.add_argument("--keep", action="store_true", help="keep the run directory (logs, recording)")
    ap.add_argument("--replot", action="store_true", help="run nothing: redraw the .png from the --out JSON")
    args = ap.parse_args()
    os.chdir(ROOT)
    if args.replot:
        path = Path(args.out)
        plot(json.loads(path.read_text()), path.with_suffix(".png"))
        print(f"wrote {path.with_suffix('.png')}")
        return 0
    run_dir = Path(tempfile.mkdtemp(prefix="soak-"))
    try:
        out = soak(args, run_dir)
    finally:
        if not args.keep:
            shutil.rmtree(run_dir, ignore_errors=True)
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1, default=float))
    plot(out, path.with_suffix(".png"))
    print("\n".join(summary_lines(out)))
    print(f"wrote {path} and {path.with_suffix('.png')}" + (f"; run dir {run_dir}" if args.keep else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
