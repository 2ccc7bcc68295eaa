"""The typed bus on real Zenoh sessions: a topic carries its one type, the publisher stamps ``seq`` and
``stamp``, bad bytes are counted and reported (never raised into Zenoh), a queryable answers typed."""

import threading
import time

import pytest
from bus_probe import LABELS
from loopback import unique_name
from polling import wait_until

from bus import messages as m
from bus.transport import Bus, QueryCancelled, ZenohConfig, open_session


@pytest.fixture
def buses(endpoint):
    name = unique_name("tr")
    a = Bus(open_session(ZenohConfig(listen=(endpoint,))), name)
    b = Bus(open_session(ZenohConfig(connect=(endpoint,))), name)
    yield a, b
    b.close()
    a.close()


def test_publisher_stamps_and_subscriber_decodes(buses):
    a, b = buses
    got, bad = [], []
    b.subscribe(m.CHUNK_STATUS, got.append, on_bad=lambda topic, exc, data: bad.append((topic, str(exc))))
    pub = a.publisher(m.CHUNK_STATUS, first_seq=41)
    time.sleep(0.3)  # let the subscription reach the publisher's session
    before = time.time()
    seqs = [
        pub.put(m.ChunkStatus(chunk_seq=i, preempted_by=-1, verdict=m.ChunkStatus.ACCEPTED, **LABELS))
        for i in range(3)
    ]
    a.session.put(a.key(m.CHUNK_STATUS), b"\xff\xff not protobuf")
    wait_until(lambda: len(got) == 3 and bad, what="three statuses and the bad bytes")
    assert seqs == [41, 42, 43] and [s.seq for s in got] == seqs
    assert all(before <= s.stamp <= time.time() for s in got)
    assert bad[0][0] == "cmd/status" and "ChunkStatus: undecodable" in bad[0][1]
    assert b.bad_messages == {"cmd/status": 1}


def test_a_topic_refuses_another_type(buses):
    a, _ = buses
    pub = a.publisher(m.CMD_CHUNK)
    with pytest.raises(TypeError, match="cmd/chunk carries ActionChunk, not Control"):
        pub.put(m.Control(command=m.Control.ESTOP, jog=[0, 0, 0]))


def test_queryable_answers_typed_and_refuses_bad_requests(buses):
    a, b = buses
    seen = threading.Event()

    def on_reset(req: m.ResetRequest) -> m.ResetReply:
        seen.set()
        return m.ResetReply(ok=req.seed == 5, detail=f"seed {req.seed}")

    a.queryable(m.RESET, on_reset)
    time.sleep(0.3)
    reply = b.query(m.RESET, m.ResetRequest(seed=5), timeout=5)
    assert isinstance(reply, m.ResetReply) and reply.ok and reply.detail == "seed 5" and reply.stamp > 0
    replies = list(b.session.get(b.key(m.RESET), payload=b"\xff\xff", timeout=5))
    assert replies and replies[0].err is not None
    assert "ResetRequest: undecodable" in replies[0].err.payload.to_bytes().decode()
    assert a.bad_messages == {"reset": 1}


def test_a_query_is_given_up_at_once_when_cancelled(buses):
    """A stopping node does not wait out a slow reply (a reset while the arm homes took over 5 s, and the
    actor's thread outlived its stop); a reply that comes in time is returned as before."""
    a, b = buses
    release = threading.Event()

    def on_reset(req: m.ResetRequest) -> m.ResetReply:
        if req.seed == 1:
            release.wait(10.0)
        return m.ResetReply(ok=True, detail=f"seed {req.seed}")

    a.queryable(m.RESET, on_reset)
    time.sleep(0.3)
    assert b.query(m.RESET, m.ResetRequest(seed=2), timeout=5, cancel=threading.Event()).detail == "seed 2"
    cancel = threading.Event()
    threading.Timer(0.3, cancel.set).start()
    start = time.monotonic()
    with pytest.raises(QueryCancelled, match="reset: the query was cancelled"):
        b.query(m.RESET, m.ResetRequest(seed=1), timeout=10, cancel=cancel)
    assert time.monotonic() - start < 2.0
    release.set()
    with pytest.raises(TimeoutError, match="no reply on .*nothing"):
        b.query(m.Service("nothing", m.ResetRequest, m.ResetReply), m.ResetRequest(seed=3), timeout=1)


