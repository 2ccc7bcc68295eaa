"""Zenoh wiring shared by every node: open a session from config, typed publish/subscribe/query helpers.

On one machine the default is loopback with no router: the first session to start listens on the hub
endpoint and later ones connect to it (peers then find each other by gossip). Across machines set
``connect``/``listen`` (or ``mode: client`` pointing at a ``zenohd`` router). Incoming bytes are
decoded with ``bus.messages``; a bad message is logged and counted, never raised into Zenoh.
"""

from __future__ import annotations

import json
import logging
import signal
import socket
import threading
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any, Generic, Literal, TypeVar

import zenoh
import zenoh.ext
from pydantic import Field, model_validator

from bus import messages, security
from bus.messages import Message, MessageError, Service, Topic
from bus.security import AuthConfig, RouterConfig, TlsConfig
from bus.signing import Verifier, sign, signed
from common.config import Section
from common.errors import AdaptiveHError
from common.throttle import Throttle

log = logging.getLogger(__name__)
M = TypeVar("M", bound=Message)
R = TypeVar("R", bound=Message)
T = TypeVar("T")
QUERY_POLL_S = 0.01  # how often a query waiting for its reply looks at its cancel event


class QueryCancelled(AdaptiveHError, RuntimeError):
    """A query given up on its caller's word (``Bus.query(cancel=...)``) before a reply came."""


Endpoint = Annotated[str, Field(pattern=r"^[a-z][a-z0-9-]*/.+")]
"""A Zenoh locator such as ``tcp/127.0.0.1:7447``."""


class ZenohConfig(Section):
    """The ``zenoh:`` section."""

    mode: Literal["peer", "client", "router"] = Field(
        "peer",
        description="how this session joins the bus: peer (talks to the other parts directly), client"
        " (only through a router it connects to), router (relays for others)",
    )
    connect: tuple[Endpoint, ...] = Field(
        (),
        description="endpoints this session dials at start, e.g. [tcp/192.168.1.10:7447] or a router's"
        " tls/host:port; empty with listen empty: the loopback hub",
    )
    listen: tuple[Endpoint, ...] = Field(
        (), description="endpoints this session accepts connections on, e.g. [tcp/0.0.0.0:7447]"
    )
    hub: Endpoint = "tcp/127.0.0.1:7447"  # loopback rendezvous when connect and listen are both empty
    multicast_scouting: bool = Field(
        False,
        description="find other sessions by UDP multicast on the local network (off: only the endpoints)",
    )
    # A peer that dies without closing its session (SIGKILL, power, cable) is noticed when its lease
    # expires: Zenoh's default 10 s left the arm driven by a dead learner's last chunk that long. Set on
    # every session (the lease a peer declares is what the other side waits for).
    lease_ms: int = Field(1000, ge=200)
    options: dict[str, Any] = {}  # extra Zenoh config keys, e.g. {"transport/...": v}
    # Several machines (bus.security): mutual TLS, user/password, and the router's access control.
    # Paths and the user may contain {identity}: the process's own (learner, robot-io, ...).
    tls: TlsConfig | None = None
    auth: AuthConfig | None = Field(
        None, description="Zenoh user/password authentication of every session (null: none)"
    )
    router: RouterConfig | None = None  # the router's own settings, read only by `adaptiveh router --config`

    @model_validator(mode="after")
    def _secure_endpoints(self) -> ZenohConfig:
        if self.tls is not None:  # a tcp/ endpoint beside tls: would carry the bus in clear, unauthenticated
            used = {"connect": self.connect, "listen": self.listen}
            if not (self.connect or self.listen):
                used["hub"] = (self.hub,)
            if self.router is not None:
                used["router.listen"] = self.router.listen
            for name, endpoints in used.items():
                clear = [e for e in endpoints if not e.startswith(("tls/", "quic/"))]
                if clear:
                    raise ValueError(f"{name}: {clear} with zenoh.tls set: use tls/host:port endpoints")
        security.check_router(self)
        return self


GOSSIP_STRATEGY = {"peer": {"to_router": "always", "to_peer": "always"}}
TX_QUEUE_BATCHES = {
    "control": 1,
    "real_time": 4,
    "interactive_high": 4,
    "interactive_low": 4,
    "data_high": 16,
    "data": 16,
    "data_low": 16,
    "background": 4,
}


