"""A short ``adaptiveh up`` run records every part's traffic to MCAP; the file decodes with the mcap
reader and the protobuf schema stored in it alone (no project code), Foxglove's well-known channels
included; ``adaptiveh replay`` puts the robot's own channels back on Zenoh, where a subscriber and the
monitor's JSON endpoint receive them. A recorder fed a stranger's fuzz writes only records a reader
decodes with their channel's schema, and, given the stack's key, typed channels of the stack's own signed
messages alone (issue #31)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import threading
import time
import urllib.request
from collections import Counter, defaultdict, deque
from collections.abc import Callable, Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import zenoh
from bus_probe import LABELS
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.descriptor import FieldDescriptor
from loopback import unique_name
from mcap.reader import make_reader
from polling import wait_until
from stack_helpers import write_stack_config

from bus import messages as m
from bus.signing import authentic, mac_key, sign, signed
from bus.transport import ZenohConfig, open_session
from monitor.foxglove.derive import Deriver, is_derived

TYPES = {
    "adaptiveh.RobotState",
    "adaptiveh.Target",
    "adaptiveh.ActionChunk",
    "adaptiveh.ChunkStatus",
    "adaptiveh.RetreatEvent",
    "adaptiveh.LearnerTelemetry",
    "adaptiveh.AnnotatedImage",
}


def schema_decoder(schema_name: str, schema_data: bytes):
    """A message class built from an MCAP schema (a FileDescriptorSet) with protobuf alone."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema_data)
    pool = descriptor_pool.DescriptorPool()
    for file in fds.file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path, list]:
    """One 60-step stack run (robot-io, vision, monitor, learner); returns (config, MCAP path, records)."""
    tmp = tmp_path_factory.mktemp("rec")
    path, cfg = write_stack_config(tmp, "rec", vision_rate_hz=5.0, steps=60)
    out = tmp / "summary.json"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "deploy.cli",
            "up",
            str(path),
            "--summary",
            str(out),
            "--log-level",
            "WARNING",
        ],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    mcap = Path(json.loads(out.read_text())["recording"])
    records, decoders, json_schemas = [], {}, {}
    with open(mcap, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            assert schema.encoding in ("protobuf", "jsonschema")  # JSON: derived plot values only
            records.append(
                (channel.topic, schema.name, channel.message_encoding, message.sequence, message.data)
            )
            if schema.encoding == "jsonschema":
                json_schemas[schema.name] = json.loads(schema.data)
            elif schema.name not in decoders:
                decoders[schema.name] = schema_decoder(schema.name, schema.data)
    cfg["_path"] = str(path)
    cfg["_decoders"] = decoders
    cfg["_json_schemas"] = json_schemas
    return cfg, mcap, records


def test_recording_has_every_type_decodable(run: tuple[dict, Path, list]) -> None:
    cfg, _, records = run
    assert TYPES <= {r[1] for r in records}, Counter(r[1] for r in records)
    assert not any(r[1] == "adaptiveh.CameraFrame" for r in records)  # excluded in sim.yaml: huge
    decoders, json_schemas, last_seq = cfg["_decoders"], cfg["_json_schemas"], {}
    for topic, schema, encoding, seq, data in records:
        assert topic.startswith(f"adaptiveh/{cfg['name']}/")
        assert seq > last_seq.get(topic, 0)  # per-channel sequence, in time order
        last_seq[topic] = seq
        if encoding == "json":
            value = json.loads(data)
            assert set(value) == set(json_schemas[schema]["properties"]), (schema, value)
            continue
        assert encoding == "protobuf"
        msg = decoders[schema].FromString(data)  # the schema in the file alone, no project code
        assert msg.DESCRIPTOR.full_name == schema and msg.SerializeToString() == data
        if schema == "adaptiveh.RobotState":  # joint positions are numbers in every state message
            assert len(msg.q) == 7 and all(isinstance(x, float) for x in msg.q), msg
    telemetry = decoders["adaptiveh.LearnerTelemetry"]
    steps = [telemetry.FromString(d).global_step for _, s, _, _, d in records if s.endswith("Telemetry")]
    assert max(steps) == cfg["learner"]["steps"]  # the learner's last telemetry made it into the file


def _derived(cfg: dict, records: list, channel: str) -> list:
    """The messages of ``adaptiveh/<name>/foxglove/<channel>``, decoded with the file's schema alone."""
    topic = f"adaptiveh/{cfg['name']}/foxglove/{channel}"
    return [cfg["_decoders"][s].FromString(d) for t, s, _, _, d in records if t == topic]


def test_recording_has_foxglove_well_known_channels(run: tuple[dict, Path, list]) -> None:
    """Image, transforms, scene and robot channels carry Foxglove's schema names and decode with them."""
    cfg, _, records = run
    schemas = {t.rsplit("/", 1)[1]: s for t, s, *_ in records if "/foxglove/" in t}
    assert schemas == {
        "camera": "foxglove.CompressedImage",
        "tf": "foxglove.FrameTransforms",
        "scene": "foxglove.SceneUpdate",
        "robot": "foxglove.SceneUpdate",
        "distance": "adaptiveh.foxglove.Distance",
        "retreat": "adaptiveh.foxglove.RetreatPoint",
    } | ({"log": "foxglove.Log"} if "log" in schemas else {})
    images = _derived(cfg, records, "camera")
    assert images and all(i.format == "jpeg" and i.data[:2] == b"\xff\xd8" for i in images)
    n_states = sum(s == "adaptiveh.RobotState" for _, s, *_ in records)
    frames = Counter(tf.child_frame_id for msg in _derived(cfg, records, "tf") for tf in msg.transforms)
    assert frames["ee"] == n_states  # the ee at every state, the links and camera every other state
    assert frames["camera"] == frames["panda_hand"] == (n_states + 1) // 2
    parents = {tf.parent_frame_id for msg in _derived(cfg, records, "tf") for tf in msg.transforms}
    assert frames["target"] > 0 and parents == {"base"}
    scenes = _derived(cfg, records, "scene")
    ids = Counter(e.id for u in scenes for e in u.entities)
    assert ids["executed"] > 0 and ids["target"] > 0, ids
    assert all(u.deletions[0].type == 1 for u in scenes)  # each update replaces the last (ALL)
    (robot,) = _derived(cfg, records, "robot")  # the meshes, once
    models = {e.frame_id: e.models[0] for e in robot.entities if e.frame_locked}
    assert {"panda_link0", "panda_link7", "panda_hand"} <= set(models) <= set(frames)
    for model in models.values():  # binary STL: 80-byte header, count, 50 bytes per triangle
        n = int.from_bytes(model.data[80:84], "little")
        assert model.media_type == "model/stl" and len(model.data) == 84 + 50 * n and n > 10


def _replay(cfg: dict, mcap: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "replay", str(mcap), "--config", cfg["_path"], *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_replay_reaches_a_subscriber(run: tuple[dict, Path, list]) -> None:
    cfg, mcap, records = run
    records = [r for r in records if m.topic_of_key(r[0]) is not None]  # derived channels stay in the file
    assert len(records) < len(run[2])
    session = open_session(ZenohConfig(hub=cfg["zenoh"]["hub"]))  # the test owns the hub; replay joins
    got: Counter[str] = Counter()
    lock = threading.Lock()

    def on(sample) -> None:
        topic = m.topic_of_key(str(sample.key_expr))
        msg = topic.decode(sample.payload.to_bytes())
        with lock:
            got[msg.DESCRIPTOR.full_name] += 1

    sub = session.declare_subscriber(f"adaptiveh/{cfg['name']}-replay/**", on)
    try:
        proc = _replay(cfg, mcap, "--no-monitor", "--speed", "10")
        out, err = proc.communicate(timeout=90)
        assert proc.returncode == 0, err[-2000:]
        assert f"replayed {len(records)} messages" in out
        time.sleep(0.5)
        with lock:
            assert got == Counter(r[1] for r in records)  # every message, decodable, under the new name
    finally:
        sub.undeclare()
        session.close()


def test_replay_into_the_monitor(run: tuple[dict, Path, list]) -> None:
    cfg, mcap, records = run
    proc = _replay(cfg, mcap, "--speed", "10", "--port", "0")
    try:
        url = proc.stdout.readline().split(" ", 1)[1].split("?")[0].strip()
        assert url.startswith("http://127.0.0.1:")
        n_segments = sum(r[1] == "adaptiveh.RetreatEvent" for r in records)
        telemetry = [m.TELEMETRY_LEARNER.decode(r[4]) for r in records if r[1].endswith("Telemetry")]
        last_step = max(t.global_step for t in telemetry)
        deadline, state = time.monotonic() + 60, {}
        while time.monotonic() < deadline:
            with urllib.request.urlopen(url + "api/state", timeout=5) as r:
                state = json.loads(r.read())
            if state["counts"]["segments"] == n_segments and state["learner"].get("step") == last_step:
                break
            time.sleep(0.3)
        assert state["counts"]["segments"] == n_segments > 0, state["counts"]
        assert state["learner"]["step"] == last_step
        assert state["robot"]["ee"] and state["target"] and state["image"]
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    assert proc.returncode == 0


def test_bytes_that_do_not_decode_are_kept_apart(tmp_path: Path, endpoint: str) -> None:
    """Garbage on a typed key is recorded as an ``adaptiveh.Rejected`` on ``_rejected/<key>``, never
    under the key's schema (a reader would fail on it) and never dropped; replay skips it."""
    from monitor.recording import Recorder, read

    session = open_session(ZenohConfig(listen=(endpoint,)))
    path = tmp_path / "r.mcap"
    recorder = Recorder(session, "rj", path)
    good = m.ChunkStatus(chunk_seq=3, executed=1, dropped=0, preempted_by=-1, verdict=1, **LABELS)
    good = good.SerializeToString()
    try:
        session.put("adaptiveh/rj/cmd/status", good)
        session.put("adaptiveh/rj/cmd/status", b"\xff\x00garbage")
        session.put("adaptiveh/rj/no/such/topic", good)
        wait_until(lambda: recorder.count == 3, 5, "the recorder to take three messages")
    finally:
        recorder.close()
        session.close()
    records = read(path)  # in arrival order; keys may come through different subscribers (Recorder)
    assert sorted((k, s) for k, s, _, _ in records) == [
        ("_rejected/adaptiveh/rj/cmd/status", "adaptiveh.Rejected"),
        ("_rejected/adaptiveh/rj/no/such/topic", "adaptiveh.Rejected"),
        ("adaptiveh/rj/cmd/status", "adaptiveh.ChunkStatus"),
    ]
    rejected = m.decode(
        next(d for k, _, _, d in records if k == "_rejected/adaptiveh/rj/cmd/status"), m.Rejected
    )
    assert rejected.data == b"\xff\x00garbage" and "ChunkStatus: undecodable" in rejected.error


def test_a_killed_recorder_leaves_everything_to_its_last_flush(tmp_path: Path, endpoint: str) -> None:
    """The file as a SIGKILL leaves it (no summary, cut mid-record) reads back up to the last flush."""
    import shutil

    from monitor.recording import Recorder, read

    session = open_session(ZenohConfig(listen=(endpoint,)))
    path = tmp_path / "r.mcap"
    recorder = Recorder(session, "kf", path, flush_s=0.2)
    try:
        for seq in range(1, 31):
            status = m.ChunkStatus(seq=seq, chunk_seq=seq, executed=1, preempted_by=-1, verdict=1, **LABELS)
            session.put("adaptiveh/kf/cmd/status", status.SerializeToString())
        time.sleep(0.8)  # a flush or more
        killed = tmp_path / "killed.mcap"
        shutil.copy(path, killed)  # what is on disk at the kill
        data = killed.read_bytes()
        killed.write_bytes(data + data[-20:-7])  # and a record cut short after it
    finally:
        recorder.close()
        session.close()
    seqs = [m.decode(d, m.ChunkStatus).seq for k, _, _, d in read(killed) if k == "adaptiveh/kf/cmd/status"]
    assert seqs == list(range(1, 31))


def test_old_msgpack_recordings_are_refused_clearly(tmp_path: Path) -> None:
    from mcap.writer import Writer

    from monitor.recording import RecordingError, read

    path = tmp_path / "old.mcap"
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        schema = writer.register_schema("RobotState", "", b"")
        channel = writer.register_channel("adaptiveh/panda/state", "msgpack", schema)
        writer.add_message(channel, 1, b"\x80", 1)
        writer.finish()
    with pytest.raises(RecordingError, match="'msgpack'; this build reads protobuf recordings only"):
        read(path)


def test_a_long_recording_is_split_and_reads_back_whole(tmp_path: Path, endpoint: str) -> None:
    """Past ``split_s`` the recorder finishes its file and begins ``<stem>.part2.mcap``: the MCAP writer's
    chunk index stays small. Each part is a whole MCAP file with its own schemas; ``read`` of the first
    reads every part, the per-key sequence going on across them."""
    from monitor.recording import Recorder, parts, read

    session = open_session(ZenohConfig(listen=(endpoint,)))
    path = tmp_path / "long.mcap"
    recorder = Recorder(session, "sp", path, flush_s=0.1, split_s=0.4)
    try:
        for seq in range(1, 61):
            status = m.ChunkStatus(seq=seq, chunk_seq=seq, executed=1, preempted_by=-1, verdict=1, **LABELS)
            session.put("adaptiveh/sp/cmd/status", status.SerializeToString())
            time.sleep(0.025)
    finally:
        recorder.close()
        session.close()
    assert len(recorder.parts) >= 3 and parts(path) == recorder.parts
    assert recorder.parts[1].name == "long.part2.mcap"
    got = [m.decode(d, m.ChunkStatus).seq for k, _, _, d in read(path) if k == "adaptiveh/sp/cmd/status"]
    assert got == list(range(1, 61))
    per_part = []
    for part in recorder.parts:  # each opens on its own, with the mcap reader and its summary
        with open(part, "rb") as fh:
            msgs = list(make_reader(fh).iter_messages())
        per_part.append(len(msgs))
        assert all(schema.name == "adaptiveh.ChunkStatus" for schema, _, _ in msgs)
    assert sum(per_part) == 60 and min(per_part[:-1]) > 0


# -- a stranger's fuzz (issue #31) ---------------------------------------------------------------------
KEY = mac_key("the operator's token")
STRANGER = mac_key("a stranger's guess")
ME = "0a1b2c3d4e5f6071"
FUZZED = 10_000
BAD_STAMPS = (-1.0, -1e-9, -1e300, 2.0**32, 1e12, 1e300)  # 1e12 s = 1e21 ns: past MCAP's uint64


def sample(key: str, data: bytes) -> SimpleNamespace:
    """What the recorder and the live view read of a ``zenoh.Sample``: its key and its payload."""
    return SimpleNamespace(key_expr=key, payload=zenoh.ZBytes(data))


def _v(rng: np.random.Generator, n: int) -> list[float]:
    return rng.uniform(-1.0, 1.0, n).tolist()


def _target(r: np.random.Generator, valid: bool, status: int) -> m.Target:
    return m.Target(position=_v(r, 3), velocity=_v(r, 3), covariance=_v(r, 9), valid=valid, status=status)


GENUINE: dict[m.Topic[Any], Callable[[np.random.Generator], m.Message]] = {
    m.STATE: lambda r: m.RobotState(
        q=_v(r, 7),
        dq=_v(r, 7),
        ee_pos=_v(r, 3),
        ee_vel=_v(r, 3),
        ee_cmd=_v(r, 3),
        mode=1,
        session=ME,
        chunk_seq=-1,
    ),
    m.TARGET: lambda r: _target(r, valid=True, status=m.Target.TRACKING),
    m.TARGET_TRUTH: lambda r: _target(r, valid=False, status=m.Target.NONE),
    m.CMD_CHUNK: lambda r: m.ActionChunk(
        actions=_v(r, 6), predicted_ee=_v(r, 6), session=ME, opened_by=m.ActionChunk.FIRST
    ),
    m.CHUNK_STATUS: lambda r: m.ChunkStatus(
        chunk_seq=3, executed=2, preempted_by=-1, session=ME, verdict=1, **LABELS
    ),
    m.EVENTS_RETREAT: lambda r: m.RetreatEvent(segment=4, H=9, reason=1, statistic=_v(r, 9), threshold=0.3),
    m.EVENTS_SAFETY: lambda r: m.SafetyEvent(kind=1, detail="workspace", held=True),
    m.TELEMETRY_LEARNER: lambda r: m.LearnerTelemetry(global_step=12, episode=1, algo="adaptiveh"),
    m.CONTROL: lambda r: m.Control(command=m.Control.PAUSE, jog=[0.0] * 3),
    m.CAMERA_ANNOTATED: lambda r: m.AnnotatedImage(jpeg=r.bytes(int(r.integers(10, 2000))), detected=True),
}


def _genuine(topic: m.Topic[Any], n: int, rng: np.random.Generator) -> bytes:
    """The stack's ``n``-th message: its own seq and a newer stamp, signed with the stack's key."""
    msg = GENUINE[topic](rng)
    msg.seq, msg.stamp = n, 1.7e9 + n * 1e-3
    if signed(type(msg)):
        sign(msg, KEY)
    return msg.SerializeToString()


def _refield(topic: m.Topic[Any], data: bytes, rng: np.random.Generator, change: str) -> bytes:
    """A genuine message changed through protobuf: a bad stamp or a NaN (then signed with the stack's key
    or a stranger's), no mac, a stranger's mac, or a seq altered under the genuine mac."""
    msg = topic.type.FromString(data)
    if change == "stamp":
        msg.stamp = float(rng.choice(BAD_STAMPS))
    elif change == "nan":
        floats = [f for f in msg.DESCRIPTOR.fields if f.type == FieldDescriptor.TYPE_DOUBLE]
        fd = floats[int(rng.integers(len(floats)))]
        if fd.is_repeated and len(getattr(msg, fd.name)):
            getattr(msg, fd.name)[0] = math.nan
        else:
            setattr(msg, fd.name, [math.nan] if fd.is_repeated else math.nan)
    elif change == "seq":
        msg.seq += 1  # the old mac kept: an altered copy
    if change in ("unsigned", "foreign") and isinstance(msg, m.Control):
        msg.command = m.Control.ESTOP  # robot-io obeys it; the recording keeps it apart all the same
    if signed(topic.type) and change != "seq":
        msg.mac = b""
        if change != "unsigned":
            sign(msg, STRANGER if change == "foreign" or rng.random() < 0.5 else KEY)
    return msg.SerializeToString()


def _mutated(topic: m.Topic[Any], data: bytes, rng: np.random.Generator) -> bytes:
    """One of a stranger's copies of ``data`` (a genuine payload already on the bus)."""
    kind = int(rng.integers(10))
    if kind == 0:
        return rng.bytes(int(rng.integers(1, 400)))
    if kind == 1:
        return data[: int(rng.integers(len(data)))]
    if kind == 2:
        out = bytearray(data)
        for _ in range(int(rng.integers(1, 5))):
            out[int(rng.integers(len(out)))] ^= 1 << int(rng.integers(8))
        return bytes(out)
    if kind == 3:  # concatenated copies: protobuf parses them as one merged message
        return data * int(rng.integers(2, max(3, 300_000 // len(data))))
    if kind == 4:
        return data  # an exact replay
    return _refield(topic, data, rng, ("stamp", "nan", "unsigned", "foreign", "seq")[kind - 5])


def _fuzz(robot: str, rng: np.random.Generator) -> Iterator[tuple[str, bytes, bool]]:
    """``FUZZED`` (key, payload, genuine?): a quarter the stack's own messages, the rest a stranger's
    mutations of recent genuine payloads, on their own key or (a tenth) on another typed key."""
    topics = list(GENUINE)
    recent: dict[m.Topic[Any], deque[bytes]] = defaultdict(lambda: deque(maxlen=8))
    for n in range(1, FUZZED + 1):
        topic = topics[int(rng.integers(len(topics)))]
        if not recent[topic] or rng.random() < 0.25:
            recent[topic].append(_genuine(topic, n, rng))
            yield topic.key(robot), recent[topic][-1], True
            continue
        data = _mutated(topic, recent[topic][int(rng.integers(len(recent[topic])))], rng)
        on = topics[int(rng.integers(len(topics)))] if rng.random() < 0.1 else topic
        yield on.key(robot), data, False


def _records(path: Path) -> Iterator[tuple[str, str, Any]]:
    """(channel, schema name, message) of every record as written, decoded with the mcap reader and the
    file's schemas alone (protobuf from the FileDescriptorSet, JSON for the derived plot values)."""
    decoders: dict[int, Any] = {}
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=False):
            if schema.encoding == "jsonschema":
                yield channel.topic, schema.name, json.loads(message.data)
                continue
            assert schema.encoding == "protobuf" and channel.message_encoding == "protobuf"
            if schema.id not in decoders:
                decoders[schema.id] = schema_decoder(schema.name, schema.data)
            yield channel.topic, schema.name, decoders[schema.id].FromString(message.data)


def _assert_typed(topic: str, msg: Any, macs: set[tuple[str, bytes]]) -> None:
    """A typed record: strictly valid, and for a signed type the stack's, once."""
    m.validate(msg)
    if signed(type(msg)):
        assert authentic(msg, KEY), (topic, msg)
        assert (topic, msg.mac) not in macs, f"{topic}: a replayed copy was recorded as the stack's"
        macs.add((topic, msg.mac))


@pytest.mark.parametrize("stamp_max_s", [m.STAMP_MAX_S, math.inf], ids=["decoder", "no-stamp-bound"])
def test_a_stranger_fuzz_is_recorded_whole_and_every_record_decodes(
    tmp_path: Path, endpoint: str, monkeypatch: pytest.MonkeyPatch, stamp_max_s: float
) -> None:
    """Issue #31: 10^4 of a stranger's random, truncated, bit-flipped, concatenated (merged, up to 300 kB),
    restamped, NaN, unsigned, foreign-signed and replayed payloads among the stack's own, fed to a recorder
    with the stack's key. Every record decodes with its channel's schema (mcap and protobuf alone); typed
    channels hold only authentic messages, each once, every genuine one among them; and the file holds
    as many raw records as were fed, the rest under ``_rejected/``. Also with the decoder's stamp bound
    lifted (as when the issue was found): the recorder itself never hands MCAP a time it cannot pack."""
    from monitor.recording import REJECTED, Recorder, read

    monkeypatch.setattr(m, "STAMP_MAX_S", stamp_max_s)
    session = open_session(ZenohConfig(listen=(endpoint,)))
    robot, path = unique_name("fz"), tmp_path / "fuzz.mcap"
    deriver = Deriver(robot) if math.isfinite(stamp_max_s) else None  # Foxglove's times need the bound
    recorder = Recorder(session, robot, path, deriver=deriver, key=KEY)
    fed: list[tuple[str, bytes, bool]] = []
    try:
        for key, data, genuine in _fuzz(robot, np.random.default_rng(31)):
            fed.append((key, data, genuine))
            recorder._on_sample(sample(key, data))
    finally:
        recorder.close()
        session.close()
    raw, macs = Counter(), set()
    for topic, name, msg in _records(path):
        if is_derived(topic):
            continue
        raw[topic.startswith(REJECTED)] += 1
        if topic.startswith(REJECTED):
            assert name == "adaptiveh.Rejected" and msg.key == topic[len(REJECTED) :] and msg.error
        else:
            assert m.topic_of_key(topic).type.DESCRIPTOR.full_name == name
            _assert_typed(topic, msg, macs)
    assert raw.total() == recorder.count == len(fed) == FUZZED  # nothing lost
    records = read(path)  # the project's reader agrees
    assert (recorder.derived > 0) == (deriver is not None) and len(records) == FUZZED + recorder.derived
    typed = Counter((k, d) for k, _, _, d in records if m.topic_of_key(k) is not None)
    genuine = [(k, d) for k, d, g in fed if g]
    assert all(typed[kd] == 1 for kd in genuine if signed(m.topic_of_key(kd[0]).type))  # each once
    assert all(typed[kd] >= 1 for kd in genuine)  # an image has no mac: its copies are recorded too
    assert len(genuine) < raw[False] < len(fed) / 2, raw  # and image copies, Targets on both Target keys


def test_a_stamp_mcap_cannot_hold_never_reaches_the_writer(
    tmp_path: Path, endpoint: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue #31's cause: a decodable message stamped 1e12 s (1e21 ns, past MCAP's uint64) made the writer
    fail half-way through a record, and a reader took the rest of the chunk as that message. With the
    decoder's stamp bound lifted (as before it existed), such a message is recorded whole with its arrival
    time, and everything after it reads back."""
    from monitor.recording import Recorder

    monkeypatch.setattr(m, "STAMP_MAX_S", math.inf)
    session = open_session(ZenohConfig(listen=(endpoint,)))
    robot, path = unique_name("st"), tmp_path / "stamps.mcap"
    recorder = Recorder(session, robot, path)
    stamps = [1.7e9, 1e12, 1e300, 1.7e9 + 1]
    try:
        for n, stamp in enumerate(stamps):
            msg = m.LearnerTelemetry(seq=n, stamp=stamp, global_step=n)
            recorder._on_sample(sample(m.TELEMETRY_LEARNER.key(robot), msg.SerializeToString()))
    finally:
        recorder.close()
        session.close()
    with open(path, "rb") as fh:
        records = make_reader(fh).iter_messages(log_time_order=False)  # as written
        got = [(msg.publish_time, msg.log_time, msg.data) for _, _, msg in records]
    assert [m.LearnerTelemetry.FromString(d).seq for *_, d in got] == [0, 1, 2, 3]
    assert [p == t for p, t, _ in got] == [False, True, True, False]  # a stamp MCAP cannot hold: arrival
    assert got[3][0] == int((1.7e9 + 1) * 1e9)


def test_a_stranger_s_many_keys_share_one_rejected_channel(
    tmp_path: Path, endpoint: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """MCAP's channel ids are uint16: past ``MAX_OTHER_KEYS`` keys outside the schema, their bytes share
    one ``_rejected`` channel (each Rejected keeps its key), so a stranger's new keys cannot exhaust them."""
    import monitor.recording as rec

    monkeypatch.setattr(rec, "MAX_OTHER_KEYS", 3)
    session = open_session(ZenohConfig(listen=(endpoint,)))
    robot, path = unique_name("mk"), tmp_path / "keys.mcap"
    recorder = rec.Recorder(session, robot, path)
    keys = [m.key(robot, f"k{i}") for i in range(6)] + [m.key(robot, "k0")]
    try:
        for key in keys:
            recorder._on_sample(sample(key, b"x"))
    finally:
        recorder.close()
        session.close()
    got = [(topic, msg.key) for topic, _, msg in _records(path)]
    other = rec.REJECTED + m.key(robot, rec.OTHER_KEYS)
    assert got == [(rec.REJECTED + k, k) for k in keys[:3]] + [(other, k) for k in keys[3:6]] + [
        (rec.REJECTED + keys[0], keys[0])
    ]
