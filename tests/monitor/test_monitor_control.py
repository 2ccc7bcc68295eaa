"""The monitor's control endpoint: an e-stop is published whatever else is wrong with the request (no or a
wrong token, garbage jog values, a body that is not JSON), every other command needs the token and a
valid body; and the page's numbers keep out what the stack did not sign or a plot cannot hold."""

from __future__ import annotations

import json
import urllib.error
import urllib.request

import pytest
from bus_probe import BusProbe
from loopback import unique_name

from bus import messages as m
from bus.signing import mac_key, sign
from bus.transport import Bus, ZenohConfig, open_session
from monitor.server import MonitorConfig, MonitorServer
from monitor.view_limits import ViewLimits

TOKEN = "operator-token"


@pytest.fixture
def monitor(endpoint):
    name = unique_name("mc")
    server = MonitorServer(
        Bus(open_session(ZenohConfig(listen=(endpoint,))), name, mac_key(TOKEN)),
        MonitorConfig(port=0, foxglove_port=None),
        TOKEN,
        ViewLimits(longest_segment=50),
    ).start()
    peer = Bus(open_session(ZenohConfig(connect=(endpoint,))), name)
    probe = BusProbe(peer)
    controls = probe.collect(m.CONTROL, arrival=False)
    probe.wait_heard_by(server.bus, m.CONTROL)
    yield server, probe, controls
    peer.close()
    server.stop()


def _post(url: str, body: bytes, token: str | None = None) -> tuple[int, dict]:
    headers = {"Content-Type": "application/json", **({"X-Token": token} if token is not None else {})}
    request = urllib.request.Request(url + "api/control", data=body, headers=headers, method="POST")
    try:
        with urllib.request.urlopen(request, timeout=5) as reply:
            return reply.status, json.loads(reply.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


ESTOPS = {
    "no token": (b'{"command": "estop"}', None),
    "a wrong token": (b'{"command": "estop"}', "wrong"),
    "garbage jog values": (b'{"command": "ESTOP", "jog": ["x", null]}', None),
    "a body that is not JSON": (b'{"command": "estop", jog: [1,', None),
}


@pytest.mark.parametrize("case", list(ESTOPS))
def test_an_estop_request_is_published_whatever_else_is_wrong(monitor, case):
    server, probe, controls = monitor
    body, token = ESTOPS[case]
    code, reply = _post(server.url, body, token)
    assert code == 200 and reply["command"] == "estop", reply
    probe.wait(lambda: [c for c in controls if c.command == m.Control.ESTOP], 5, "the e-stop on the bus")


@pytest.mark.parametrize(
    "body, token, code",
    [
        (b'{"command": "release"}', None, 403),
        (b'{"command": "release"}', "wrong", 403),
        (b'{"command": "jog", "jog": [1, 2]}', TOKEN, 400),
        (b'{"command": "pause", jog: ', TOKEN, 400),
        (b"[1, 2]", TOKEN, 400),
    ],
)
def test_every_other_command_needs_the_token_and_a_valid_body(monitor, body, token, code):
    server, probe, controls = monitor
    assert _post(server.url, body, token)[0] == code
    assert _post(server.url, b'{"command": "pause"}', TOKEN)[0] == 200  # the channel works
    probe.wait(lambda: controls, 5, "the pause on the bus")
    assert [c.command for c in controls] == [m.Control.PAUSE]


def test_the_page_counts_only_signed_events_within_range(monitor):
    server, probe, _ = monitor
    stranger, stack = probe.bus, mac_key(TOKEN)
    key = stranger.key(m.EVENTS_RETREAT)
    unsigned = m.RetreatEvent(segment=1, H=3, reason=m.SegmentEnd.RETREAT, stamp=1.0, statistic=[1e76])
    too_long = m.RetreatEvent(segment=2, H=85, reason=m.SegmentEnd.RETREAT, stamp=2.0)
    genuine = m.RetreatEvent(segment=3, H=4, reason=m.SegmentEnd.H_MAX, stamp=3.0, statistic=[0.5])
    sign(too_long, stack)
    sign(genuine, stack)
    for msg in (unsigned, too_long, genuine, genuine):  # the last an exact replay
        stranger.session.put(key, msg.SerializeToString())
    probe.wait(lambda: server.state.snapshot()["counts"]["rejected"] == 3, 5, "three refusals")
    snap = server.state.snapshot()
    assert [s["segment"] for s in snap["segments"]] == [3]
    assert [x for _, x, _ in snap["statistic"]] == [0.5]