def _config(cfg: ZenohConfig, connect: list[str], listen: list[str], identity: str = "") -> zenoh.Config:
    """``cfg`` as Zenoh's config; ``identity`` picks this process's certificate and credentials."""
    zc = zenoh.Config()
    zc.insert_json5("mode", json.dumps(cfg.mode))
    zc.insert_json5("connect/endpoints", json.dumps(connect))
    zc.insert_json5("listen/endpoints", json.dumps(listen))
    zc.insert_json5("scouting/multicast/enabled", json.dumps(cfg.multicast_scouting))
    # Both ends of a gossiped peer link try to (re)connect, not only the greater Zenoh id (the default): a
    # link dropped by a stall past its lease is remade at the next gossip. With the default it could stay
    # lost while both parts kept the hub: robot-io's states stopped reaching vision and the test's peer
    # after a 1 s SIGSTOP of robot-io (the fault matrix, tests/deploy/test_fault_matrix.py).
    zc.insert_json5("scouting/gossip/autoconnect_strategy", json.dumps(GOSSIP_STRATEGY))
    # Express messages take a batch each, and Zenoh's default data queue holds 4 per link: a subscriber
    # busy for a few ticks (the recorder compressing a chunk) lost single states. Zenoh's maximum, 16.
    zc.insert_json5("transport/link/tx/queue/size", json.dumps(TX_QUEUE_BATCHES))
    zc.insert_json5("transport/link/tx/lease", json.dumps(cfg.lease_ms))
    zc.insert_json5("transport/link/tx/keep_alive", json.dumps(4))  # keep-alives per lease (Zenoh's default)
    for key, value in security.zenoh_keys(cfg, identity).items():
        zc.insert_json5(key, json.dumps(value))
    for key, value in cfg.options.items():
        zc.insert_json5(key, json.dumps(value))
    return zc


def own_listener(hub: str) -> str:
    """The hub's protocol and host with port 0: a joining peer's own listener (the OS picks the port)."""
    proto, _, address = hub.partition("/")
    host = address.rsplit(":", 1)[0]
    return f"{proto}/{host}:0"


def wait_listening(endpoint: str, timeout: float = 60.0, alive: Callable[[], bool] = lambda: True) -> None:
    """Block until something accepts TCP connections on ``endpoint`` (a hub's owner, a router): a peer
    opening its session on a free hub would take the hub itself. ``TimeoutError`` after ``timeout`` s or
    as soon as ``alive()`` (the process expected to listen) is false."""
    host, port = endpoint.partition("/")[2].rsplit(":", 1)
    deadline = time.monotonic() + timeout
    while True:
        try:
            socket.create_connection((host, int(port)), timeout=1).close()
            return
        except OSError:
            if time.monotonic() > deadline or not alive():
                raise TimeoutError(f"nothing listened on {endpoint}") from None
            time.sleep(0.2)


def open_session(cfg: ZenohConfig, identity: str | None = None) -> zenoh.Session:
    """Open a session; with no endpoints configured, listen on the hub or, if taken, join through it.

    ``identity`` (default: ``$ADAPTIVEH_ZENOH_IDENTITY``, else the CLI command's) names this process's
    certificate and credentials when ``cfg`` has ``tls``/``auth`` (bus.security); a missing file is a
    ConfigError naming the key.

    Peers in Zenoh's default ``peer_to_peer`` routing never forward for each other, so a joiner that only
    connected to the hub reached the hub's owner and nobody else (tried: the third process heard one of
    two). A joiner therefore also listens on its own loopback port: the hub's gossip hands its locator to
    the other peers, which connect to it directly (a full mesh), so any number of parts reach each other
    and the mesh survives the hub's owner leaving.
    """
    return _open(cfg, identity)[0]


def _open(cfg: ZenohConfig, identity: str | None) -> tuple[zenoh.Session, Callable[[], zenoh.Session] | None]:
    """``open_session``, and how to open a second session like it beside the first (None where the first
    holds a fixed listener, such as the hub, that the second would need)."""
    me = security.process_identity() if identity is None else identity
    if cfg.connect or cfg.listen:
        connect, listen = list(cfg.connect), list(cfg.listen)
    elif cfg.mode == "client":
        connect, listen = [cfg.hub], []
    else:
        try:
            return zenoh.open(_config(cfg, [], [cfg.hub], me)), None
        except zenoh.ZError:
            log.info("zenoh hub %s already taken; joining through it", cfg.hub)
            connect, listen = [cfg.hub], [own_listener(cfg.hub)]

    def again() -> zenoh.Session:
        return zenoh.open(_config(cfg, connect, listen, me))

    return again(), None if cfg.listen else again


