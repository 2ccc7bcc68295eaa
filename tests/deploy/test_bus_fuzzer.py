"""A black-box bus fuzzer against ``adaptiveh up`` (issues #13, #31): for ``ADAPTIVEH_FUZZ_S`` seconds (30
in the default run) a stranger on the bus publishes mutated, truncated, replayed and oversized copies of
the stack's own live traffic on every key it saw, random bytes on ``control``, and well-formed but unsigned
progress, retreat and safety events that would rewrite the operator's view.

Afterwards: every part is the same process as before (nothing crashed or was restarted), every periodic
key flows, every chunk the arm played is one the learner signed, the learner took at most one step per
control tick, and no state shows the arm outside its workspace box or joint limits or moving more than
``robot.max_step_m`` in a tick. The forged events change neither the supervisor's progress and summary
nor what the monitor serves; each part logged fewer than 100 lines; no log file holds the token. Genuine
messages are told apart with the stack's key (the stranger has no token)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from collections import defaultdict, deque
from pathlib import Path

import numpy as np
import pytest
from bus_probe import BusProbe
from stack_helpers import PARTS, assert_within_limits, parts_of, start_up, write_stack_config

from bus import messages as m
from bus.signing import authentic, mac_key
from bus.transport import Bus, open_session
from deploy.config import load_stack_config

FUZZ_S = float(os.environ.get("ADAPTIVEH_FUZZ_S", "30"))
FORGED_STEP = 987_654_321  # a step count, H, statistic and safety kind no genuine message of this run has
FORGED_H = 85
FORGED_STATISTIC = 1e76
FORGED_KIND = "driver_error"  # the PyBullet arm never reports one
TOL_M = 0.01  # m: PyBullet tracking slack around the box and the step bound


def forged_view(name: str, rng: np.random.Generator) -> dict[str, bytes]:
    """Well-formed, unsigned messages a stranger would put to rewrite the operator's view."""
    tel = m.LearnerTelemetry(global_step=FORGED_STEP, episode=14, episode_return=1e9, stamp=time.time())
    retreat = m.RetreatEvent(
        segment=int(rng.integers(10**6)),
        H=FORGED_H,
        reason=m.SegmentEnd.RETREAT,
        statistic=[FORGED_STATISTIC],
        stamp=time.time(),
    )
    safety = m.SafetyEvent(kind=m.SafetyEvent.DRIVER_ERROR, detail="forged", stamp=time.time())
    return {
        m.TELEMETRY_LEARNER.key(name): tel.SerializeToString(),
        m.EVENTS_RETREAT.key(name): retreat.SerializeToString(),
        m.EVENTS_SAFETY.key(name): safety.SerializeToString(),
    }


def monitor_view(logs: Path) -> dict:
    """What the monitor serves now (its URL from its log: the token is never there)."""
    url = re.search(r"^monitor: (http://\S+/)", (logs / "monitor.log").read_text(), re.M)
    assert url, "the monitor printed no URL"
    with urllib.request.urlopen(url.group(1) + "api/state", timeout=10) as reply:
        return json.loads(reply.read())


def assert_view_not_forged(view: dict, h_max: int) -> None:
    assert view["learner"].get("step", 0) != FORGED_STEP
    assert all(s["H"] <= h_max for s in view["segments"]), "a forged H reached the page"
    assert all(abs(x) < FORGED_STATISTIC for _, x, _ in view["statistic"])
    assert FORGED_KIND not in {e["kind"] for e in view["safety"]}
    assert view["counts"]["rejected"] > 0


