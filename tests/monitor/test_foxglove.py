"""Foxglove's view: a plan's predicted path and the rest a newer plan cut off reach the recorded 3D scene
(read back with mcap and protobuf alone), and ``adaptiveh monitor`` serves the robot's state over
Foxglove's WebSocket protocol to a plain client that decodes it with the advertised schema; with the stack's
key, the live view shows none of a stranger's messages."""

from __future__ import annotations

import asyncio
import base64
import json
import queue
import re
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import websockets
from loopback import unique_name
from mcap.reader import make_reader
from polling import wait_until
from stack_helpers import write_stack_config
from test_recording import KEY, STRANGER, schema_decoder

from bus import messages as m
from bus.signing import sign
from bus.transport import ZenohConfig, open_session
from monitor.foxglove.derive import Deriver, SceneSetup
from monitor.foxglove.live import FoxgloveLive
from monitor.foxglove.robot_model import obj_to_stl
from monitor.recording import Recorder

Q = [0.0, -0.78, 0.0, -2.36, 0.0, 1.57, 0.78]


ME = "0a1b2c3d4e5f6071"  # the learner session the arm obeys


def state(seq: int, ee: list[float]) -> m.RobotState:
    return m.RobotState(
        seq=seq,
        stamp=time.time(),
        q=Q,
        dq=[0.0] * 7,
        ee_pos=ee,
        ee_vel=[0.0] * 3,
        ee_cmd=ee,
        mode=1,
        session=ME,
    )


def test_obj_polygons_become_stl_triangles() -> None:
    stl = obj_to_stl("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\nf -4/1 -2/2 -1/3\n")
    assert int.from_bytes(stl[80:84], "little") == 3 and len(stl) == 84 + 3 * 50  # a quad fans into two
    first = struct.unpack("<12f", stl[84 : 84 + 48])
    assert first[3:] == (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0)  # vertices 1, 2, 3 (normal zeros)


def test_recorded_scene_shows_the_plan_and_the_cut_rest(tmp_path: Path, endpoint: str) -> None:
    session = open_session(ZenohConfig(listen=(endpoint,)))
    path = tmp_path / "plan.mcap"
    deriver = Deriver("fx", SceneSetup(camera=((1.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0))), scene_every=2)
    recorder = Recorder(session, "fx", path, deriver=deriver)
    predicted = [0.41, 0.0, 0.3, 0.42, 0.0, 0.3, 0.43, 0.0, 0.3, 0.44, 0.0, 0.3]
    sent = [
        (
            m.TARGET,
            m.Target(position=[0.5, 0.1, 0.3], velocity=[0] * 3, covariance=[0] * 9, valid=True, status=1),
        ),
        (m.STATE, state(1, [0.4, 0.0, 0.3])),
        (
            m.CMD_CHUNK,
            m.ActionChunk(
                seq=7,
                actions=[0.01, 0, 0] * 4,
                predicted_ee=predicted,
                session=ME,
                opened_by=m.ActionChunk.FIRST,
            ),
        ),
        # A stranger's plan: robot-io refuses it, so it is not drawn.
        (
            m.CMD_CHUNK,
            m.ActionChunk(
                seq=9,
                actions=[0.01, 0, 0],
                predicted_ee=[1, 1, 1],
                session="f" * 16,
                opened_by=m.ActionChunk.FIRST,
            ),
        ),
        (m.STATE, state(2, [0.41, 0.0, 0.3])),
        (
            m.CHUNK_STATUS,
            m.ChunkStatus(
                chunk_seq=7,
                executed=1,
                dropped=3,
                preempted_by=8,
                done=True,
                session=ME,
                verdict=1,
                opened_by=m.ActionChunk.FIRST,
                preempted_by_opening=m.ActionChunk.RETREAT,
            ),
        ),
        (
            m.CMD_CHUNK,
            m.ActionChunk(seq=8, actions=[0.0, 0, 0] * 2, session=ME, opened_by=m.ActionChunk.RETREAT),
        ),  # no prediction: no plan path
        (m.STATE, state(3, [0.41, 0.0, 0.3])),
        (m.STATE, state(4, [0.41, 0.0, 0.3])),
    ]
    try:
        for topic, msg in sent:  # paced as the parts send them: the recorder's subscribers are per key
            session.put(topic.key("fx"), msg.SerializeToString())
            time.sleep(0.02)
        wait_until(lambda: recorder.count == len(sent), 5, "the recorder to take every message")
    finally:
        recorder.close()
        session.close()
    scenes, decoders = [], {}
    with open(path, "rb") as fh:  # mcap and protobuf alone
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            if channel.topic == "adaptiveh/fx/foxglove/scene":
                assert schema.name == "foxglove.SceneUpdate"
                cls = decoders.setdefault(schema.name, schema_decoder(schema.name, schema.data))
                scenes.append({e.id: e for e in cls.FromString(message.data).entities})

    def line(scene: dict, name: str) -> list[list[float]]:
        return [[p.x, p.y, p.z] for p in scene[name].lines[0].points]

    triples = [predicted[i : i + 3] for i in range(0, len(predicted), 3)]
    first_plan = next(s for s in scenes if "plan" in s)  # drawn as soon as the plan arrives
    assert line(first_plan, "plan") == [[0.4, 0.0, 0.3], *triples]  # the arm at arrival, then the prediction
    assert all([1.0, 1.0, 1.0] not in line(s, "plan") for s in scenes if "plan" in s)  # not the stranger's
    cut = next(s for s in scenes if "abandoned" in s)
    assert line(cut, "abandoned") == triples  # one action played (the arm at triples[0]), three dropped
    assert "plan" not in scenes[-1] and "abandoned" in scenes[-1] and "executed" in scenes[-1]
    assert scenes[-1]["target"].cubes[0].pose.position.y == 0.1


