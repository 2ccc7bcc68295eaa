"""The monitor on a fleet (configs/fleet.yaml's two arms) over real Zenoh on loopback, in the browser the
other monitor tests use: every arm is listed with what it publishes and the panels show the arm picked; an
arm's own stop goes on that arm's control key alone (a real robot-io obeys it) and the E-STOP on the
fleet's, which every arm obeys; other requests need the token and an arm the fleet has."""

from __future__ import annotations

import json
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from bus_probe import BusProbe
from loopback import unique_name
from polling import wait_until
from stack_helpers import running_part
from test_monitor_browser import ARGS, CHROMIUM

from bus import messages as m
from bus.signing import mac_key
from bus.transport import Bus, ZenohConfig, open_session
from deploy.config import StackConfig, compose_stack_yaml
from monitor.server import MonitorConfig, MonitorServer

TOKEN = "operator-token"
SESSION = "0a1b2c3d4e5f6071"  # the learner session the test's arms say they obey
ZERO3 = [0.0, 0.0, 0.0]


def _fleet_config(endpoint: str) -> dict[str, Any]:
    """configs/fleet.yaml with a name of its own, joining the monitor's listener on ``endpoint``."""
    cfg = compose_stack_yaml("configs/fleet.yaml")
    cfg.update(name=unique_name("mf"), zenoh={"connect": [endpoint]}, monitor=None)
    return cfg


class Fleet(BusProbe):
    """The test's peer on the fleet's keys, signing as the arms do: puts what an arm or the learner says,
    collects the controls on each arm's key and on the fleet's ("")."""

    def __init__(self, cfg: dict[str, Any], endpoint: str, server: MonitorServer) -> None:
        super().__init__(Bus(open_session(ZenohConfig(connect=(endpoint,))), cfg["name"], mac_key(TOKEN)))
        self.cfg = cfg
        self.controls: dict[str, list[str]] = {"": []}
        self.bus.subscribe(m.CONTROL, lambda c: self._control("", c))
        for arm in ("arm0", "arm1"):
            self.controls[arm] = []
            self.bus.subscribe(m.CONTROL, lambda c, a=arm: self._control(a, c), arm=arm)
            _heard(server.bus, server.bus.key(m.CONTROL, arm=arm))  # the monitor sees the test's keys,
            _heard(self.bus, self.bus.key(m.STATE, arm=arm))  # the test the monitor's
        _heard(server.bus, server.bus.key(m.CONTROL))
        _heard(self.bus, self.bus.key(m.TRANSITIONS))

    def _control(self, key: str, c: m.Control) -> None:
        with self.lock:
            self.controls[key].append(m.label(c, "command"))

    def got(self) -> dict[str, list[str]]:
        with self.lock:
            return {k: list(v) for k, v in self.controls.items()}

    def state(self, arm: str, mode: str, tick: int = 1) -> None:
        self.bus.publisher(m.STATE, arm=arm)(
            m.RobotState(
                ee_pos=[0.5, 0.0, 0.3], ee_vel=ZERO3, ee_cmd=[0.5, 0.0, 0.3], dq=[0.0] * 7, tick=tick,
                mode=m.enum(m.RobotState, "mode", mode), played_chunk=-1, chunk_seq=0, session=SESSION,
            )
        )  # fmt: skip


def _heard(bus: Bus, key: str) -> None:
    """Wait until a put on ``key`` from ``bus`` reaches a subscriber (Zenoh declares a subscription to a
    peer a moment after it connects; a put before that is lost)."""
    publisher = bus.session.declare_publisher(key)
    try:
        wait_until(lambda: publisher.matching_status.matching, 10, f"{key} to match a subscriber")
    finally:
        publisher.undeclare()


