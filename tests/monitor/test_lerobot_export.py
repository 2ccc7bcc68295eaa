"""``adaptiveh export lerobot``: a short ``adaptiveh up`` run exports, and LeRobot's own ``LeRobotDataset``
loads it with the recording's episodes, frames, fps and features; every frame's state, action and reward
are the recording's at the frame's tick (read back from the MCAP with the mcap reader, not the
exporter). A recording made here on Zenoh, whose later-stamped values arrive first, shows that a frame
never takes a value stamped after its tick; a damaged recording is refused with the file and channel.
Skipped, with the reason, only where LeRobot cannot be imported."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import av
import cv2
import numpy as np
import pytest
import yaml
from bus_probe import LABELS
from loopback import unique_name
from mcap.reader import make_reader
from mcap.writer import Writer
from polling import wait_until
from stack_helpers import run_up, write_stack_config

from bus import messages as m
from bus.transport import ZenohConfig, open_session
from monitor.lerobot_export import CAMERA_KEY, ExportError, export, lerobot_dataset_class
from monitor.recording import Recorder
from tasks.reach import OBSERVATION_NAMES


@pytest.fixture(scope="module")
def lerobot() -> type:
    """LeRobot's ``LeRobotDataset`` class, or the module is skipped with why it cannot be imported."""
    try:
        return lerobot_dataset_class()
    except ExportError as exc:
        pytest.skip(str(exc))


def load(dataset_class: type, out: Path) -> Any:
    """The export at ``out`` as LeRobot loads a local dataset."""
    info = json.loads((out / "meta" / "info.json").read_text())
    return dataset_class(f"adaptiveh/{info['robot_type']}", root=out)


def mcap_messages(path: Path) -> dict[str, list]:
    """The recording's typed messages by topic, in log order, decoded with the schema's classes; the
    transitions once each (an actor resends those its learner lacks: the same step, a later copy)."""
    out: dict[str, list] = defaultdict(list)
    with open(path, "rb") as fh:
        for _, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            topic = m.topic_of_key(channel.topic)
            if topic is not None:
                out[topic.name].append(topic.type.FromString(message.data))
    once = {(tr.episode, tr.step): tr for tr in reversed(out["stream/transition"])}
    out["stream/transition"] = sorted(once.values(), key=lambda tr: (tr.episode, tr.step))
    return out


# -- a short stack run ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def stack_export(lerobot: type, tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path, Path]:
    """A 60-step ``adaptiveh up`` run (one episode and part of the next), its annotated image at 10 Hz,
    exported; (config, recording, dataset folder)."""
    tmp = tmp_path_factory.mktemp("lerobot")
    path, cfg = write_stack_config(tmp, "lrx", vision_rate_hz=10.0, steps=60)
    cfg["vision"]["annotated"]["rate_hz"] = 10.0
    path.write_text(yaml.safe_dump(cfg))
    recording = Path(run_up(path, "--log-level", "WARNING", timeout=240)["recording"])
    out = tmp / "dataset"
    export([recording], out, learner_names=OBSERVATION_NAMES)
    return cfg, recording, out


def test_lerobot_loads_the_export_of_a_stack_run(lerobot: type, stack_export: tuple) -> None:
    cfg, recording, out = stack_export
    ds = load(lerobot, out)
    transitions = mcap_messages(recording)["stream/transition"]
    episodes = [tr.episode for tr in transitions]
    assert ds.num_frames == len(transitions) >= cfg["learner"]["steps"]  # the actor may run a few more
    assert ds.num_episodes == len(set(episodes)) >= 2
    assert ds.meta.total_tasks == 1
    assert ds.fps == cfg["robot"]["control_rate_hz"] == 20
    assert list(ds.meta.episodes["length"]) == [episodes.count(e) for e in sorted(set(episodes))]
    ours = {
        "observation.state",
        "observation.learner",
        "action",
        "next.reward",
        "next.done",
        "next.success",
        "segment.index",
        "segment.end",
        "retreat.statistic",
        "retreat.evaluated",
        "plan.dropped",
        "observation.camera_age",
        "robot.tick",
        "robot.stamp_ns",
        "robot.published",
        CAMERA_KEY,
    }
    assert set(ds.features) == ours | {"timestamp", "frame_index", "episode_index", "index", "task_index"}
    assert ds.features["observation.state"]["shape"] == (7 + 10,)
    assert ds.features["observation.learner"]["names"] == list(OBSERVATION_NAMES)
    height = round(cfg["vision"]["annotated"]["width"] * 480 / 640)
    assert ds.features[CAMERA_KEY]["shape"] == (height, cfg["vision"]["annotated"]["width"], 3)
    assert ds.meta.video_keys == [CAMERA_KEY] and ds.meta.stats["action"]["mean"].shape == (3,)
    video = out / ds.meta.get_video_file_path(0, CAMERA_KEY)
    with av.open(str(video)) as container:  # every frame has its image in the video
        assert sum(1 for _ in container.decode(video=0)) == ds.num_frames