def test_a_stalled_peer_is_noticed_within_about_a_second(endpoint):
    """SIGSTOP keeps the peer's socket open, so only the lease tells: 1 s by default (Zenoh's own 10 s
    left an arm driven by a frozen learner's last plan that long)."""
    import os
    import signal
    import subprocess
    import sys

    name = unique_name("lease")
    child = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import time\nfrom bus.transport import Bus, ZenohConfig, open_session\n"
            f"b = Bus(open_session(ZenohConfig(connect=({endpoint!r},))), {name!r})\n"
            "b.declare_alive('learner'); print('up', flush=True); time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    bus = Bus(open_session(ZenohConfig(listen=(endpoint,))), name)
    seen: dict[str, tuple[bool, float]] = {}
    try:
        bus.watch_alive(lambda who, alive: seen.update({who: (alive, time.monotonic())}))
        assert child.stdout.readline().strip() == "up"
        wait_until(lambda: seen.get("learner", (False,))[0], 10, "the peer's token")
        t0 = time.monotonic()
        os.kill(child.pid, signal.SIGSTOP)
        wait_until(lambda: not seen["learner"][0], 5, "the stalled peer to be noticed")
        assert seen["learner"][1] - t0 < 2.5
    finally:
        child.kill()
        child.wait()
        bus.close()


def test_a_renewed_session_keeps_every_declaration(endpoint):
    """``renew`` (what a part does after a stall) remakes publishers, subscribers, queryables and tokens on
    a fresh session: the peers hear it again, it hears them once per message, its seq goes on."""
    name = unique_name("renew")
    hub = Bus(open_session(ZenohConfig(listen=(endpoint,))), name)
    part = Bus.open(ZenohConfig(hub=endpoint), name)  # the hub is taken: it joins, so it can renew
    try:
        heard, got, alive = [], [], []
        hub.subscribe(m.CHUNK_STATUS, heard.append)
        hub.watch_alive(lambda who, up: alive.append((who, up)))
        part.subscribe(m.CONTROL, got.append)
        part.queryable(m.RESET, lambda req: m.ResetReply(ok=True, detail=f"seed {req.seed}"))
        part.declare_alive("learner")
        pub, control = part.publisher(m.CHUNK_STATUS), hub.publisher(m.CONTROL)
        status = m.ChunkStatus(chunk_seq=1, preempted_by=-1, verdict=m.ChunkStatus.ACCEPTED, **LABELS)
        wait_until(lambda: ("learner", True) in alive, what="the part's token")
        time.sleep(0.3)
        pub.put(status)
        wait_until(lambda: len(heard) == 1, what="the first status")
        old = part.session

        assert part.renew() and part.session is not old and part.renewals == 1
        # The old session is closed, so the token the hub sees now is the fresh one's. Zenoh may or may
        # not report the old token's end first: the fresh token can reach the hub before it on the other
        # link, and a key with a token left is not reported gone.
        wait_until(
            lambda: alive[-1] == ("learner", True) and hub.alive_now("learner"),
            what=lambda: f"the fresh token (the hub saw {alive})",
        )
        time.sleep(0.3)  # the fresh session's declarations reach the hub
        assert pub.put(status) == 2
        control.put(m.Control(command=m.Control.PAUSE, jog=[0, 0, 0]))
        wait_until(
            lambda: len(heard) == 2 and len(got) == 1, what="a status and a control through the fresh session"
        )
        assert hub.query(m.RESET, m.ResetRequest(seed=7), timeout=5).detail == "seed 7"
        time.sleep(0.3)
        assert [s.seq for s in heard] == [1, 2] and len(got) == 1  # nothing twice
        part.close()
        wait_until(
            lambda: alive[-1] == ("learner", False),
            what=lambda: f"the fresh token to go (the hub saw {alive})",
        )
    finally:
        part.close()
        hub.close()


def test_a_bus_holding_the_hub_cannot_renew(endpoint):
    bus = Bus.open(ZenohConfig(hub=endpoint), unique_name("own"))
    try:
        with pytest.raises(ValueError, match="fixed listener"):
            bus.renew()
    finally:
        bus.close()


def test_a_part_stalled_for_about_a_lease_is_heard_again(endpoint):
    """A SIGSTOP near the 1 s lease expired the part's links on some peers only, and Zenoh remade none
    of them (the fault matrix lost robot-io's states for good once). The part renews its session when
    it was stopped (SIGCONT tells it; its own clocks too), so every peer hears it again within a few
    seconds. With a thread that holds the GIL for a C loop, the CPU it burned right after SIGCONT hid
    the stop from the clocks (vision in the fault matrix then never heard robot-io again)."""
    import os
    import signal
    import subprocess
    import sys

    name = unique_name("stall")
    hub = Bus(open_session(ZenohConfig(listen=(endpoint,))), name)
    child = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import logging, time\nfrom bus import messages as m\n"
            "from bus.transport import Bus, ZenohConfig\nlogging.basicConfig()\n"
            f"b = Bus.open(ZenohConfig(hub={endpoint!r}), {name!r}); p = b.publisher(m.CHUNK_STATUS)\n"
            "print('up', flush=True)\n"
            "s = m.ChunkStatus(chunk_seq=1, preempted_by=-1, verdict=m.ChunkStatus.ACCEPTED,"
            " opened_by=m.ActionChunk.FIRST, preempted_by_opening=m.ActionChunk.NONE)\n"
            "while True:\n    p.put(s); time.sleep(0.02)",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    probe = Bus.open(ZenohConfig(hub=endpoint), name)  # a third peer: its link to the part is gossiped
    last = [0.0]
    try:
        probe.subscribe(m.CHUNK_STATUS, lambda msg: last.__setitem__(0, time.monotonic()))
        assert child.stdout.readline().strip() == "up"
        wait_until(lambda: time.monotonic() - last[0] < 0.1, 10, "the part's statuses")
        for stall in (0.8, 1.0, 1.2):
            os.kill(child.pid, signal.SIGSTOP)
            time.sleep(stall)
            os.kill(child.pid, signal.SIGCONT)
            resumed = time.monotonic()
            wait_until(
                lambda t=resumed: last[0] > t + 0.5, 5, f"the part to be heard again after a {stall} s stop"
            )
    finally:
        child.kill()
        _, err = child.communicate()
        probe.close()
        hub.close()
    assert err.count("reopening its Zenoh session") == 3, err


