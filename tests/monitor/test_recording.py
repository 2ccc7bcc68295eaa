"""A short ``adaptiveh up`` run records every part's traffic to MCAP; the file decodes with the mcap
reader and the protobuf schema stored in it alone (no project code), Foxglove's well-known channels
included; ``adaptiveh replay`` puts the robot's own channels back on Zenoh, where a subscriber and the
monitor's JSON endpoint receive them."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
import urllib.request
from collections import Counter
from pathlib import Path

import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader
from stack_helpers import write_stack_config

from bus import messages as m
from bus.transport import ZenohConfig, open_session

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
    good = m.ChunkStatus(chunk_seq=3, executed=1, dropped=0, preempted_by=-1, verdict=1).SerializeToString()
    try:
        session.put("adaptiveh/rj/cmd/status", good)
        session.put("adaptiveh/rj/cmd/status", b"\xff\x00garbage")
        session.put("adaptiveh/rj/no/such/topic", good)
        deadline = time.monotonic() + 5
        while recorder.count < 3 and time.monotonic() < deadline:
            time.sleep(0.02)
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
            status = m.ChunkStatus(seq=seq, chunk_seq=seq, executed=1, preempted_by=-1, verdict=1)
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
            status = m.ChunkStatus(seq=seq, chunk_seq=seq, executed=1, preempted_by=-1, verdict=1)
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