def test_every_frame_is_the_recording_at_its_tick(lerobot: type, stack_export: tuple) -> None:
    """State, action, reward and the learner's observation of every frame, against the MCAP: the frame's
    tick is the state it names (tick and publish time); its action is what the tick played whose state
    the Transition's next observation is (the next tick, unless the actor passed ticks over)."""
    _, recording, out = stack_export
    msgs = mcap_messages(recording)
    states = {(s.tick, int(s.stamp * 1e9)): s for s in msgs["state"]}
    chunks = {(c.session, c.seq, c.stamp): m.action_array(c) for c in msgs["cmd/chunk"]}
    transitions = msgs["stream/transition"]
    rows = load(lerobot, out).hf_dataset.with_format("numpy")[:]
    assert len(rows["index"]) == len(transitions)
    published = 0
    for k, tr in enumerate(transitions):
        state = states[(int(rows["robot.tick"][k]), int(rows["robot.stamp_ns"][k]))]
        assert np.array_equal(rows["observation.state"][k][:7], np.float32(state.q))
        assert np.array_equal(rows["observation.state"][k][7:10], np.float32(state.ee_pos))
        assert np.array_equal(rows["observation.learner"][k], np.float32(tr.obs))
        assert rows["next.reward"][k] == np.float32(tr.reward)
        assert rows["next.success"][k] == tr.success and rows["segment.index"][k] == tr.segment
        assert rows["segment.end"][k] == m.label(tr, "end")  # the learner's own vocabulary (SegmentEnd)
        nxt = next_state(msgs["state"], state.tick, tr.next_obs)  # the tick that played the action
        played = np.zeros(3)  # a hold
        if nxt.played_chunk >= 0:
            played = chunks[(nxt.session, nxt.played_chunk, nxt.played_stamp)][nxt.played_index]
        assert np.array_equal(rows["action"][k], np.float32(played))
        published += bool(rows["robot.published"][k])
        if rows["robot.published"][k]:  # the observation is this state's, as the learner saw it
            assert np.array_equal(rows["observation.learner"][k][:3], np.float32(state.ee_cmd))
    assert published >= len(transitions) - 2  # all but the episodes' first, observed from the reset


def next_state(states: list, after: int, next_obs: list) -> m.RobotState:
    """The first state after tick ``after`` that the learner's ``next_obs`` was observed from."""
    wanted = np.float32(next_obs[:6])
    return min(
        (s for s in states if s.tick > after and np.array_equal(np.float32([*s.ee_cmd, *s.ee_vel]), wanted)),
        key=lambda s: s.tick,
    )


# -- a recording made here ---------------------------------------------------------------------------------
T0, PERIOD = 1_800_000_000.0, 0.05
SESSION = "s1"


def jpeg(color: tuple[int, int, int]) -> bytes:
    """A 64x64 image of one RGB colour, as the annotated image carries it."""
    bgr = np.zeros((64, 64, 3), np.uint8)
    bgr[:] = color[::-1]
    return cv2.imencode(".jpg", bgr)[1].tobytes()