class Publisher(Generic[M]):
    """Puts messages of one topic, stamping ``seq`` (1, 2, … or from ``first_seq``) and ``stamp``.

    The stamp is the wall clock when the message is put; the returned ``seq`` names the message (a
    chunk's seq is how the robot reports on it).
    """

    def __init__(
        self,
        pub: zenoh.Publisher,
        topic: Topic[M],
        first_seq: int = 1,
        seal: Callable[[M], None] | None = None,
        before_put: Callable[[], object] | None = None,
    ) -> None:
        self._pub = pub
        self.topic = topic
        self._seq = first_seq - 1
        self._seal = seal  # called after stamping, before serializing (e.g. to sign the message)
        self._before_put = before_put  # the bus's stall check (Bus.check_stall): may renew the session
        self._lock = threading.Lock()

    @property
    def next_seq(self) -> int:
        """The number the next message put will get."""
        return self._seq + 1

    def put(self, msg: M) -> int:
        if not isinstance(msg, self.topic.type):
            raise TypeError(f"{self.topic.name} carries {self.topic.type.__name__}, not {type(msg).__name__}")
        if self._before_put is not None:
            self._before_put()  # outside the lock: a renewal takes it to switch this publisher
        with self._lock:
            self._seq += 1
            msg.seq = self._seq
            msg.stamp = time.time()
            if self._seal is not None:
                self._seal(msg)
            self._pub.put(msg.SerializeToString())
            return self._seq

    __call__ = put


