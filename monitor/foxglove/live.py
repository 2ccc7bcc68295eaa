"""The live view: Foxglove's WebSocket protocol, served by ``foxglove-sdk``, fed from the robot's Zenoh bus.

The same channels as a recording (``monitor.recording``): each of the robot's topics as it travels on
Zenoh (protobuf bytes, schema = the message type and ``adaptiveh.proto``'s FileDescriptorSet, forwarded
without re-encoding), and the channels ``monitor.foxglove.derive`` computes from them. So one layout
(``configs/foxglove_layout.json``) serves a recording and the live stack. Loopback by default: the
protocol has no authentication, and our web page stays the place for control (e-stop, jog).

The server runs on its own ``foxglove.Context``, so two servers (a test's, a replay's) never share
channels. Bytes that do not decode are not forwarded (the recording keeps them, under ``_rejected/``);
with the stack's signing key, neither are messages of a signed type that are not the stack's (unsigned,
forged, or a replayed copy): a viewer, and the deriver's paths and plans, see only what the stack said.
"""

from __future__ import annotations

import logging
import threading
import time

import foxglove
import zenoh

from bus import messages as m
from bus.signing import KeyedVerifiers
from monitor.foxglove.derive import ROBOT, Derived, Deriver, SceneSetup
from monitor.view_limits import ViewLimits

log = logging.getLogger(__name__)


class _Listener(foxglove.websocket.ServerListener):
    """Notes a viewer subscribing to the robot's meshes: they are sent once, so they are sent again."""

    def __init__(self, live: FoxgloveLive) -> None:
        self.live = live

    def on_subscribe(
        self, client: foxglove.websocket.Client, channel: foxglove.websocket.ChannelView
    ) -> None:
        if channel.topic == self.live.deriver.topic(ROBOT):
            self.live.robot_wanted.set()


class FoxgloveLive:
    """A Foxglove WebSocket server on ``host:port`` (0: any free port) showing ``robot``'s traffic.

    ``key``: the stack's signing key (``bus.signing.mac_key``); with it, a message of a signed type is
    shown only if it is authentic and new (one ``Verifier`` per key). Without one, everything that decodes.
    """

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        setup: SceneSetup | None = None,
        host: str = "127.0.0.1",
        port: int = 8766,
        exclude: tuple[str, ...] = (),
        key: bytes | None = None,
        limits: ViewLimits | None = None,
    ) -> None:
        self.robot, self.host = robot, host
        self._verifiers = KeyedVerifiers(key)
        self.context = foxglove.Context()
        self.deriver = Deriver(robot, setup, limits)
        self.robot_wanted = threading.Event()
        self.exclude = tuple(m.key(robot, t) for t in exclude)
        self.count = 0
        self._lock = threading.Lock()
        self._channels: dict[str, foxglove.Channel] = {}
        self.server = foxglove.start_server(
            name=f"adaptiveh/{robot}",
            host=host,
            port=port,
            context=self.context,
            server_listener=_Listener(self),
        )
        for topic in m.TOPICS.values():  # advertised up front, so a layout's panels subscribe at once
            if m.key(robot, topic.name) not in self.exclude:
                self._raw_channel(m.key(robot, topic.name), topic.type)
        self._sub = session.declare_subscriber(f"{m.NAMESPACE}/{robot}/**", self._on_sample)

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def url(self) -> str:
        """What to type into Foxglove's "Open connection" dialog (Foxglove WebSocket)."""
        return f"ws://{self.host}:{self.port}"

    def _raw_channel(self, key: str, msg_type: type[m.Message]) -> foxglove.Channel:
        channel = self._channels.get(key)
        if channel is None:
            schema = foxglove.Schema(
                name=msg_type.DESCRIPTOR.full_name, encoding="protobuf", data=m.file_descriptor_set(msg_type)
            )
            channel = foxglove.Channel(key, schema=schema, message_encoding="protobuf", context=self.context)
            self._channels[key] = channel
        return channel

    def _derived_channel(self, d: Derived) -> foxglove.Channel:
        channel = self._channels.get(d.topic)
        if channel is None:
            schema = foxglove.Schema(name=d.schema_name, encoding=d.schema_encoding, data=d.schema_data)
            channel = foxglove.Channel(
                d.topic, schema=schema, message_encoding=d.message_encoding, context=self.context
            )
            self._channels[d.topic] = channel
        return channel

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        topic = m.topic_of_key(key)
        if topic is None or key.startswith(self.exclude or ("\0",)):
            return
        data = sample.payload.to_bytes()
        try:
            msg = topic.decode(data)
        except m.MessageError as exc:
            log.debug("not forwarded: %s", exc)
            return
        now = time.time_ns()
        with self._lock:  # the deriver keeps paths and plans: one message at a time, in arrival order
            if not self._believed(key, msg):
                return
            self._raw_channel(key, topic.type).log(data, log_time=now)
            derived = self.deriver.feed(topic, msg)
            if isinstance(msg, m.RobotState) and self.robot_wanted.is_set():
                self.robot_wanted.clear()
                model = self.deriver.robot_model(msg.stamp)
                derived += [model] if model is not None else []
            for d in derived:
                self._derived_channel(d).log(d.data, log_time=now)
            self.count += 1

    def _believed(self, key: str, msg: m.Message) -> bool:
        """Whether ``msg`` is the stack's and new (under the lock: a replay guard sees each message once,
        in order); everything without a key."""
        try:
            self._verifiers.check(key, msg)
        except m.MessageError as exc:
            log.debug("not forwarded: %s", exc)
            return False
        return True

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception as exc:  # the session may already be closed
            log.debug("undeclare: %s", exc)
        self.server.stop()
        with self._lock:
            for channel in self._channels.values():
                channel.close()
            self._channels.clear()


def start_live(
    session: zenoh.Session,
    robot: str,
    setup: SceneSetup | None,
    host: str,
    port: int | None,
    exclude: tuple[str, ...] = (),
    key: bytes | None = None,
    limits: ViewLimits | None = None,
) -> FoxgloveLive | None:
    """The live server, or None when it is off (``port`` None) or cannot bind: the monitor runs without it.
    ``key``: the stack's signing key; with it only the stack's own signed messages are shown. ``limits``:
    the derived plots leave out-of-range values out (``monitor.view_limits``)."""
    if port is None:
        return None
    try:
        return FoxgloveLive(session, robot, setup, host, port, exclude, key, limits)
    except Exception as exc:  # foxglove-sdk raises its own error types on a port in use
        log.warning("Foxglove live view not started on %s:%s: %s", host, port, exc)
        return None