def state(tick: int, played: int) -> m.RobotState:
    """The arm at ``tick``: it moves 1 cm in x a tick; ``played``: the index it played of chunk 0."""
    x = 0.4 + 0.01 * tick
    return m.RobotState(
        seq=tick + 1,
        stamp=T0 + PERIOD * tick,
        q=[0.1 * tick] * 7,
        dq=[0.0] * 7,
        ee_pos=[x, 0.0, 0.3],
        ee_vel=[0.2, 0.0, 0.0],
        ee_cmd=[x, 0.0, 0.3],
        mode=m.RobotState.RUNNING,
        tick=tick,
        played_chunk=0 if played >= 0 else -1,
        played_index=played,
        played_stamp=T0 if played >= 0 else 0.0,
        session=SESSION,
        instance="i1",
    )


def transition(step: int, obs_tick: int) -> m.Transition:
    def obs(tick: int) -> list[float]:
        x = 0.4 + 0.01 * tick
        return [x, 0.0, 0.3, 0.2, 0.0, 0.0, 0.5, 0.1, 0.3, 0.0, 0.0, 0.0, 0.5 - x, 0.1, 0.0]

    return m.Transition(
        seq=step + 1,
        stamp=T0 + PERIOD * (obs_tick + 1) + 0.002,  # after the tick that played its action
        step=step,
        episode=0,
        segment=0,
        obs=obs(obs_tick),
        raw_action=[0.01, 0.0, 0.0],
        reward=-0.1 * step,
        next_obs=obs(obs_tick + 1),
        truncated=step == 3,
        end=m.SegmentEnd.EPISODE_END if step == 3 else m.SegmentEnd.OPEN,
        target_age=0.03,
    )


def record(path: Path, endpoint: str, puts: list[tuple[str, bytes]]) -> None:
    """``puts`` (topic, bytes) put on a real Zenoh session, in this order, and recorded."""
    session = open_session(ZenohConfig(listen=(endpoint,)))
    robot = unique_name("lrt")
    recorder = Recorder(session, robot, path)
    try:
        for topic, data in puts:
            session.put(m.key(robot, topic), data)
        wait_until(lambda: recorder.count == len(puts), 10, "the recorder to take every message")
    finally:
        recorder.close()
        session.close()


def later_values_first(path: Path, endpoint: str) -> None:
    """Ticks 0..5 and four transitions observing ticks 1..4; image A (red) stamped at tick 1, image B
    (blue) 1 ms after tick 2, a target fix 1 ms after tick 1, and a chunk's 5 dropped actions 1 ms after
    tick 2, each of the late ones put on the bus before the tick it follows; one transition again (a
    resend) and garbage on the transition key (recorded apart, on ``_rejected/...``)."""
    t = [T0 + PERIOD * k for k in range(6)]
    late_image = m.AnnotatedImage(seq=2, stamp=t[2] + 0.001, jpeg=jpeg((0, 0, 255)), detected=True)
    fix = {"position": [0.5, 0.1, 0.3], "velocity": [0.0] * 3, "covariance": [0.0] * 9, "valid": True}
    early_fix = m.Target(seq=1, stamp=t[0], status=m.Target.TRACKING, **fix)
    late_fix = m.Target(seq=2, stamp=t[1] + 0.001, status=m.Target.TRACKING, **fix)
    dropped = m.ChunkStatus(
        seq=1,
        stamp=t[2] + 0.001,
        chunk_seq=0,
        executed=3,
        dropped=5,
        preempted_by=1,
        done=True,
        session=SESSION,
        verdict=m.ChunkStatus.ACCEPTED,
        chunk_stamp=T0,
        **LABELS,
    )
    actions = [0.01, 0.0, 0.0] * 6
    chunk = m.ActionChunk(seq=0, stamp=T0, actions=actions, session=SESSION, opened_by=m.ActionChunk.FIRST)
    early_image = m.AnnotatedImage(seq=1, stamp=t[1], jpeg=jpeg((255, 0, 0)), detected=True)
    puts = [("cmd/chunk", chunk), ("target", early_fix), ("state", state(0, -1)), ("target", late_fix)]
    puts += [("state", state(1, 0)), ("camera/annotated", early_image), ("camera/annotated", late_image)]
    puts += [("cmd/status", dropped), ("state", state(2, 1))]
    puts += [("state", state(k, k - 1)) for k in (3, 4, 5)]
    puts += [("stream/transition", transition(step, step + 1)) for step in range(4)]
    resent = transition(1, 2)  # an actor's resend to its learner: the same tick, a new seq and stamp
    resent.seq, resent.stamp = 99, t[5] + 0.5
    puts.append(("stream/transition", resent))
    encoded = [(topic, msg.SerializeToString()) for topic, msg in puts]
    record(path, endpoint, [*encoded, ("stream/transition", b"\xff\x00not a transition")])


