"""The monitor process: collects the robot's Zenoh traffic and serves it to one local web page.

Plans (chunks that carry a predicted end-effector path, ``learner.execution: plan``) are kept with the
path the arm really took while each played (from the ticks that name the plan's actions), where a newer
plan cut them short (the tick, and whether that plan came from a retreat) and their executed / dropped /
queued counts, so the page can draw planned against executed and the abandoned rest in red.

stdlib ``http.server`` on 127.0.0.1; the page polls ``/api/state`` (JSON) and ``/api/image.jpg``
(the vision node's annotated JPEG) a few times a second. ``POST /api/control`` turns a button or a jog
key into a ``Control`` message; it needs the operator token (``X-Token`` header or ``token`` field; the
page asks for it once and keeps it out of the URL). An e-stop needs neither the token nor valid values,
and a body without a readable command that mentions ``estop`` (not JSON, say) still stops the arm. The
message carries no token: the bus signs it with the token's key (``bus.signing``), and the robot and
learner obey only a signed, fresh request (an e-stop from anyone).

A fleet (``fleet:`` in the stack config; ``MonitorServer``'s ``arms``) is listed arm by arm: each arm's
mode, success, retreats and last plan (``FleetState``), with its own stop; the detail panels show the one
the operator picks (``/api/state?arm=``). The E-STOP goes on the fleet's key, which every arm obeys; a
request that names an ``arm`` goes on that arm's key alone (its stop, its release, a jog).
"""

from __future__ import annotations

import json
import logging
import math
import secrets
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

from pydantic import Field

from bus import messages as m
from bus.learner_session import REFUSALS
from bus.node import Node
from bus.transport import Bus, Publisher
from common.config import Section
from common.throttle import Throttle
from monitor.view_limits import ViewLimits

log = logging.getLogger(__name__)
STATIC = Path(__file__).parent / "static"
PLANS_KEPT = 8  # the current plan and the recent ones the page draws
SUCCESS_WINDOW = 20  # episodes in the success rate the page shows (the benches' rolling window)
SNAPSHOT_MAX_AGE_S = 0.1  # the page polls a few times a second; a snapshot this old is still current
MAX_BODY = 64 * 1024  # a control request is a few dozen bytes


def _length(header: str | None) -> int:
    """The body's length to read: a garbled or huge Content-Length is read as at most MAX_BODY."""
    try:
        return max(0, min(int(header or 0), MAX_BODY))
    except ValueError:
        return 0


def _error(exc: Exception) -> dict[str, Any]:
    return {"ok": False, "error": str(exc)}


class Server(ThreadingHTTPServer):
    """http.server with a longer listen queue: with the default 5, a few busy pages made the kernel drop
    the operator's e-stop connection, which the client retried a second later (measured)."""

    request_queue_size = 128
    daemon_threads = True


class JsonCache:
    """``build()`` as JSON, built at most once per ``max_age_s``: every page polls it, and building it per
    request let a few busy pages starve the operator's e-stop of the interpreter (measured)."""

    def __init__(self, build: Callable[[], dict[str, Any]]) -> None:
        self.build = build
        self._lock = threading.Lock()
        self._json, self._at = b"", -float("inf")

    def get(self, max_age_s: float = SNAPSHOT_MAX_AGE_S) -> bytes:
        with self._lock:
            now = time.monotonic()
            if now - self._at > max_age_s:
                self._json, self._at = json.dumps(self.build()).encode(), now
            return self._json


class MonitorConfig(Section):
    """The ``monitor:`` section."""

    host: str = Field(
        "127.0.0.1",
        description="the address the monitor's web page (and Foxglove live view) listens on; 127.0.0.1:"
        " this machine only, 0.0.0.0: every interface",
    )
    port: int = Field(8765, ge=0, le=65535)  # the web page's TCP port; 0: any free port
    history: int = Field(600, ge=10)  # points kept per plot on the web page
    # Foxglove WebSocket live view on ``host`` (monitor.foxglove.live); 0: any free port; null: off
    foxglove_port: int | None = Field(8766, ge=0, le=65535)