class Bus:
    """Typed access to ``adaptiveh/<robot>/…`` on one session. Counts bad messages per topic.

    With the stack's ``key`` (``bus.signing.mac_key`` of the operator token) it signs every message
    of a type that has a ``mac`` as it is put (or sent as a query), and drops received ones that do not
    verify, as bad messages (a subscriber may opt out to judge them itself: robot-io answers a forged
    chunk, and obeys an e-stop from anyone)."""

    def __init__(
        self, session: zenoh.Session, robot: str, key: bytes | None = None, fleet: str | None = None
    ) -> None:
        self.session = session
        self.robot = robot  # this part's keys: the stack's name, or ``<name>/<arm>`` for an arm of a fleet
        self.fleet = fleet or robot  # the keys every arm shares (``Topic.fleet``: the learner's)
        self.signing_key = key
        self.bad_messages: dict[str, int] = {}  # per topic: undecodable, invalid, forged or replayed
        self._reports = Throttle("like it")  # one log line per topic and reason per interval, not per message
        self.renewals = 0  # sessions reopened after a stall (``open``)
        self._lock = threading.Lock()
        self._declared: list[_Declared] = []
        self._renew_lock = threading.RLock()  # declarations and renewals, one at a time
        self._closed = threading.Event()
        self._reopen: Callable[[], zenoh.Session] | None = None  # how ``renew`` opens a session like this one
        self._stall_s: float | None = None  # a stall this long renews the session (``open``); None: never
        self._looked = (time.monotonic(), time.process_time())  # check_stall's last look: clock and CPU
        self._stall_lock = threading.Lock()
        self.continued = False  # set by the SIGCONT handler (``_watch_continue``): this process was stopped
        self._gap_judged_busy = (-float("inf"), 0.0)  # (when, how long) a long gap was judged no stop

    @classmethod
    def open(
        cls,
        cfg: ZenohConfig,
        robot: str,
        key: bytes | None = None,
        identity: str | None = None,
        fleet: str | None = None,
    ) -> Bus:
        """A bus on its own session that reopens that session when this process was stalled.

        A process stopped (SIGSTOP, swap, a debugger) for about a lease comes back to links that only
        some of its peers expired: Zenoh then keeps a half-closed link that nothing remakes (its gossip
        speaks only when a link is added; eclipse-zenoh/zenoh#2806), and a peer may never hear this
        process again (seen: the test's peer lost robot-io's states for good after a 1 s SIGSTOP). Past
        ``STALL_LEASES`` of its lease the process closes its session and opens a fresh one with every
        declaration remade, which every peer sees as a part leaving and coming back. Not for a session
        that holds a fixed listener (the hub's owner): the new one could not listen beside it.
        """
        session, again = _open(cfg, identity)
        bus = cls(session, robot, key, fleet)
        bus._reopen = again
        if again is not None:
            bus._stall_s = STALL_LEASES * cfg.lease_ms / 1000
            _watch_continue(bus)
            threading.Thread(target=bus._guard, name="zenoh-stall-guard", daemon=True).start()
        return bus

    def declare(self, make: Callable[[zenoh.Session], T]) -> T:
        """``make(session)``'s declaration (a subscriber, a token, …): undeclared on ``close`` and made
        again on a renewed session."""
        with self._renew_lock:
            obj = make(self.session)
            self._declared.append(_Declared(make, obj))
            return obj

    def _guard(self) -> None:
        """Look at this process's clocks every ``GUARD_TICK_S``, so a stall is seen within a tick."""
        while not self._closed.wait(GUARD_TICK_S):
            try:
                self.check_stall()
            except Exception:  # the guard must outlive a failed renewal
                log.exception("the Zenoh stall guard failed")

    def check_stall(self) -> bool:
        """Renew the session if this process was stalled since the last look; True if it did.

        A look that comes ``stall_s`` late while the process used almost no CPU means it was stopped or
        starved (Zenoh's threads with it). A thread holding the GIL (a long pickle) delays the look too,
        but burns CPU, and Zenoh's own threads, outside the GIL, kept the links alive: no renewal then.
        SIGCONT also says the process was stopped (``continued``): a thread that burned CPU holding the
        GIL right after the stop (vision's renderer, 50-180 ms a frame) hid it from the CPU test, and
        vision in the fault matrix never heard robot-io again. The handler runs in the main thread,
        possibly after this look judged the gap: a late SIGCONT renews at the next look.
        Publishers look before each put (``Publisher.before_put``), so nothing leaves a stalled process
        on links its peers may have half-closed, even before the guard's thread runs again."""
        if self._stall_s is None:
            return False
        now = time.monotonic()
        if now - self._looked[0] - GUARD_TICK_S <= self._stall_s:  # the common case: one clock read
            if now - self._looked[0] >= GUARD_TICK_S:
                self._looked = (now, time.process_time())
                if self.continued:
                    return self._late_continue()
            return False
        with self._stall_lock:
            last, cpu = self._looked
            now, now_cpu = time.monotonic(), time.process_time()
            stalled = now - last - GUARD_TICK_S
            if stalled <= self._stall_s:  # another thread looked (or renewed) meanwhile
                return False
            continued, self.continued = self.continued, False
            renewed = False
            if continued or now_cpu - cpu < STALL_CPU_SHARE * (now - last):
                renewed = self._renew_after(stalled)
            else:
                self._gap_judged_busy = (time.monotonic(), stalled)  # unless SIGCONT says otherwise soon
            self._looked = (time.monotonic(), time.process_time())  # the renewal itself is no stall
            return renewed

    def _late_continue(self) -> bool:
        """SIGCONT arrived after a look judged the gap busy: it was a stop after all (a SIGCONT with no
        long gap before it was a stop too short to matter)."""
        with self._stall_lock:
            if not self.continued:
                return False
            self.continued = False
            judged_at, stalled = self._gap_judged_busy
            self._gap_judged_busy = (-float("inf"), 0.0)
            if time.monotonic() - judged_at > LATE_CONTINUE_S:
                return False
            renewed = self._renew_after(stalled)
            self._looked = (time.monotonic(), time.process_time())
            return renewed

    def _renew_after(self, stalled: float) -> bool:
        assert self._stall_s is not None
        log.warning(
            "this process was stalled %.2f s (Zenoh lease %.2f s): reopening its Zenoh session",
            stalled,
            self._stall_s / STALL_LEASES,
        )
        return self.renew()

    def renew(self) -> bool:
        """Swap the session for a fresh one like it, remaking every declaration on it; False (the old
        session kept, its declarations restored) if the new one cannot be opened or declared on. No
        subscriber is on both; publishers switch one at a time and never wait on Zenoh. Only for a bus
        from ``open`` that holds no fixed listener (ValueError otherwise)."""
        if self._reopen is None:
            raise ValueError(
                "this bus cannot renew its session: it holds a fixed listener or came from outside"
            )
        try:
            fresh = self._reopen()
        except zenoh.ZError as exc:
            log.error("could not reopen the Zenoh session (%s); keeping the old one", exc)
            return False
        with self._renew_lock:
            if self._closed.is_set():
                fresh.close()
                return False
            for d in reversed(self._declared):
                if d.publisher is None:
                    undeclare_quietly(d.obj)
            made: list[Any] = []
            try:
                for d in self._declared:
                    made.append(d.make(fresh))
            except Exception as exc:
                log.error("could not declare on the new Zenoh session (%s); keeping the old one", exc)
                for obj in made:
                    undeclare_quietly(obj)
                fresh.close()
                for d in self._declared:
                    if d.publisher is None:
                        d.obj = d.make(self.session)
                return False
            old, self.session = self.session, fresh
            for d, obj in zip(self._declared, made, strict=True):
                d.obj = obj
                if d.publisher is not None:
                    with d.publisher._lock:
                        d.publisher._pub = obj
            old.close()
            self.renewals += 1
        return True

    def key(self, topic: Topic[Any] | Service[Any, Any] | str, arm: str | None = None) -> str:
        """``topic``'s key: the fleet's for a fleet topic; else this part's arm, or ``arm`` of the fleet
        (``*``: any arm's)."""
        name = topic if isinstance(topic, str) else topic.name
        if getattr(topic, "fleet", False):
            return messages.key(self.fleet, name)
        return messages.key(self.robot if arm is None else f"{self.fleet}/{arm}", name)

    def report_bad(self, name: str, exc: Exception) -> None:
        """Count a bad message on topic ``name`` and log it, rate-limited per key and reason (a part that
        judges messages itself, such as robot-io's commands, reports its refusals here too)."""
        reason = getattr(exc, "reason", type(exc).__name__)
        with self._lock:
            self.bad_messages[name] = self.bad_messages.get(name, 0) + 1
        line = self._reports.report(str(exc), (self.key(name), reason))
        if line is not None:
            log.warning("bad message on %s: %s", self.key(name), line)

    def publisher(
        self,
        topic: Topic[M],
        express: bool = True,
        first_seq: int = 1,
        seal: Callable[[M], None] | None = None,
        arm: str | None = None,
    ) -> Publisher[M]:
        """A publisher of ``topic``'s type on its key (``seal``: see ``Publisher``; then it is signed;
        ``arm``: another arm's key of the fleet, as ``key``)."""
        congestion = zenoh.CongestionControl

        qos = {
            "express": express,
            "priority": zenoh.Priority.REAL_TIME if topic.urgent else zenoh.Priority.DEFAULT,
            "congestion_control": congestion.BLOCK if topic.never_drop else congestion.DROP,
        }

        def make(session: zenoh.Session) -> zenoh.Publisher | zenoh.ext.AdvancedPublisher:
            if not topic.kept:
                return session.declare_publisher(self.key(topic, arm), **qos)
            return zenoh.ext.declare_advanced_publisher(  # a subscriber that missed some asks for them
                session,
                self.key(topic, arm),
                **qos,
                cache=zenoh.ext.CacheConfig(topic.kept),
                sample_miss_detection=zenoh.ext.MissDetectionConfig(
                    heartbeat=HEARTBEAT_S, sporadic_heartbeat=None
                ),
                publisher_detection=True,
            )

        with self._renew_lock:
            pub = make(self.session)
            check = self.check_stall if self._stall_s is not None else None
            wrapper = Publisher(pub, topic, first_seq, self._sealer(topic.type, seal), check)
            self._declared.append(_Declared(make, pub, wrapper))
        return wrapper

    def _sealer(self, cls: type[M], seal: Callable[[M], None] | None) -> Callable[[M], None] | None:
        key = self.signing_key
        if key is None or not signed(cls):
            return seal

        def seal_and_sign(msg: M) -> None:
            if seal is not None:
                seal(msg)
            sign(msg, key)

        return seal_and_sign

    def subscribe(
        self,
        topic: Topic[M],
        callback: Callable[[M], None],
        on_bad: Callable[[str, Exception, bytes], None] | None = None,
        verify: bool = True,
        check: Callable[[M], str | None] | None = None,
        arm: str | None = None,
    ) -> None:
        """Call ``callback`` with each decoded (and, with a key, authentic and new) message; bad bytes are
        counted, logged (rate-limited) and reported to ``on_bad`` (topic, error, the bytes). ``check``:
        the reader's own rule (e.g. a view's range), its complaint handled as a bad message's. ``arm``:
        another arm's key of the fleet, as ``key``."""
        verifier = Verifier(self.signing_key) if verify and self.signing_key and signed(topic.type) else None

        def handler(sample: zenoh.Sample) -> None:
            data = sample.payload.to_bytes()
            try:
                msg = topic.decode(data)
                if verifier is not None:
                    verifier.check(topic.name, msg)
                problem = check(msg) if check is not None else None
                if problem is not None:
                    raise MessageError(f"{topic.name}: {problem}", "out_of_range")
            except MessageError as exc:
                self.report_bad(topic.name, exc)
                if on_bad is not None:
                    on_bad(topic.name, exc, data)
                return
            try:
                callback(msg)
            except Exception:  # a handler bug must not kill Zenoh's thread
                log.exception("handler for %s failed", self.key(topic, arm))

        self.declare(lambda s: s.declare_subscriber(self.key(topic, arm), handler))

    def queryable(self, service: Service[M, R], handler: Callable[[M], R]) -> None:
        """Answer queries: the payload decodes to the request type, the reply is ``handler``'s."""

        def on_query(query: zenoh.Query) -> None:
            try:
                payload = query.payload.to_bytes() if query.payload is not None else b""
                request = messages.decode(payload, service.request)
            except MessageError as exc:
                self.report_bad(service.name, exc)
                query.reply_err(str(exc).encode())
                return
            try:
                reply = handler(request)
                reply.stamp = time.time()
                query.reply(query.key_expr, reply.SerializeToString())
            except Exception as exc:
                log.exception("queryable %s failed", self.key(service))
                query.reply_err(f"{type(exc).__name__}: {exc}".encode())

        self.declare(lambda s: s.declare_queryable(self.key(service), on_query))

    def query(
        self,
        service: Service[M, R],
        request: M,
        timeout: float = 10.0,
        seal: Callable[[M], None] | None = None,
        cancel: threading.Event | None = None,
    ) -> R:
        """Send ``request`` (stamped, then ``seal``-ed) and return the first reply; raises TimeoutError or
        MessageError, and QueryCancelled as soon as ``cancel`` is set (a stopping node does not wait out
        a reply that takes seconds, e.g. a reset while the arm homes)."""
        request.stamp = time.time()
        sealer = self._sealer(service.request, seal)
        if sealer is not None:
            sealer(request)
        key = self.key(service)
        replies = self.session.get(key, payload=request.SerializeToString(), timeout=timeout)
        cancel = cancel or threading.Event()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                reply = replies.try_recv()
            except zenoh.ZError:  # the query is over (no queryable, or each one's reply is in)
                break
            if reply is not None and reply.ok is not None:
                return messages.decode(reply.ok.payload.to_bytes(), service.reply)
            if reply is not None:
                raise MessageError(
                    f"{key}: error reply: {reply.err.payload.to_bytes().decode(errors='replace')}"
                )
            if cancel.wait(QUERY_POLL_S):
                raise QueryCancelled(f"{key}: the query was cancelled before a reply")
        raise TimeoutError(f"no reply on {key} within {timeout} s")

    def declare_alive(self, name: str) -> zenoh.LivelinessToken:
        """Declare this process's liveliness token ``adaptiveh/<robot>/alive/<name>``."""
        return self.declare(lambda s: s.liveliness().declare_token(self.key(f"{messages.LIVELINESS}/{name}")))

    def alive_now(self, name: str, timeout: float = 1.0, fleet: bool = False) -> bool:
        """Whether the token ``alive/<name>`` (``fleet``: the fleet's, e.g. the learner's) exists now, asked
        of the network: a subscriber's view (``watch_alive``) can lag a request that reached this session
        first. ConnectionError when the query cannot be made."""
        owner = self.fleet if fleet else self.robot
        key = messages.key(owner, f"{messages.LIVELINESS}/{name}")
        try:
            return any(reply.ok is not None for reply in self.session.liveliness().get(key, timeout=timeout))
        except zenoh.ZError as exc:  # e.g. the session is closing
            raise ConnectionError(f"liveliness query {key}: {exc}") from exc

    def watch_alive(self, on_change: Callable[[str, bool], None], below: str = "") -> None:
        """``on_change(name, alive)`` for every peer token (``alive/<name>``, or ``alive/<below>/<name>``),
        including those already present."""
        prefix = self.key(messages.LIVELINESS) + "/" + (f"{below}/" if below else "")

        def handler(sample: zenoh.Sample) -> None:
            name = str(sample.key_expr)[len(prefix) :]
            on_change(name, sample.kind == zenoh.SampleKind.PUT)

        self.declare(lambda s: s.liveliness().declare_subscriber(prefix + "*", handler, history=True))

    def watch_arms(self, part: str, on_change: Callable[[str, bool], None]) -> None:
        """``on_change(arm, alive)`` whenever ``part`` (e.g. ``actor``) of an arm of the fleet comes or goes
        (``adaptiveh/<fleet>/<arm>/alive/<part>``; ``arm`` "" for a stack of one arm), those present first."""
        fleet = messages.key(self.fleet, "")
        tail = f"/{messages.LIVELINESS}/{part}"

        def handler(sample: zenoh.Sample) -> None:
            arm = str(sample.key_expr)[len(fleet) : -len(tail)]
            on_change(arm, sample.kind == zenoh.SampleKind.PUT)

        for below in (fleet.rstrip("/"), fleet + "*"):
            self.declare(
                lambda s, k=below + tail: s.liveliness().declare_subscriber(k, handler, history=True)
            )

    def close(self) -> None:
        with self._renew_lock:
            self._closed.set()
            for d in reversed(self._declared):
                undeclare_quietly(d.obj)
            self._declared.clear()
            self.session.close()


