"""Zenoh wiring shared by every node: open a session from config, typed publish/subscribe/query helpers.

On one machine the default is loopback with no router: the first session to start listens on the hub
endpoint and later ones connect to it (peers then find each other by gossip). Across machines set
``connect``/``listen`` (or ``mode: client`` pointing at a ``zenohd`` router). Incoming bytes are
decoded with ``deploy.messages``; a bad message is logged and counted, never raised into Zenoh.
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import zenoh

from deploy import messages
from deploy.messages import Message, MessageError

log = logging.getLogger(__name__)
M = TypeVar("M", bound=Message)
MODES = ("peer", "client", "router")


@dataclass(frozen=True)
class ZenohConfig:
    """The ``zenoh:`` section."""

    mode: str = "peer"
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    hub: str = "tcp/127.0.0.1:7447"  # loopback rendezvous when connect and listen are both empty
    multicast_scouting: bool = False
    options: dict[str, Any] = field(
        default_factory=dict
    )  # extra Zenoh config keys, e.g. {"transport/...": v}

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        for name in ("connect", "listen"):
            value = getattr(self, name)
            if isinstance(value, str) or not all(isinstance(e, str) and "/" in e for e in value):
                raise ValueError(
                    f"{name} must be a list of endpoints like 'tcp/127.0.0.1:7447', got {value!r}"
                )
            object.__setattr__(self, name, tuple(value))
        if not isinstance(self.hub, str) or "/" not in self.hub:
            raise ValueError(f"hub must be an endpoint like 'tcp/127.0.0.1:7447', got {self.hub!r}")
        if not isinstance(self.options, dict):
            raise ValueError("options must be a mapping of Zenoh config keys to values")


def _config(cfg: ZenohConfig, connect: list[str], listen: list[str]) -> zenoh.Config:
    zc = zenoh.Config()
    zc.insert_json5("mode", json.dumps(cfg.mode))
    zc.insert_json5("connect/endpoints", json.dumps(connect))
    zc.insert_json5("listen/endpoints", json.dumps(listen))
    zc.insert_json5("scouting/multicast/enabled", json.dumps(cfg.multicast_scouting))
    for key, value in cfg.options.items():
        zc.insert_json5(key, json.dumps(value))
    return zc


def own_listener(hub: str) -> str:
    """The hub's protocol and host with port 0: a joining peer's own listener (the OS picks the port)."""
    proto, _, address = hub.partition("/")
    host = address.rsplit(":", 1)[0]
    return f"{proto}/{host}:0"


def open_session(cfg: ZenohConfig) -> zenoh.Session:
    """Open a session; with no endpoints configured, listen on the hub or, if taken, join through it.

    Peers in Zenoh's default ``peer_to_peer`` routing never forward for each other, so a joiner that only
    connected to the hub reached the hub's owner and nobody else (tried: the third process heard one of
    two). A joiner therefore also listens on its own loopback port: the hub's gossip hands its locator to
    the other peers, which connect to it directly (a full mesh), so any number of parts reach each other
    and the mesh survives the hub's owner leaving.
    """
    if cfg.connect or cfg.listen:
        return zenoh.open(_config(cfg, list(cfg.connect), list(cfg.listen)))
    if cfg.mode == "client":
        return zenoh.open(_config(cfg, [cfg.hub], []))
    try:
        return zenoh.open(_config(cfg, [], [cfg.hub]))
    except zenoh.ZError:
        log.info("zenoh hub %s already taken; joining through it", cfg.hub)
        return zenoh.open(_config(cfg, [cfg.hub], [own_listener(cfg.hub)]))


class Bus:
    """Typed access to ``adaptiveh/<robot>/…`` on one session. Counts bad messages per topic."""

    def __init__(self, session: zenoh.Session, robot: str) -> None:
        self.session = session
        self.robot = robot
        self.bad_messages: dict[str, int] = {}
        self._lock = threading.Lock()
        self._declared: list[Any] = []

    def key(self, topic: str) -> str:
        return messages.key(self.robot, topic)

    def _bad(self, topic: str, exc: Exception) -> None:
        with self._lock:
            self.bad_messages[topic] = self.bad_messages.get(topic, 0) + 1
        log.warning("bad message on %s: %s", self.key(topic), exc)

    def publisher(self, topic: str, express: bool = True) -> Callable[[Message], None]:
        """A function that encodes and publishes a message on ``topic``."""
        pub = self.session.declare_publisher(self.key(topic), express=express)
        self._declared.append(pub)
        return lambda msg: pub.put(msg.encode())

    def subscribe(
        self,
        topic: str,
        cls: type[M],
        callback: Callable[[M], None],
        on_bad: Callable[[str, Exception], None] | None = None,
    ) -> None:
        """Call ``callback`` with each decoded ``cls`` message; bad bytes are logged, counted, reported."""

        def handler(sample: zenoh.Sample) -> None:
            try:
                msg = messages.decode(sample.payload.to_bytes(), cls)
            except MessageError as exc:
                self._bad(topic, exc)
                if on_bad is not None:
                    on_bad(topic, exc)
                return
            try:
                callback(msg)
            except Exception:  # a handler bug must not kill Zenoh's thread
                log.exception("handler for %s failed", self.key(topic))

        self._declared.append(self.session.declare_subscriber(self.key(topic), handler))

    def queryable(self, topic: str, cls: type[M], handler: Callable[[M], Message]) -> None:
        """Answer queries on ``topic``: the payload decodes to ``cls``, the reply is ``handler``'s message."""

        def on_query(query: zenoh.Query) -> None:
            try:
                payload = query.payload.to_bytes() if query.payload is not None else cls().encode()
                request = messages.decode(payload, cls)
            except MessageError as exc:
                self._bad(topic, exc)
                query.reply_err(str(exc).encode())
                return
            try:
                query.reply(query.key_expr, handler(request).encode())
            except Exception as exc:
                log.exception("queryable %s failed", self.key(topic))
                query.reply_err(f"{type(exc).__name__}: {exc}".encode())

        self._declared.append(self.session.declare_queryable(self.key(topic), on_query))

    def query(self, topic: str, request: Message, reply_cls: type[M], timeout: float = 10.0) -> M:
        """Send ``request`` and return the first reply; raises TimeoutError or MessageError."""
        for reply in self.session.get(self.key(topic), payload=request.encode(), timeout=timeout):
            if reply.ok is not None:
                return messages.decode(reply.ok.payload.to_bytes(), reply_cls)
            raise MessageError(
                f"{self.key(topic)}: error reply: {reply.err.payload.to_bytes().decode(errors='replace')}"
            )
        raise TimeoutError(f"no reply on {self.key(topic)} within {timeout} s")

    def declare_alive(self, name: str) -> zenoh.LivelinessToken:
        """Declare this process's liveliness token ``adaptiveh/<robot>/alive/<name>``."""
        token = self.session.liveliness().declare_token(self.key(f"{messages.LIVELINESS}/{name}"))
        self._declared.append(token)
        return token

    def watch_alive(self, on_change: Callable[[str, bool], None]) -> None:
        """``on_change(name, alive)`` for every peer token, including those already present."""
        prefix = self.key(messages.LIVELINESS) + "/"

        def handler(sample: zenoh.Sample) -> None:
            name = str(sample.key_expr)[len(prefix) :]
            on_change(name, sample.kind == zenoh.SampleKind.PUT)

        sub = self.session.liveliness().declare_subscriber(prefix + "*", handler, history=True)
        self._declared.append(sub)

    def close(self) -> None:
        for obj in reversed(self._declared):
            try:
                obj.undeclare()
            except Exception as exc:  # already gone with the session
                log.debug("undeclare: %s", exc)
        self._declared.clear()
        self.session.close()