@pytest.fixture
def fleet(endpoint: str) -> Iterator[tuple[MonitorServer, Fleet]]:
    """A monitor on a two-arm fleet config (its arms: ``StackConfig.arm_names``), and the test's peer on
    the fleet's keys."""
    cfg = _fleet_config(endpoint)
    stack = StackConfig.model_validate(cfg)
    bus = Bus(open_session(ZenohConfig(listen=(endpoint,))), stack.name, mac_key(TOKEN))
    config = MonitorConfig(port=0, foxglove_port=None)
    server = MonitorServer(bus, config, TOKEN, stack.view_limits(), arms=stack.arm_names).start()
    peer = Fleet(cfg, endpoint, server)
    yield server, peer
    peer.bus.close()
    server.stop()


@pytest.fixture
def page() -> Iterator[Any]:
    """A page of the real browser (Debian's headless Chromium through Playwright)."""
    if not Path(CHROMIUM).exists():
        pytest.skip("needs Debian's chromium at /usr/bin/chromium (apt-get install chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield browser.new_page(viewport={"width": 1400, "height": 900})
        browser.close()


def _shows(page: Any, selector: str, text: str, what: str, alive: Callable[[], None] | None = None) -> None:
    """``selector`` reads ``text`` within 10 s; ``alive`` (the test's arm publishing a state) is called at
    each look, as a live arm publishes: a state older than 2 s reads "(silent N s)" after its mode."""

    def shown() -> bool:
        if alive is not None:
            alive()
        return page.inner_text(selector) == text

    wait_until(shown, 10, what, every=0.1)


def _episodes(peer: Fleet, arm: str, successes: list[bool]) -> list[m.Transition]:
    """``arm``'s ticks of one actor stream: two per episode, the second its end with its success."""
    put, sent, step = peer.bus.publisher(m.TRANSITIONS), [], 0
    for episode, success in enumerate(successes):
        for last in (False, True):
            t = m.Transition(
                stream=f"stream-{arm}", step=step, episode=episode, reward=-1.0, terminated=last and success,
                truncated=last and not success, success=last and success, arm=arm,
                end=m.SegmentEnd.EPISODE_END if last else m.SegmentEnd.OPEN,
            )  # fmt: skip
            put(t)
            sent.append(t)
            step += 1
    return sent


def test_the_page_lists_each_arm_with_what_it_publishes_and_shows_the_arm_picked(fleet, page):
    server, peer = fleet
    peer.state("arm0", "running")
    peer.state("arm1", "paused")
    peer.bus.publisher(m.CMD_CHUNK, arm="arm1")(
        m.ActionChunk(actions=[0.0, 0.01, 0.0] * 4, segment=2, session=SESSION, opened_by=m.ActionChunk.FIRST)
    )
    retreat = peer.bus.publisher(m.EVENTS_RETREAT)  # the learner's, one key for the fleet: its arm named
    for arm, reason in (("arm1", "retreat"), ("arm1", "retreat"), ("arm0", "h_max")):
        retreat(m.RetreatEvent(segment=1, H=3, reason=m.enum(m.RetreatEvent, "reason", reason), arm=arm))
    sent = _episodes(peer, "arm0", [True, True, False])
    _episodes(peer, "arm1", [False])
    peer.bus.publisher(m.TRANSITIONS)(sent[-1])  # sent again (the learner lacked it): one episode still

    page.goto(server.url)
    _shows(page, "#arm-arm0 .amode", "RUNNING", "arm0's state in its row")
    _shows(page, "#arm-arm1 .amode", "PAUSED", "arm1's state in its row")
    _shows(page, "#arm-arm0 .asuccess", "67 % of 3 (3 episodes)", "arm0's success")
    _shows(page, "#arm-arm1 .asuccess", "0 % of 1 (1 episodes)", "arm1's success")
    assert [page.inner_text(f"#arm-{a} .aretreats") for a in ("arm0", "arm1")] == ["0", "2"]
    assert page.inner_text("#arm-arm1 .aplan") == "chunk 1 (segment 2): 0 executed, 0 dropped of 4"
    assert page.inner_text("#arm-arm0 .aplan") == "none yet"
    # The panels show the first arm until the operator picks another.
    assert page.inner_text("#robot-name").endswith("/arm0") and page.inner_text("#mode") == "RUNNING"
    assert page.inner_text("#estop") == "E-STOP all arms" and page.inner_text("#release") == "release arm0"
    page.click("#arm-arm1 .view")
    _shows(page, "#mode", "PAUSED", "arm1's panels")
    assert page.inner_text("#robot-name").endswith("/arm1") and page.inner_text("#retreats") == "2"
    assert page.inner_text("#success") == "0 % of 1 (1 episodes)" and "chunk 1" in page.inner_text("#chunk")
    assert page.inner_text("#release") == "release arm1"
    assert page.get_attribute("#arm-arm1", "class") == "chosen"
    with pytest.raises(urllib.error.HTTPError, match="404"):
        urllib.request.urlopen(server.url + "api/state?arm=arm9", timeout=5)


def test_an_arms_stop_goes_to_that_arm_alone_and_the_estop_to_every_arm(fleet, page, endpoint, tmp_path):
    server, peer = fleet
    peer.state("arm1", "running")  # arm1: the test's; arm0: a real robot-io
    ready = lambda: wait_until(lambda: server.fleet.arms["arm0"].robot, 30, "arm0's robot-io")  # noqa: E731
    with running_part("robot-io", peer.cfg, tmp_path, ready, TOKEN, ("--arm", "arm0", "--watch", "")):
        page.goto(server.url)
        _shows(page, "#arm-arm0 .amode", "RUNNING", "arm0's robot-io in its row")
        _shows(page, "#arm-arm1 .amode", "RUNNING", "arm1 in its row", lambda: peer.state("arm1", "running"))
        page.click("#stop-arm0")  # no token typed: a stop needs none
        _shows(page, "#arm-arm0 .amode", "ESTOP", "arm0's robot-io e-stopped")
        assert page.inner_text("#reply") == "sent estop to arm0"
        time.sleep(0.5)  # anything sent elsewhere would have come by now
        assert peer.got() == {"": [], "arm0": ["estop"], "arm1": []}
        page.click("#release")  # the arm shown, arm0, alone; signed with the token
        wait_until(lambda: "refused" in page.inner_text("#reply"), 5, "a release without the token refused")
        page.fill("#token", TOKEN)
        page.click("#release")
        _shows(page, "#arm-arm0 .amode", "RUNNING", "arm0 released")
        page.click("#estop")
        _shows(page, "#arm-arm0 .amode", "ESTOP", "arm0's robot-io e-stopped by the fleet's E-STOP")
        assert page.inner_text("#reply") == "sent estop to all arms"
        time.sleep(0.5)
        assert peer.got() == {"": ["estop"], "arm0": ["estop", "release"], "arm1": []}


def _post(server: MonitorServer, body: dict[str, Any], token: str | None = None) -> tuple[int, dict]:
    headers = {"Content-Type": "application/json", **({"X-Token": token} if token else {})}
    data = json.dumps(body).encode()
    request = urllib.request.Request(server.url + "api/control", data=data, headers=headers, method="POST")
    try:
        with urllib.request.urlopen(request, timeout=5) as reply:
            return reply.status, json.loads(reply.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def test_a_request_for_an_arm_the_fleet_lacks_is_refused_but_its_stop_stops_every_arm(fleet):
    server, peer = fleet
    code, reply = _post(server, {"command": "estop", "arm": "arm9"})  # a stop by mistake is safe
    assert code == 200 and reply["to"] == "all arms", reply
    assert _post(server, {"command": "release", "arm": "arm9"}, TOKEN)[0] == 400
    assert _post(server, {"command": "release", "arm": ["arm1"]}, TOKEN)[0] == 400
    assert _post(server, {"command": "release", "arm": "arm1"})[0] == 403  # an arm's release: the token
    assert _post(server, {"command": "release", "arm": "arm1"}, TOKEN)[1]["to"] == "arm1"
    assert _post(server, {"command": "pause"}, TOKEN)[1]["to"] == "all arms"  # the learner and every arm
    peer.wait(lambda: len(peer.controls[""]) == 2 and peer.controls["arm1"], 5, "the requests on the bus")
    time.sleep(0.3)
    assert peer.got() == {"": ["estop", "pause"], "arm0": [], "arm1": ["release"]}