class MonitorState:
    """Everything the page shows, updated from Zenoh callbacks, read under one lock. With the stack's key
    on ``bus`` only signed, new messages arrive here; ``limits`` keeps out-of-range ones off the plots.
    Both kinds of refusal land in one counter (``counts["rejected"]``), never in the page's numbers.

    ``arm``: one arm of a fleet, read on its own keys; the fleet's topics (the learner's retreats and
    telemetry, the arms' transitions) are read once by ``FleetState``, which hands each arm its own."""

    def __init__(
        self, bus: Bus, history: int = 600, limits: ViewLimits | None = None, arm: str | None = None
    ) -> None:
        self.bus = bus
        self.arm = arm
        self.limits = limits or ViewLimits()
        self.lock = threading.Lock()
        self._json = JsonCache(self.snapshot)
        self.name = bus.robot if arm is None else f"{bus.fleet}/{arm}"
        self.segments: deque[dict[str, Any]] = deque(maxlen=history)
        self.statistic: deque[tuple[int, float, str]] = deque(maxlen=history * 5)
        self.threshold = 0.0
        self.chunks: deque[dict[str, Any]] = deque(maxlen=50)
        self.ee: deque[list[float]] = deque(maxlen=history)
        self.target: deque[list[float]] = deque(maxlen=history)
        self.returns: deque[dict[str, Any]] = deque(maxlen=history)
        self.safety: deque[dict[str, Any]] = deque(maxlen=100)
        self.robot: dict[str, Any] = {}
        self.learner: dict[str, Any] = {}
        self.current_chunk: dict[str, Any] = {}
        self.image: bytes = b""
        self.image_detected = False
        self.counts = {
            "retreats": 0,
            "segments": 0,
            "dropped": 0,
            "dropped_at_retreat": 0,
            "safety": 0,
            "messages": 0,
            "refused": 0,  # chunks robot-io refused: stale, foreign (not the obeyed session), a seq jump
        }
        self.session = ""  # the learner session the arm obeys (from state)
        self._n_state = 0
        self._state_at = 0.0  # monotonic, when the last state came: an arm gone silent shows it
        # (session, chunk seq) -> plan, the newest PLANS_KEPT in arrival order
        self.plans: dict[tuple[str, int], dict[str, Any]] = {}
        self.episodes = 0  # an arm of a fleet: its episodes ended (from its transitions)
        self._next_step: dict[str, int] = {}  # an arm: per actor stream, the next step not yet counted
        self._open: dict[str, tuple[int, float]] = {}  # an arm: per stream, (open episode, its return so far)
        bus.subscribe(m.STATE, self._state, arm=arm)
        bus.subscribe(m.TARGET, self._target, arm=arm)
        bus.subscribe(m.CMD_CHUNK, self._chunk, arm=arm)
        bus.subscribe(m.CHUNK_STATUS, self._status, arm=arm)
        bus.subscribe(m.EVENTS_SAFETY, self._safety, arm=arm)
        bus.subscribe(m.CAMERA_ANNOTATED, self._image, arm=arm)
        if arm is None:
            bus.subscribe(m.EVENTS_RETREAT, self._retreat, check=self.limits.problem)
            bus.subscribe(m.TELEMETRY_LEARNER, self._telemetry)

    def _state(self, s: m.RobotState) -> None:
        with self.lock:
            self.counts["messages"] += 1
            self.robot = {
                "mode": m.label(s, "mode"),
                "ee": list(s.ee_pos),
                "chunk_seq": s.chunk_seq,
                "queue_len": s.queue_len,
                "session": s.session,
                "joint_speed": max((abs(v) for v in s.dq), default=0.0),  # rad/s, the hold check
                "stamp": s.stamp,
            }
            self.session = s.session
            self._state_at = time.monotonic()
            self._n_state += 1
            if self._n_state % 2 == 0:
                self.ee.append([round(x, 4) for x in s.ee_pos])
            plan = self.plans.get((s.session, s.played_chunk))
            if plan is not None and s.tick > plan["last_tick"]:  # a state between ticks repeats its tick
                plan["path"].append([round(x, 4) for x in s.ee_pos])
                plan["executed"] = s.played_index + 1
                plan["last_tick"] = s.tick

    def _target(self, t: m.Target) -> None:
        if t.valid:
            with self.lock:
                self.target.append([round(x, 4) for x in t.position])

    def _retreat(self, e: m.RetreatEvent) -> None:
        reason = m.label(e, "reason")
        with self.lock:
            self.counts["segments"] += 1
            self.counts["retreats"] += reason == "retreat"
            self.threshold = e.threshold
            self.segments.append({"segment": e.segment, "H": e.H, "reason": reason, "step": e.global_step})
            for x in e.statistic:
                self.statistic.append((e.segment, round(x, 5), reason))

    def _chunk(self, c: m.ActionChunk) -> None:
        with self.lock:
            if self.session and c.session != self.session:
                return  # not the session the arm obeys: robot-io refuses it (shown with its status)
            self.current_chunk = {
                "chunk_seq": c.seq,
                "n": len(c.actions) // 3,
                "segment": c.segment,
                "executed": 0,
                "dropped": 0,
            }
            if c.predicted_ee:
                self._plan(c)

    def _plan(self, c: m.ActionChunk) -> None:
        """A new plan: its predicted path, starting where the arm is now (caller holds the lock)."""
        start = [round(x, 4) for x in self.robot.get("ee", [])]
        planned = [[round(x, 4) for x in c.predicted_ee[i : i + 3]] for i in range(0, len(c.predicted_ee), 3)]
        self.plans[(c.session, c.seq)] = {
            "session": c.session,
            "chunk_seq": c.seq,
            "segment": c.segment,
            "n": len(c.actions) // 3,
            "planned": ([start] if start else []) + planned,
            "path": [start] if start else [],
            "executed": 0,
            "dropped": 0,
            "last_tick": -1,
            "parted_tick": None,  # the tick of the last action played before a newer plan cut it short
            "by_retreat": False,
            "done": False,
        }
        while len(self.plans) > PLANS_KEPT:
            del self.plans[next(iter(self.plans))]

    def _status(self, s: m.ChunkStatus) -> None:
        verdict = m.label(s, "verdict")
        with self.lock:
            if verdict in REFUSALS:
                self.counts["refused"] += 1
                self.chunks.append(
                    {"chunk_seq": s.chunk_seq, "executed": 0, "dropped": 0, "refused": verdict}
                )
                return
            self.counts["dropped"] += s.dropped
            if self.current_chunk.get("chunk_seq") == s.chunk_seq:
                self.current_chunk.update(executed=s.executed, dropped=s.dropped)
            plan = self.plans.get((s.session, s.chunk_seq))
            if plan is not None:
                plan.update(executed=s.executed, dropped=s.dropped, done=s.done)
                if s.dropped and s.preempted_by >= 0:
                    plan["parted_tick"] = plan["last_tick"]
                    # Robot-io's status says why the plan that cut this one was made.
                    plan["by_retreat"] = m.label(s, "preempted_by_opening") == "retreat"
                    self.counts["dropped_at_retreat"] += s.dropped if plan["by_retreat"] else 0
            if s.done:
                self.chunks.append(
                    {
                        "chunk_seq": s.chunk_seq,
                        "executed": s.executed,
                        "dropped": s.dropped,
                        "preempted_by": s.preempted_by,
                    }
                )

    def _safety(self, e: m.SafetyEvent) -> None:
        with self.lock:
            self.counts["safety"] += 1
            kind = m.label(e, "kind")
            self.safety.append({"kind": kind, "detail": e.detail, "held": e.held, "stamp": e.stamp})

    def _telemetry(self, t: m.LearnerTelemetry) -> None:
        with self.lock:
            self.learner = {
                "step": t.global_step,
                "episode": t.episode,
                "paused": t.paused,
                "algo": t.algo,
                "started_from": t.started_from,
            }
            if self.arm is not None:
                return  # the learner's episodes are every arm's: an arm's own come with its transitions
            if t.episode and (not self.returns or self.returns[-1]["episode"] != t.episode):
                self.returns.append({"episode": t.episode, "ret": t.episode_return, "success": t.success})

    def _transition(self, t: m.Transition) -> None:
        """An arm's tick: its episode's return so far, and at the episode's end its return and success. A
        step counted before (the actor sends again what the learner lacks) is not counted twice."""
        with self.lock:
            if t.step < self._next_step.get(t.stream, 0):
                return
            self._next_step[t.stream] = t.step + 1
            episode, ret = self._open.get(t.stream, (t.episode, 0.0))
            ret = (ret if episode == t.episode else 0.0) + t.reward
            if not (t.terminated or t.truncated):
                self._open[t.stream] = (t.episode, ret)
                return
            self._open.pop(t.stream, None)
            self.episodes += 1
            self.returns.append({"episode": self.episodes, "ret": round(ret, 4), "success": t.success})

    def _success(self) -> dict[str, Any]:
        """The success rate over the last ``SUCCESS_WINDOW`` finished episodes, and the episode count (an
        arm of a fleet: its own). Caller holds the lock."""
        recent = [bool(r["success"]) for r in list(self.returns)[-SUCCESS_WINDOW:]]
        rate = sum(recent) / len(recent) if recent else None
        return {
            "rate": rate,
            "of": len(recent),
            "window": SUCCESS_WINDOW,
            "episodes": self.learner.get("episode", 0) if self.arm is None else self.episodes,
        }

    def summary(self) -> dict[str, Any]:
        """The arm's row in the fleet's list: its mode (and how long ago it said so, by this clock: the
        arm's may differ), success, retreats and last plan."""
        with self.lock:
            return {
                "arm": self.arm,
                "mode": self.robot.get("mode", ""),
                "age_s": round(time.monotonic() - self._state_at, 1) if self.robot else None,
                "success": self._success(),
                "retreats": self.counts["retreats"],
                "segments": self.counts["segments"],
                "chunk": dict(self.current_chunk),
            }

    def _image(self, a: m.AnnotatedImage) -> None:
        with self.lock:
            self.image, self.image_detected = a.jpeg, a.detected

    def snapshot_json(self, max_age_s: float = SNAPSHOT_MAX_AGE_S) -> bytes:
        """The snapshot as JSON, built at most once per ``max_age_s`` (``JsonCache``)."""
        return self._json.get(max_age_s)

    def snapshot(self) -> dict[str, Any]:
        with self.lock:
            return {
                "name": self.name,
                "robot": self.robot,
                "learner": self.learner,
                "segments": list(self.segments),
                "statistic": list(self.statistic),
                "threshold": self.threshold,
                "chunk": self.current_chunk,
                "chunks": list(self.chunks)[-20:],
                "ee": list(self.ee),
                "target": list(self.target),
                "returns": list(self.returns),
                "success": self._success(),
                "safety": list(self.safety)[-20:],
                "counts": dict(self.counts) | {"rejected": sum(self.bus.bad_messages.values())},
                "plans": [
                    {k: v for k, v in p.items() if k != "last_tick"}
                    | {"queued": max(0, p["n"] - p["executed"] - p["dropped"])}
                    for p in sorted(self.plans.values(), key=lambda p: p["chunk_seq"])
                    if p["session"] == self.session or not self.session
                ],
                "image": bool(self.image),
                "detected": self.image_detected,
            }