async def _watch_state(url: str, robot: str, want: int) -> tuple[list, set[str]]:
    """Connect as a Foxglove client, subscribe to the state channel, decode ``want`` messages."""
    topic = f"adaptiveh/{robot}/state"
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
        assert ws.subprotocol == "foxglove.sdk.v1"
        advertised: dict[str, dict] = {}
        while topic not in advertised:
            frame = await asyncio.wait_for(ws.recv(), 10)
            if isinstance(frame, str) and json.loads(frame)["op"] == "advertise":
                advertised |= {c["topic"]: c for c in json.loads(frame)["channels"]}
        channel = advertised[topic]
        assert channel["encoding"] == "protobuf" and channel["schemaName"] == "adaptiveh.RobotState"
        cls = schema_decoder(channel["schemaName"], base64.b64decode(channel["schema"]))
        await ws.send(
            json.dumps({"op": "subscribe", "subscriptions": [{"id": 5, "channelId": channel["id"]}]})
        )
        got = []
        while len(got) < want:
            frame = await asyncio.wait_for(ws.recv(), 10)
            if isinstance(frame, bytes) and frame[0] == 1:  # message data: op, subscription, log time
                sub_id, _log_time = struct.unpack_from("<IQ", frame, 1)
                assert sub_id == 5
                got.append(cls.FromString(frame[13:]))
            elif isinstance(frame, str) and json.loads(frame)["op"] == "advertise":
                advertised |= {c["topic"]: c for c in json.loads(frame)["channels"]}
        return got, {c["schemaName"] for c in advertised.values()}


def test_live_view_serves_state_over_foxglove_websocket(tmp_path: Path) -> None:
    path, cfg = write_stack_config(tmp_path, "fxl")
    session = open_session(ZenohConfig(listen=(cfg["zenoh"]["hub"],)))  # the test owns the hub
    proc = subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "monitor", "--config", str(path), "--log-level", "WARNING"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    stop = threading.Event()

    def publish() -> None:  # robot-io's part: state at 20 Hz
        seq = 0
        while not stop.wait(0.05):
            seq += 1
            session.put(
                m.STATE.key(cfg["name"]), state(seq, [0.4, 0.0, 0.3 + 0.001 * seq]).SerializeToString()
            )

    publisher = threading.Thread(target=publish, daemon=True)
    try:
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()
        url, deadline = "", time.monotonic() + 60
        while not url:  # the monitor prints its page's URL, its token, then the Foxglove URL
            line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
            url = line.split(" ", 1)[1].strip() if line.startswith("foxglove: ") else ""
        assert url.startswith("ws://127.0.0.1:")
        publisher.start()
        got, schemas = asyncio.run(_watch_state(url, cfg["name"], want=10))
    finally:
        stop.set()
        proc.terminate()
        proc.wait(timeout=20)
        session.close()
    assert all(len(s.q) == 7 and all(isinstance(x, float) for x in s.q) for s in got)
    assert [s.seq for s in got] == sorted(s.seq for s in got) and len({s.seq for s in got}) == 10
    assert {"foxglove.FrameTransforms", "foxglove.SceneUpdate"} <= schemas  # derived, live, same as recorded


def test_layout_file_is_current_and_names_our_channels() -> None:
    """configs/foxglove_layout.json is what scripts/foxglove_layout.py writes, and every topic in it is one
    a recording of ``panda`` has (raw or derived), so no panel is left empty by a renamed channel."""
    sys.path.insert(0, "scripts")
    from foxglove_layout import layout

    committed = json.loads(Path("configs/foxglove_layout.json").read_text())
    assert committed == json.loads(layout("panda").to_json())
    text = json.dumps(committed)
    named = set(re.findall(r"adaptiveh/panda/[a-z_/]+", text))
    derived = {
        f"adaptiveh/panda/foxglove/{c}"
        for c in ("camera", "tf", "scene", "robot", "log", "distance", "retreat")
    }
    assert named and named <= derived | {t.key("panda") for t in m.TOPICS.values()}, named


def _target(seq: int, key: bytes | None) -> m.Target:
    """A tracked target, signed with ``key`` (None: unsigned)."""
    t = m.Target(
        seq=seq,
        stamp=time.time(),
        position=[0.5, 0.01 * seq, 0.3],
        velocity=[0.0] * 3,
        covariance=[0.0] * 9,
        valid=True,
        status=m.Target.TRACKING,
    )
    if key is not None:
        sign(t, key)
    return t


def test_live_view_with_the_key_shows_only_the_stack_s_messages(endpoint: str) -> None:
    """With the stack's key, an unsigned, a stranger-signed, an altered and a replayed Target are neither
    forwarded to a viewer nor fed to the deriver (the scene's target); the stack's own ones are. Without a
    key (the default), everything that decodes is shown, as before."""
    session = open_session(ZenohConfig(listen=(endpoint,)))
    robot = unique_name("fk")
    strict, lenient = (FoxgloveLive(session, robot, port=0, key=k) for k in (KEY, None))
    first, last = _target(1, KEY), _target(6, KEY)
    altered = m.Target.FromString(first.SerializeToString())
    altered.position[1] = 9.0
    sent = [_target(2, None), _target(3, STRANGER), first, altered, first, last]
    try:
        for msg in sent:  # one key, one session: they arrive in this order
            session.put(m.TARGET.key(robot), msg.SerializeToString())
        wait_until(
            lambda: (strict.deriver.target, lenient.deriver.target) == (last, last), 5, "the last target"
        )
    finally:
        strict.close()
        lenient.close()
        session.close()
    assert strict.deriver.target == last and lenient.deriver.target == last
    assert (strict.count, lenient.count) == (2, len(sent))  # first and last; everything
