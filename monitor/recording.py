"""Recording every Zenoh message of a robot to MCAP, and replaying a recording back onto Zenoh.

One MCAP channel per key expression (``adaptiveh/<robot>/<topic>``), message encoding ``protobuf``,
one schema per message type: its full name (``adaptiveh.RobotState``) and the ``FileDescriptorSet`` of
``adaptiveh.proto``, so any MCAP reader decodes the file with the schema alone (Foxglove does).
Bytes that do not decode as their key's type are kept too, wrapped in an ``adaptiveh.Rejected`` on the
channel ``_rejected/<key>``: nothing seen on the bus is lost. Given the stack's signing key, so are
messages of a signed type that are not the stack's (unsigned, forged, or a copy of one already recorded):
a typed channel holds only what the stack said, once. Given a ``Deriver``, the recorder also
writes Foxglove's well-known channels derived from the messages (``adaptiveh/<robot>/foxglove/...``:
image, transforms, 3D scene, log; ``monitor.foxglove.derive``), each with its own schema, so the file
opens in Foxglove's 3D, image and plot panels. ``adaptiveh replay`` republishes the robot's own
channels (not the rejected or derived ones) with the original timing.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh
import zenoh.ext
from mcap.exceptions import McapError
from mcap.records import Channel as McapChannel
from mcap.records import Message as McapMessage
from mcap.records import Schema as McapSchema
from mcap.stream_reader import StreamReader
from mcap.writer import Writer

from bus import messages as m
from bus.signing import KeyedVerifiers
from bus.transport import undeclare_quietly
from common.errors import AdaptiveHError
from monitor.foxglove.derive import Derived, Deriver, is_derived

log = logging.getLogger(__name__)
NAMESPACE = m.NAMESPACE
REJECTED = "_rejected/"
# MCAP packs times as uint64 ns, sequences as uint32 and channel ids as uint16; a value out of range fails
# half-way through a record and corrupts its chunk, so every value written is kept in range.
MAX_STAMP_S = 2.0**32  # a stamp below this is < 4.3e18 ns, inside uint64 (and Foxglove's uint32 seconds)
U32 = 2**32
MAX_OTHER_KEYS = 256  # keys outside the schema with their own channel; a stranger's further ones share one
OTHER_KEYS = "_other_keys"


class RecordingError(AdaptiveHError, ValueError):
    """A file that is not a recording this build can read."""


class Recorder:
    """Subscribes to ``adaptiveh/<robot>/**`` on ``session`` and writes every sample to ``path``.

    ``deriver``: writes the Foxglove channels derived from each valid message too (the stack passes one
    built from its config; without one the file holds the raw channels only). ``flush_s``: the data are
    written out (as a finished chunk) at least this often, so a recorder killed outright (SIGKILL, power
    loss) leaves a file that ``read`` opens with everything up to its last flush. ``split_s``: a file is
    finished and the next part (``<stem>.part2.mcap``, …; ``parts``) begun after this long, because an
    MCAP writer keeps one chunk index per flush in memory until the file ends (the soak's supervisor
    grew ~4 MB an hour with 1 s flushes); ``read`` of the first part reads them all. ``key``: the stack's
    signing key (``bus.signing.mac_key``); with it, a message of a signed type goes to its typed channel
    only if it is authentic and new (one ``Verifier`` per key), else to ``_rejected/<key>`` with the reason.
    """

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        path: str | Path,
        exclude: tuple[str, ...] = (),
        deriver: Deriver | None = None,
        flush_s: float = 1.0,
        split_s: float = 900.0,
        key: bytes | None = None,
        arms: tuple[str, ...] = (),
    ):
        """``arms``: a fleet's arms, whose own topics are under ``adaptiveh/<robot>/<arm>/``: each arm's
        channels are kept apart by their keys."""
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.parts: list[Path] = []
        self._split_s = split_s
        self._lock = threading.Lock()
        self._deriver = deriver
        self._begin(self.path)
        self._seq: dict[str, int] = {}  # per key, across parts
        self.robot = robot
        self._verifiers = KeyedVerifiers(key)  # per typed key, across parts
        self._other_keys: set[str] = set()  # keys outside the schema that have their own rejected channel
        self.derived = 0
        owners = [robot, *(f"{robot}/{arm}" for arm in arms)]
        self.exclude = tuple(f"{NAMESPACE}/{owner}/{t}" for owner in owners for t in exclude)
        self.count = 0
        self._closed = False
        self._done = threading.Event()
        self._flusher = threading.Thread(target=self._flush_every, args=(flush_s,), daemon=True)
        self._flusher.start()
        # The kept topics through advanced subscribers: they notice from the publishers' heartbeats what
        # they missed (a stall of this process, a link remade) and ask the publishers' caches for it
        # (``Topic.kept``), so nothing is lost while the recorder was away. Everything else (images,
        # a stranger's bytes on any key) through a plain one.
        kept = [t for t in m.TOPICS.values() if t.kept]
        kept_keys = [(t, t.key(robot)) for t in kept]
        kept_keys += [(t, t.key(f"{robot}/{arm}")) for t in kept if not t.fleet for arm in arms]
        self._kept_keys = {k for _, k in kept_keys}
        self._subs: list[Any] = []
        self.lost = 0  # messages it missed and could not get back (gone from the publisher's cache)
        for topic, kept_key in kept_keys:
            sub = zenoh.ext.declare_advanced_subscriber(
                session,
                kept_key,
                self._on_sample,
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=topic.kept),
                recovery=zenoh.ext.RecoveryConfig(periodic_queries=None, heartbeat=True),
            )
            self._subs += [sub.sample_miss_listener(self._on_miss), sub]
        self._subs.append(session.declare_subscriber(f"{NAMESPACE}/{robot}/**", self._on_other))

    def _begin(self, path: Path) -> None:
        """Start the file ``path`` (schemas and channels are registered again in each part)."""
        self._fh = open(path, "wb")
        self._writer = Writer(self._fh)
        self._writer.start(profile="", library="adaptiveh")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._started = time.monotonic()
        self.parts.append(path)
        if self._deriver is not None:
            self._deriver.robot_sent = False  # each part carries the robot's model for Foxglove

    def _flush_every(self, period: float) -> None:
        while not self._done.wait(period):
            with self._lock:
                if self._closed:
                    continue
                try:
                    if time.monotonic() - self._started >= self._split_s:
                        self._writer.finish()
                        self._fh.close()
                        self._begin(part_path(self.path, len(self.parts) + 1))
                    else:
                        self._writer.flush()
                except OSError:  # a full disk: say so, and try again at the next flush
                    log.exception("recording %s: could not write", self.parts[-1])

    def _on_miss(self, miss: zenoh.ext.Miss) -> None:
        with self._lock:
            self.lost += miss.nb
        log.error("recording: %d messages lost (missed, and no longer in their publisher's cache)", miss.nb)

    def _on_other(self, sample: zenoh.Sample) -> None:
        if str(sample.key_expr) not in self._kept_keys:  # those come through their advanced subscriber
            self._on_sample(sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if key.startswith(self.exclude) if self.exclude else False:
            return
        data = sample.payload.to_bytes()
        with self._lock:
            # Read under the lock: a record's log time and its channel sequence then rise together even
            # when two Zenoh threads deliver the same key at once (under load they did not).
            now = time.time_ns()
            if self._closed:
                return
            msg, error = self._checked(key, data)
            if msg is None:
                rejected = m.Rejected(key=key, error=error, data=data).SerializeToString()
                self._write(self._rejected_topic(key), m.Rejected, rejected, now, now)
            else:
                self._write(key, type(msg), data, now, publish_time(msg, now))
            self.count += 1
            if self._deriver is not None and msg is not None:
                for derived in self._deriver.feed(m.topic_of_key(key), msg):
                    self._write_derived(derived, now)
                    self.derived += 1

    def _write(self, key: str, msg_type: type[m.Message], data: bytes, now: int, sent: int) -> None:
        self._add(key, self._channel(key, msg_type), data, now, sent)

    def _write_derived(self, d: Derived, now: int) -> None:
        self._add(d.topic, self._derived_channel(d), d.data, now, now)

    def _add(self, key: str, channel: int, data: bytes, now: int, sent: int) -> None:
        """One record; its sequence wraps within uint32 (MCAP's), per key."""
        self._seq[key] = (self._seq.get(key, 0) + 1) % U32
        self._writer.add_message(channel, now, data, sent, self._seq[key])

    def _checked(self, key: str, data: bytes) -> tuple[m.Message | None, str]:
        """(the message, "") when ``data`` belongs on ``key``'s typed channel; (None, why) when not."""
        topic = m.topic_of_key(key)
        if topic is None:
            return None, f"{key}: not a topic of the schema"
        try:
            msg = topic.decode(data)
            self._verifiers.check(key, msg)
        except m.MessageError as exc:
            return None, str(exc)
        return msg, ""

    def _rejected_topic(self, key: str) -> str:
        """``_rejected/<key>``; past MAX_OTHER_KEYS keys outside the schema, one shared channel (the
        Rejected keeps the key), so a stranger's new keys cannot run MCAP out of channel ids."""
        if m.topic_of_key(key) is None and key not in self._other_keys:
            if len(self._other_keys) >= MAX_OTHER_KEYS:
                return REJECTED + m.key(self.robot, OTHER_KEYS)
            self._other_keys.add(key)
        return REJECTED + key

    def _channel(self, key: str, msg_type: type[m.Message]) -> int:
        channel = self._channels.get(key)
        if channel is None:
            name = msg_type.DESCRIPTOR.full_name
            schema = self._schemas.get(name)
            if schema is None:
                schema = self._writer.register_schema(name, "protobuf", m.file_descriptor_set(msg_type))
                self._schemas[name] = schema
            channel = self._channels[key] = self._writer.register_channel(key, "protobuf", schema)
        return channel

    def _derived_channel(self, d: Derived) -> int:
        channel = self._channels.get(d.topic)
        if channel is None:
            schema = self._schemas.get(d.schema_name)
            if schema is None:
                schema = self._writer.register_schema(d.schema_name, d.schema_encoding, d.schema_data)
                self._schemas[d.schema_name] = schema
            channel = self._writer.register_channel(d.topic, d.message_encoding, schema)
            self._channels[d.topic] = channel
        return channel

    def close(self) -> None:
        for sub in self._subs:
            undeclare_quietly(sub)
        with self._lock:
            self._done.set()
            if not self._closed:
                self._closed = True
                self._writer.finish()
                self._fh.close()


def publish_time(msg: m.Message, now: int) -> int:
    """When ``msg`` was sent, in ns: its stamp when that is a time MCAP holds, else ``now`` (arrival).

    A message got back late keeps when it was sent. A stamp of 1e12 s (a stranger's bit flip) decoded
    fine but made the writer fail half-way through the record: never passed to it.
    """
    stamp = getattr(msg, "stamp", 0.0)
    return int(stamp * 1e9) if 0.0 < stamp < MAX_STAMP_S else now


def part_path(first: Path, n: int) -> Path:
    """The ``n``-th file (from 2) of the recording that begins with ``first``: ``<stem>.part<n>.mcap``."""
    return first.with_name(f"{first.stem}.part{n}{first.suffix}")


def parts(path: str | Path) -> list[Path]:
    """The files of the recording that begins with ``path``, in order."""
    out, first = [Path(path)], Path(path)
    while part_path(first, len(out) + 1).exists():
        out.append(part_path(first, len(out) + 1))
    return out


def read(path: str | Path) -> list[tuple[str, str, int, bytes]]:
    """All messages of a recording (every part from ``path`` on) as (key, schema name, log_time ns,
    payload), in time order.

    A file whose recorder was killed outright has no summary and ends mid-record: it is read as a
    stream up to its last whole record, with a warning (everything up to the recorder's last flush).
    Recordings made before the protobuf schema (msgpack channels) are refused with a RecordingError.
    The derived Foxglove channels are read too (the JSON ones among them); ``replayable`` drops them.
    """
    out = [r for part in parts(path) for r in _read_file(part)]
    out.sort(key=lambda r: r[2])
    return out


def _read_file(path: Path) -> list[tuple[str, str, int, bytes]]:
    schemas: dict[int, str] = {}
    channels: dict[int, McapChannel] = {}
    out = []
    with open(path, "rb") as fh:
        try:
            for record in StreamReader(fh, skip_magic=False).records:
                if isinstance(record, McapSchema):
                    schemas[record.id] = record.name
                elif isinstance(record, McapChannel):
                    _check_encoding(path, record)
                    channels[record.id] = record
                elif isinstance(record, McapMessage):
                    channel = channels[record.channel_id]
                    name = schemas.get(channel.schema_id, "")
                    out.append((channel.topic, name, record.log_time, record.data))
        except (McapError, struct.error) as exc:
            log.warning("%s ends early (%s): read to its last whole record, %d messages", path, exc, len(out))
    return out


def _check_encoding(path: str | Path, channel: McapChannel) -> None:
    if channel.message_encoding != "protobuf" and not is_derived(channel.topic):
        raise RecordingError(
            f"{path}: channel {channel.topic} is encoded as {channel.message_encoding!r}; this "
            "build reads protobuf recordings only (msgpack ones come from adaptiveh before the "
            "protobuf schema; replay them with that version)"
        )


def replayable(records: list[tuple[str, str, int, bytes]]) -> list[tuple[str, str, int, bytes]]:
    """The records of the robot's own topics: not the rejected bytes, not the derived Foxglove channels."""
    return [r for r in records if m.topic_of_key(r[0]) is not None]


def each_tick_once(transitions: list[m.Transition]) -> list[m.Transition]:
    """Each executed tick once. An actor publishes a Transition again to a learner that lacks it
    (``deploy.transition_stream``), with a new ``seq`` and stamp, on the same stream with the same step:
    the first copy, in the order given, stands for the tick."""
    seen: set[tuple[str, int]] = set()
    out = []
    for tr in transitions:
        ident = (tr.stream, tr.step)
        if ident not in seen:
            seen.add(ident)
            out.append(tr)
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
    records = replayable(read(path))  # rejected bytes and derived channels stay in the file
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