class FleetState:
    """The arms of a fleet, each a ``MonitorState`` on its own keys. The fleet's topics are read here once
    and handed to the arm each names: retreats and transitions by their ``arm``, the learner's telemetry
    to every arm (the detail view shows the learner too)."""

    def __init__(self, bus: Bus, arms: Sequence[str], history: int, limits: ViewLimits | None) -> None:
        self.arms = {arm: MonitorState(bus, history, limits, arm=arm) for arm in arms}
        self._json = {arm: JsonCache(lambda arm=arm: self.snapshot(arm)) for arm in arms}
        checked = limits or ViewLimits()
        bus.subscribe(m.EVENTS_RETREAT, self._retreat, check=checked.problem)
        bus.subscribe(m.TELEMETRY_LEARNER, self._telemetry)
        bus.subscribe(m.TRANSITIONS, self._transition)

    def _retreat(self, e: m.RetreatEvent) -> None:
        if e.arm in self.arms:
            self.arms[e.arm]._retreat(e)

    def _transition(self, t: m.Transition) -> None:
        if t.arm in self.arms:
            self.arms[t.arm]._transition(t)

    def _telemetry(self, t: m.LearnerTelemetry) -> None:
        for state in self.arms.values():
            state._telemetry(t)

    def snapshot(self, arm: str) -> dict[str, Any]:
        """Arm ``arm``'s detail, and the list of every arm."""
        rows = [state.summary() for state in self.arms.values()]
        return self.arms[arm].snapshot() | {"fleet": {"arm": arm, "arms": rows}}

    def snapshot_json(self, arm: str, max_age_s: float = SNAPSHOT_MAX_AGE_S) -> bytes:
        return self._json[arm].get(max_age_s)