def mutate(data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    kind = ("random", "truncated", "flipped", "replayed", "oversized")[int(rng.integers(5))]
    if kind == "random":
        return kind, rng.bytes(int(rng.integers(1, 400)))
    if kind == "truncated":
        return kind, data[: int(rng.integers(0, max(len(data), 1)))]
    if kind == "flipped":
        out = bytearray(data or b"\0")
        for _ in range(int(rng.integers(1, 5))):
            out[int(rng.integers(len(out)))] ^= 1 << int(rng.integers(8))
        return kind, bytes(out)
    if kind == "replayed":
        return kind, data
    copies = int(rng.integers(20, 200))  # concatenated copies: repeated fields run long (up to ~200 kB)
    return kind, data * max(2, min(copies, 200_000 // max(len(data), 1)))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_stranger_fuzzing_the_bus_neither_ends_nor_steers_the_run(tmp_path):
    path, cfg = write_stack_config(tmp_path, "fz", steps=100000)
    stack = load_stack_config(path)
    h_max = stack.learner.longest_segment
    up, token = start_up(path)
    key = mac_key(token)
    bus = Bus(open_session(stack.zenoh), stack.name)  # the stranger: no token
    probe = BusProbe(bus)
    states = probe.collect(m.STATE, arrival=False)
    chunks = probe.collect(m.CMD_CHUNK, arrival=False)
    telemetry = probe.collect(m.TELEMETRY_LEARNER)
    flows = {t: probe.collect(t) for t in (m.STATE, m.TARGET, m.CAMERA_ANNOTATED)}
    seen: dict[str, deque[bytes]] = defaultdict(lambda: deque(maxlen=8))

    def capture(sample) -> None:
        with probe.lock:
            seen[str(sample.key_expr)].append(sample.payload.to_bytes())

    sub = bus.session.declare_subscriber(f"{m.NAMESPACE}/{stack.name}/**", capture)
    sent: dict[str, int] = defaultdict(int)
    try:
        genuine = lambda: [t for _, t in telemetry if authentic(t, key)]  # noqa: E731
        probe.wait(lambda: any(t.global_step > 20 for t in genuine()), 120, "the learner stepping")
        before = parts_of(path)
        assert set(before) == set(PARTS)
        step0 = max(t.global_step for t in genuine())
        stop, rng = threading.Event(), np.random.default_rng(0)

        def fuzz() -> None:
            control_key = m.CONTROL.key(stack.name)
            while not stop.is_set():
                with probe.lock:
                    traffic = {k: list(v) for k, v in seen.items()} | {control_key: [b""]}
                for k, copies in traffic.items():
                    kind, data = mutate(copies[int(rng.integers(len(copies)))], rng)
                    if k == control_key:
                        kind, data = "random", rng.bytes(int(rng.integers(1, 60)))
                    bus.session.put(k, data)
                    sent[kind] += 1
                for k, data in forged_view(stack.name, rng).items():
                    bus.session.put(k, data)
                    sent["forged view"] += 1
                time.sleep(0.03)  # ~500 messages a second over the stack's ~15 keys

        thread = threading.Thread(target=fuzz, daemon=True)
        t0 = time.time()
        thread.start()
        time.sleep(FUZZ_S)
        stop.set()
        thread.join()
        t1 = time.time()
        time.sleep(3.0)
        # Every part is the process it was: nothing crashed, nothing was restarted.
        assert up.poll() is None, "adaptiveh up ended"
        assert parts_of(path) == before
        # Every periodic key flows after the fuzzing (state 20 Hz, target, annotated image, learner progress).
        with probe.lock:
            late = {t.name: sum(1 for at, _ in got if at > t1 + 1.0) for t, got in flows.items()}
        assert late["state"] > 20 and late["target"] > 5 and late["camera/annotated"] >= 1, late
        # The learner still steps (its progress, signed, every 20 steps): within 15 s, not the 2 s window
        # above, as on a loaded CI machine 20 steps of plan mode can take longer than 2 s.
        probe.wait(
            lambda: [t for at, t in telemetry if at > t1 + 1.0 and authentic(t, key)],
            15.0,
            "the learner's progress after the fuzzing (it stopped)",
        )
        with probe.lock:
            mine = [s for s in states if authentic(s, key)]
            signed = {(c.session, c.seq, c.stamp) for c in chunks if authentic(c, key)}
        step1 = max(t.global_step for t in genuine())
        assert_view_not_forged(monitor_view(tmp_path / "logs"), h_max)
        log_lines = {p.stem: len(p.read_text().splitlines()) for p in (tmp_path / "logs").glob("*.log")}
    finally:
        sub.undeclare()
        bus.close()
        up.send_signal(signal.SIGTERM)
        try:
            up.wait(timeout=60)
        except subprocess.TimeoutExpired:
            up.kill()
        for pid in parts_of(path).values():
            os.kill(pid, signal.SIGKILL)
    out = up.stdout.read()
    total = sum(sent.values())
    print(f"fuzzer: {total} messages on {len(seen)} keys in {t1 - t0:.1f} s: {dict(sent)}")
    assert total > 1000
    # The arm obeyed one learner session, and played only chunks it signed.
    assert len({s.session for s in mine if s.session}) == 1
    played = {(s.session, s.played_chunk, s.played_stamp) for s in mine if s.played_chunk >= 0}
    # A chunk sent before the probe's subscription reached the learner is not in ``signed`` (a race at
    # start-up): the stranger, on the probe's session, could neither have seen nor altered it. Only the
    # learner's own chunks before the first one the probe saw, in sequence and in time, are excused.
    session, first_seq, first_stamp = min(signed, key=lambda c: c[2])
    early = {c for c in played - signed if c[0] == session and c[1] < first_seq and c[2] < first_stamp}
    assert len(early) <= 2, early
    assert played - early and played - early <= signed, "the arm played a chunk the learner did not sign"
    # At most one learner step per control tick over the fuzzing window.
    ticks = [s.tick for s in mine if t0 <= s.stamp <= t1]
    assert step1 - step0 <= (max(ticks) - min(ticks)) + int(4.0 * cfg["robot"]["control_rate_hz"])
    # No commanded motion outside the limits: inside the box, the joint limits, one step per tick.
    assert_within_limits(mine, cfg["robot"], TOL_M)
    result = json.loads((tmp_path / "learner" / "result.json").read_text())
    assert result["global_step"] >= step1
    # The supervisor believed none of the forged progress, retreats or safety events.
    assert str(FORGED_STEP) not in out, "a forged step count reached the progress line"
    summary_file = re.search(r"^summary file: (\S+)", out, re.M)
    assert summary_file, out[-2000:]
    summary = json.loads(Path(summary_file.group(1)).read_text())
    assert summary["H"]["p90"] <= h_max and FORGED_KIND not in summary["safety_events"]
    assert summary["rejected_messages"].get("events/retreat", 0) > 0
    # Rate-limited reports: 30 s of fuzz on every key is a few lines per part, not one per message.
    print(f"log lines per part after {FUZZ_S:.0f} s of fuzz: {log_lines}")
    assert max(log_lines.values()) < 100, log_lines
    for log_file in (tmp_path / "logs").glob("*"):
        assert token not in log_file.read_text(errors="replace"), f"{log_file.name} holds the token"
