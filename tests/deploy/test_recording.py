"""A short ``adaptiveh up`` run records every part's traffic to MCAP; the file decodes with the mcap
reader and the protobuf schema stored in it alone (no project code); ``adaptiveh replay`` puts it back
on Zenoh, where a subscriber and the monitor's JSON endpoint receive it."""

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

from deploy import messages as m
from deploy.transport import ZenohConfig, open_session

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
    records, decoders = [], {}
    with open(mcap, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            assert schema.encoding == "protobuf"
            records.append(
                (channel.topic, schema.name, channel.message_encoding, message.sequence, message.data)
            )
            decoders[schema.name] = decoders.get(schema.name) or schema_decoder(schema.name, schema.data)
    cfg["_path"] = str(path)
    cfg["_decoders"] = decoders
    return cfg, mcap, records


def test_recording_has_every_type_decodable(run: tuple[dict, Path, list]) -> None:
    cfg, _, records = run
    assert TYPES <= {r[1] for r in records}, Counter(r[1] for r in records)
    assert not any(r[1] == "adaptiveh.CameraFrame" for r in records)  # excluded in sim.yaml: huge
    decoders, last_seq = cfg["_decoders"], {}
    for topic, schema, encoding, seq, data in records:
        assert topic.startswith(f"adaptiveh/{cfg['name']}/") and encoding == "protobuf"
        msg = decoders[schema].FromString(data)  # the schema in the file alone, no project code
        assert msg.DESCRIPTOR.full_name == schema and msg.SerializeToString() == data
        assert seq > last_seq.get(topic, 0)  # per-channel sequence, in time order
        last_seq[topic] = seq
        if schema == "adaptiveh.RobotState":  # joint positions are numbers in every state message
            assert len(msg.q) == 7 and all(isinstance(x, float) for x in msg.q), msg
    telemetry = decoders["adaptiveh.LearnerTelemetry"]
    steps = [telemetry.FromString(d).global_step for _, s, _, _, d in records if s.endswith("Telemetry")]
    assert max(steps) == cfg["learner"]["steps"]  # the learner's last telemetry made it into the file


def _replay(cfg: dict, mcap: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "replay", str(mcap), "--config", cfg["_path"], *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_replay_reaches_a_subscriber(run: tuple[dict, Path, list]) -> None:
    cfg, mcap, records = run
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
    from deploy.recording import Recorder, read

    session = open_session(ZenohConfig(listen=(endpoint,)))
    path = tmp_path / "r.mcap"
    recorder = Recorder(session, "rj", path)
    good = m.ChunkStatus(chunk_seq=3, executed=1, dropped=0, preempted_by=-1).SerializeToString()
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
    records = read(path)
    assert [(k, s) for k, s, _, _ in records] == [
        ("adaptiveh/rj/cmd/status", "adaptiveh.ChunkStatus"),
        ("_rejected/adaptiveh/rj/cmd/status", "adaptiveh.Rejected"),
        ("_rejected/adaptiveh/rj/no/such/topic", "adaptiveh.Rejected"),
    ]
    rejected = m.decode(records[1][3], m.Rejected)
    assert rejected.data == b"\xff\x00garbage" and "ChunkStatus: undecodable" in rejected.error


def test_old_msgpack_recordings_are_refused_clearly(tmp_path: Path) -> None:
    from mcap.writer import Writer

    from deploy.recording import RecordingError, read

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