class MonitorServer(Node):
    """HTTP server + Zenoh state on ``bus`` (closed with the server); ``token`` guards control requests.
    ``arms``: the fleet's (``StackConfig.arm_names``); none, or the one arm "" of a plain stack: one arm on
    the stack's keys. ``state`` is the one arm's, or the fleet's first arm's (what the page shows first)."""

    def __init__(
        self,
        bus: Bus,
        config: MonitorConfig,
        token: str | None = None,
        limits: ViewLimits | None = None,
        arms: Sequence[str] = (),
    ) -> None:
        super().__init__(bus.robot, bus=bus)
        self.config = config
        self.token = token or secrets.token_urlsafe(12)
        named = [arm for arm in arms if arm]
        self.fleet = FleetState(bus, named, config.history, limits) if named else None
        self.state = (
            MonitorState(bus, config.history, limits) if self.fleet is None else self.fleet.arms[named[0]]
        )
        # By the key each goes on: "" the stack's (a fleet's: every arm and the learner obey it), an arm's.
        self._pubs: dict[str, Publisher[m.Control]] = {"": bus.publisher(m.CONTROL)}
        self._pubs.update({arm: bus.publisher(m.CONTROL, arm=arm) for arm in named})
        self.controls: deque[str] = deque(maxlen=256)  # the newest requests obeyed (a flood stays small)
        self._reports = Throttle("like it")
        server = self

        class Handler(BaseHTTPRequestHandler):
            timeout = 5.0  # a request that never sends its promised body does not hold a thread for good

            def log_message(self, fmt: str, *args: Any) -> None:
                log.debug(fmt, *args)

            def _send(self, code: int, body: bytes, ctype: str) -> None:
                self.send_response(code)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def do_GET(self) -> None:  # noqa: N802 (http.server's naming)
                path, _, query = self.path.partition("?")
                state = server.arm_state(parse_qs(query).get("arm", [""])[0])
                if path in ("/", "/index.html"):
                    self._send(200, (STATIC / "index.html").read_bytes(), "text/html; charset=utf-8")
                elif path in ("/api/state", "/api/image.jpg") and state is None:
                    self._send(404, b'{"ok": false, "error": "no such arm"}', "application/json")
                elif path == "/api/state":
                    self._send(200, server.state_json(state), "application/json")
                elif path == "/api/image.jpg":
                    with state.lock:
                        img = state.image
                    self._send(200 if img else 204, img, "image/jpeg")
                else:
                    self._send(404, b"not found", "text/plain")

            def _body(self) -> bytes:
                """The body, or what of it came before the time-out: one that lies about its length
                may still ask for an e-stop."""
                left, parts = _length(self.headers.get("Content-Length")), []
                try:
                    while left > 0 and (part := self.rfile.read1(left)):
                        parts.append(part)
                        left -= len(part)
                except OSError:
                    pass
                return b"".join(parts)

            def do_POST(self) -> None:  # noqa: N802
                if self.path.split("?")[0] != "/api/control":
                    self._send(404, b"not found", "text/plain")
                    return
                code, reply = server.post_control(self._body(), self.headers.get("X-Token"))
                self._send(code, json.dumps(reply).encode(), "application/json")

        self.httpd = Server((config.host, config.port), Handler)

    def arm_state(self, arm: str) -> MonitorState | None:
        """What the page asked for: the fleet's arm ``arm`` (its first for ""), None for an arm the fleet
        lacks; a stack of one arm has one."""
        if self.fleet is None or not arm:
            return self.state
        return self.fleet.arms.get(arm)

    def state_json(self, state: MonitorState) -> bytes:
        """``state``'s snapshot; in a fleet with the list of every arm."""
        if self.fleet is None or state.arm is None:
            return state.snapshot_json()
        return self.fleet.snapshot_json(state.arm)

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host}:{port}/"

    @staticmethod
    def _json_object(raw: bytes) -> dict[str, Any] | None:
        try:
            body = json.loads(raw or b"{}")
        except (ValueError, RecursionError):  # RecursionError: garbage nested a few thousand deep
            return None
        return body if isinstance(body, dict) else None

    def post_control(self, raw: bytes, header_token: str | None) -> tuple[int, dict[str, Any]]:
        """One ``POST /api/control`` body. A body without a readable command that mentions ``estop`` is
        an e-stop (stopping by mistake is safe, ignoring a stop is not); the rest needs a JSON object."""
        body = self._json_object(raw)
        command = body.get("command") if body is not None else None
        if not isinstance(command, str) and b"estop" in raw.lower():
            return self.estop()
        if body is None:
            return 400, {"ok": False, "error": "the body must be a JSON object"}
        try:
            name = "" if command is None else str(command)
            return self.control(name, body.get("jog"), header_token or body.get("token", ""), body.get("arm"))
        except (ValueError, TypeError) as exc:
            return 400, _error(exc)

    def _report(self, reason: str, text: str) -> None:
        """A log line per reason a minute at most: anyone who reaches the page can repeat a request."""
        line = self._reports.report(text, reason)
        if line is not None:
            log.warning("%s", line)

    def _target(self, arm: Any) -> str | None:
        """The key a request naming ``arm`` goes on (a key of ``_pubs``): a fleet's arm alone, or "" when
        it names none (or the stack has one arm); None for an arm the fleet lacks."""
        if self.fleet is None or arm is None or arm == "":
            return ""
        return arm if isinstance(arm, str) and arm in self._pubs else None

    def _sent(self, command: str, to: str) -> tuple[int, dict[str, Any]]:
        """Note a published request; the reply says, in a fleet, which arms it went to."""
        self.controls.append(f"{command} {to}".strip())
        reply = {"ok": True, "command": command, "at": time.time()}
        return 200, reply if self.fleet is None else reply | {"to": to or "all arms"}

    def estop(self, arm: Any = None) -> tuple[int, dict[str, Any]]:
        """Publish an e-stop: no token, nothing else asked (robot-io obeys one from anyone). ``arm``: that
        arm of a fleet alone; one the fleet lacks stops every arm (a stop by mistake is safe, one ignored
        is not)."""
        to = self._target(arm) or ""
        self._pubs[to](m.Control(command=m.Control.ESTOP, jog=[0.0, 0.0, 0.0], arm=to))
        self._report("estop", f"e-stop{' of ' + to if to else ''} published at the page's request")
        return self._sent("estop", to)

    def control(self, command: str, jog: Any, token: str, arm: Any = None) -> tuple[int, dict[str, Any]]:
        """Validate and publish one operator request; returns (HTTP code, reply). An e-stop needs
        no token and ignores the rest of the request. ``arm``: to that arm of a fleet alone (``_target``)."""
        if command.strip().lower() == "estop":
            return self.estop(arm)
        if not secrets.compare_digest(str(token).encode(), self.token.encode()):  # str: ASCII only
            self._report("token", f"control {command[:40]!r} refused: wrong or missing token")
            return 403, {"ok": False, "error": "wrong or missing token"}
        try:
            value = m.enum(m.Control, "command", command)
        except m.MessageError as exc:
            return 400, {"ok": False, "error": str(exc)}
        vec = [0.0, 0.0, 0.0] if jog is None else [float(x) for x in jog]
        if len(vec) != 3 or not all(math.isfinite(x) for x in vec):
            raise ValueError("jog must have 3 finite values")
        to = self._target(arm)
        if to is None:
            arms = list(self._pubs)[1:]
            return 400, {"ok": False, "error": f"no arm {str(arm)[:40]!r} in the fleet (arms: {arms})"}
        self._pubs[to](m.Control(command=value, jog=vec, arm=to))  # signed by the bus with the token's key
        return self._sent(command, to)

    def workers(self) -> dict[str, Callable[[], None]]:
        return {"monitor-http": self.httpd.serve_forever}

    def wake(self) -> None:
        if self._threads:  # shutdown() waits for serve_forever, which runs only once started
            self.httpd.shutdown()

    def close(self) -> None:
        self.httpd.server_close()
        super().close()