HEARTBEAT_S = 0.5
"""How often a publisher of a ``kept`` topic tells its newest seq, so a subscriber notices what it missed."""

STALL_LEASES = 0.6
"""A stall this many leases long makes ``Bus.open``'s bus renew its session: peers send a keep-alive every
quarter lease, so the earliest of them expires a stopped process's link after 3/4 of a lease."""
# At most this share of a core used meanwhile: stopped (SIGSTOP, a paused VM), not merely starved. Tried
# 0.25: vision at nice 5 on 2 cores at load 14 got ~5 % and renewed four times in 5 s, each renewal more
# links and memory for every peer; a starved process's links are Zenoh's to keep or remake.
STALL_CPU_SHARE = 0.02
GUARD_TICK_S = 0.1
LATE_CONTINUE_S = 2.0  # a SIGCONT handled this long after a gap judged busy still counts as that gap's stop


_CONTINUED: weakref.WeakSet[Bus] = weakref.WeakSet()  # buses told when this process is continued


def _on_continue(signum: int, frame: object) -> None:
    """SIGCONT: this process was stopped (SIGSTOP, Ctrl-Z, a debugger). Only sets flags: a handler
    runs between two bytecodes of the main thread, which may hold a lock (``bus.node.on_stop_signal``)."""
    for bus in list(_CONTINUED):
        bus.continued = True


def _watch_continue(bus: Bus) -> None:
    """Tell ``bus`` when the process is continued; the handler is installed from the main thread only
    (elsewhere Python refuses it, and the CPU test stands alone)."""
    _CONTINUED.add(bus)
    if threading.current_thread() is threading.main_thread() and hasattr(signal, "SIGCONT"):
        if signal.getsignal(signal.SIGCONT) is not _on_continue:
            signal.signal(signal.SIGCONT, _on_continue)


@dataclass
class _Declared:
    make: Callable[[zenoh.Session], Any]  # declares it on a session
    obj: Any  # the declaration on the current session
    publisher: Publisher[Any] | None = None  # the wrapper that puts through ``obj``


def undeclare_quietly(obj: Any) -> None:
    """Undeclare a Zenoh declaration that may already be gone with its session."""
    try:
        obj.undeclare()
    except Exception as exc:  # already gone with the session
        log.debug("undeclare: %s", exc)
