"""Recording every Zenoh message of a robot to MCAP, and replaying a recording back onto Zenoh.

One MCAP channel per key expression (``adaptiveh/<robot>/<topic>``), message encoding ``msgpack``, one
schema per message type (named after it, empty schema data: msgpack is self-describing and the types
live in ``deploy.messages``). Foxglove opens the file; ``adaptiveh replay`` republishes it with the
original timing so the monitor shows a past run.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path

import msgpack
import zenoh
from mcap.reader import make_reader
from mcap.writer import Writer

from deploy.messages import NAMESPACE

log = logging.getLogger(__name__)


def message_type(data: bytes) -> str:
    """The ``_t`` tag of an encoded message, or ``unknown`` (bad bytes are recorded too)."""
    try:
        payload = msgpack.unpackb(data, raw=False)
        return str(payload.get("_t", "unknown")) if isinstance(payload, dict) else "unknown"
    except Exception:  # msgpack raises several unrelated types on garbage
        return "unknown"


class Recorder:
    """Subscribes to ``adaptiveh/<robot>/**`` on ``session`` and writes every sample to ``path``."""

    def __init__(self, session: zenoh.Session, robot: str, path: str | Path, exclude: tuple[str, ...] = ()):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.path, "wb")
        self._writer = Writer(self._fh)
        self._writer.start(profile="", library="adaptiveh")
        self._lock = threading.Lock()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self.exclude = tuple(f"{NAMESPACE}/{robot}/{t}" for t in exclude)
        self.count = 0
        self._closed = False
        self._sub = session.declare_subscriber(f"{NAMESPACE}/{robot}/**", self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if key.startswith(self.exclude) if self.exclude else False:
            return
        data = sample.payload.to_bytes()
        now = time.time_ns()
        with self._lock:
            if self._closed:
                return
            channel = self._channels.get(key)
            if channel is None:
                name = message_type(data)
                schema = self._schemas.get(name)
                if schema is None:
                    schema = self._schemas[name] = self._writer.register_schema(name, "", b"")
                channel = self._channels[key] = self._writer.register_channel(key, "msgpack", schema)
            self._seq[key] = self._seq.get(key, 0) + 1
            self._writer.add_message(channel, now, data, now, self._seq[key])
            self.count += 1

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception as exc:  # the session may already be closed
            log.debug("undeclare: %s", exc)
        with self._lock:
            if not self._closed:
                self._closed = True
                self._writer.finish()
                self._fh.close()


def read(path: str | Path) -> list[tuple[str, str, int, bytes]]:
    """All messages of a recording as (key, schema name, log_time ns, payload), in time order."""
    out = []
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            out.append((channel.topic, schema.name if schema else "", message.log_time, message.data))
    return out


def recorded_robot(key: str) -> str:
    """``<robot>`` of ``adaptiveh/<robot>/<topic>``."""
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != NAMESPACE:
        raise ValueError(f"not an {NAMESPACE}/<robot>/<topic> key: {key!r}")
    return parts[1]


def replay(
    session: zenoh.Session,
    path: str | Path,
    speed: float = 1.0,
    stop: threading.Event | None = None,
    on_message: Callable[[str], None] | None = None,
    robot: str | None = None,
    wait_subscribers_s: float = 0.0,
) -> int:
    """Publish a recording onto ``session`` with its original timing divided by ``speed``.

    ``robot`` renames the keys (``adaptiveh/<robot>/…``) so a replay never reaches a live robot of the
    recorded name. ``wait_subscribers_s``: wait up to this long for a subscriber to match before the
    first message, so a subscriber elsewhere on the bus does not miss the start while peers connect.
    """
    records = read(path)
    if not records:
        return 0

    def renamed(key: str) -> str:
        if robot is None:
            return key
        return f"{NAMESPACE}/{robot}/" + key.split("/", 2)[2]

    publishers = {key: session.declare_publisher(renamed(key)) for key in {r[0] for r in records}}
    deadline = time.monotonic() + wait_subscribers_s
    while time.monotonic() < deadline and not any(p.matching_status.matching for p in publishers.values()):
        time.sleep(0.05)
    t0_rec, t0 = records[0][2], time.monotonic()
    try:
        for n, (key, _, stamp, data) in enumerate(records):
            if stop is not None and stop.is_set():
                return n
            delay = (stamp - t0_rec) / 1e9 / speed - (time.monotonic() - t0)
            if delay > 0:
                time.sleep(delay)
            publishers[key].put(data)
            if on_message is not None:
                on_message(renamed(key))
    finally:
        for pub in publishers.values():
            pub.undeclare()
    return len(records)