def test_alive_now_asks_the_network_whether_a_token_exists(buses):
    """``alive_now`` does not rely on a subscriber having heard of the token: it queries the network."""
    a, b = buses
    a.declare_alive("learner/abc")
    wait_until(lambda: b.alive_now("learner/abc", timeout=1.0), what="the token on the network")
    assert not b.alive_now("learner/nobody", timeout=1.0)
    assert a.alive_now("learner/abc", timeout=1.0)  # its own token too


def test_alive_now_on_a_closed_session_says_so(endpoint):
    """robot-io logs this and refuses the reset as it would have without asking (deploy.robot_io_node)."""
    bus = Bus(open_session(ZenohConfig(listen=(endpoint,))), unique_name("cl"))
    bus.close()
    with pytest.raises(ConnectionError, match="liveliness query .*alive/learner/a"):
        bus.alive_now("learner/a", timeout=0.5)


def test_with_the_stacks_key_only_signed_new_events_arrive_and_floods_log_a_line_per_reason(endpoint, caplog):
    """Unsigned, foreign-signed and replayed retreat events are dropped and counted; a flood of them logs
    one line per kind, not one per message."""
    from bus.signing import mac_key, sign

    name, key = unique_name("sg"), mac_key("tok")
    part = Bus(open_session(ZenohConfig(listen=(endpoint,))), name, key)
    reader = Bus(open_session(ZenohConfig(connect=(endpoint,))), name, key)
    try:
        got = []
        reader.subscribe(m.EVENTS_RETREAT, got.append)
        pub = part.publisher(m.EVENTS_RETREAT)
        time.sleep(0.3)
        genuine = m.RetreatEvent(segment=1, H=4, reason=m.SegmentEnd.RETREAT)
        pub.put(genuine)
        wait_until(lambda: len(got) == 1, what="the genuine event")
        wire = reader.key(m.EVENTS_RETREAT)
        with caplog.at_level("WARNING", logger="bus.transport"):
            for i in range(300):
                forged = m.RetreatEvent(segment=i, H=85, reason=m.SegmentEnd.RETREAT, stamp=time.time())
                part.session.put(wire, forged.SerializeToString())  # unsigned
                sign(forged, mac_key("another stack"))
                part.session.put(wire, forged.SerializeToString())  # foreign
                part.session.put(wire, genuine.SerializeToString())  # an exact copy of a genuine one
            wait_until(lambda: reader.bad_messages.get("events/retreat", 0) == 900, what="900 refusals")
        assert [e.segment for e in got] == [1]
        lines = [r for r in caplog.records if "events/retreat" in r.getMessage()]
        assert 2 <= len(lines) <= 3, [r.getMessage() for r in lines]  # forged, replayed: first in full
    finally:
        reader.close()
        part.close()


@pytest.mark.parametrize("sigcont", ["before the look", "after the look", "never"])
def test_sigcont_says_a_busy_looking_gap_was_a_stop(endpoint, monkeypatch, sigcont):
    """A thread that burned CPU holding the GIL right after SIGCONT (vision's renderer) made a stop look
    like a busy process to the CPU test, and vision never heard robot-io again (fault matrix). SIGCONT
    says it was a stop, whether its handler runs before the look that sees the gap or after it."""
    hub = Bus(open_session(ZenohConfig(listen=(endpoint,))), unique_name("sc"))
    bus = Bus.open(ZenohConfig(hub=endpoint), hub.robot)  # joins through the hub: it can renew
    renewals = []
    monkeypatch.setattr(bus, "renew", lambda: renewals.append(1) or True)
    try:
        with bus._stall_lock:  # the guard thread looks too: one gap, staged, under its lock
            busy_gap = (time.monotonic() - 1.5, time.process_time() - 1.0)  # 1.0 s of CPU in 1.5 s
            bus._looked = busy_gap
            bus.continued = sigcont == "before the look"
        bus.check_stall()
        if sigcont == "after the look":
            bus.continued = True
            time.sleep(0.15)
            bus.check_stall()
        assert len(renewals) == (0 if sigcont == "never" else 1)
    finally:
        bus.close()
        hub.close()