def test_a_frame_never_takes_a_value_stamped_after_its_tick(
    lerobot: type, tmp_path: Path, endpoint: str
) -> None:
    later_values_first(tmp_path / "r.mcap", endpoint)
    out = tmp_path / "dataset"
    report = export([tmp_path / "r.mcap"], out)
    assert report["frames"] == 4 and report["episodes"] == 1 and report["fps"] == 20
    rows = load(lerobot, out).hf_dataset.with_format("numpy")[:]
    ticks = rows["robot.tick"].tolist()
    assert ticks == [1, 2, 3, 4]
    stamps = rows["robot.stamp_ns"] / 1e9
    assert np.allclose(stamps, [T0 + PERIOD * k for k in ticks], atol=1e-6)
    # The fix stamped 1 ms after tick 1 is not the first frame's: its age is from the fix before.
    assert rows["observation.state"][0][-1] == pytest.approx(PERIOD, abs=1e-4)
    # Dropped actions reported 1 ms after tick 2 are the next frame's, not tick 2's.
    assert rows["plan.dropped"].tolist() == [0, 0, 5, 0]
    # Image B, stamped after tick 2 (and recorded before it), first shows at tick 3.
    ages = [0.0, PERIOD, PERIOD - 0.001, 2 * PERIOD - 0.001]
    assert rows["observation.camera_age"] == pytest.approx(ages, abs=1e-5)
    video = out / "videos" / CAMERA_KEY / "chunk-000" / "file-000.mp4"
    with av.open(str(video)) as container:
        colours = [
            f.to_ndarray(format="rgb24").reshape(-1, 3).mean(axis=0) for f in container.decode(video=0)
        ]
    red_then_blue = [int(np.argmax(c)) for c in colours]
    assert red_then_blue == [0, 0, 2, 2], colours
    assert np.allclose(rows["action"], [[0.01, 0.0, 0.0]] * 4)


def test_a_gap_in_the_transitions_is_refused_with_its_channel(tmp_path: Path, endpoint: str) -> None:
    puts = [("state", state(k, -1)) for k in range(4)]
    puts += [("stream/transition", transition(step, step)) for step in (0, 2)]  # step 1 lost
    record(tmp_path / "gap.mcap", endpoint, [(t, msg.SerializeToString()) for t, msg in puts])
    with pytest.raises(
        ExportError, match=r"gap\.mcap: channel adaptiveh/lrt\S+/stream/transition: step 0 is "
    ):
        export([tmp_path / "gap.mcap"], tmp_path / "dataset")


def test_bytes_that_are_no_message_are_refused_with_file_and_channel(tmp_path: Path) -> None:
    """A file written by something else, with bytes on a typed channel that do not decode as its type."""
    path = tmp_path / "bad.mcap"
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        schema = writer.register_schema(
            "adaptiveh.RobotState", "protobuf", m.file_descriptor_set(m.RobotState)
        )
        channel = writer.register_channel("adaptiveh/bad/state", "protobuf", schema)
        writer.add_message(channel, 1, b"\xff\x00garbage", 1)
        writer.finish()
    with pytest.raises(ExportError, match=r"bad\.mcap: channel adaptiveh/bad/state: .*RobotState"):
        export([path], tmp_path / "dataset")
    assert not (tmp_path / "dataset").exists()
