"""A run's recordings as a LeRobotDataset (format v3), written by LeRobot's own writer.

``adaptiveh export lerobot RECORDING... --out DIR``. One dataset frame per control tick the actor played
(``stream/transition``: the learner's own account of every executed tick), one dataset episode per
environment episode, fps the control rate (measured from the ``state`` stream's ticks: the recording
holds no config). Each frame is a gymnasium step: the observation before the tick, the action the tick
played, the reward and done after it.

Alignment. A Transition names no robot tick, so the frame's tick is found by value: the state whose
commanded TCP and velocity (float32, as the learner stores them) equal the Transition's ``obs[0:6]``,
the earliest after the previous frame's (ticks are consumed once, in order), stamped no later than the
Transition. Its ``stamp`` is the frame's time T; every other stream gives the frame its newest value
stamped at or before T, never a later one (a camera image published after T waits for the next frame).
The action is the step the next tick played (its state's ``played_chunk``/``played_index``, looked up in
the recorded ``cmd/chunk``); reward, done, success, segment and the retreat statistic are the
Transition's own.

Columns (LeRobot's names first, then ours; ``docs/stack_operator.md`` explains them):
``observation.state`` (joints, measured end effector, the target position and velocity as the learner saw
it, the fix's age), ``observation.learner`` (the learner's 15 values, exactly), ``action`` (the Cartesian
step played, m per period; zeros on a hold), ``observation.images.camera`` (raw ``camera/frame`` when
recorded, else the operator's annotated JPEG), ``next.reward``, ``next.done``, ``next.success``, the task
text; ``segment.index``, ``segment.end`` (open, retreat, h_max, episode_end: the schema's
``SegmentEnd`` of the schema, which spells ``learner.segments.SegmentEnd``), ``retreat.statistic`` with
``retreat.evaluated``, ``plan.dropped`` (planned actions a newer chunk preempted, reported in
``cmd/status`` since the previous frame), ``observation.camera_age``, and ``robot.tick``,
``robot.stamp_ns`` (the frame's state in the MCAP: tick, publish time) and ``robot.published``.

Not recorded, so not exported: the joint torques, the depth image unless ``camera/frame`` was recorded
(it is not exported either way), the config (the fps comes from the ticks, the task text is fixed).
"""

from __future__ import annotations

import importlib
import shutil
import sys
from bisect import bisect_right
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bus import messages as m
from common.errors import AdaptiveHError
from monitor.recording import each_tick_once, read

TASK_TEXT = "reach the moving target with the end effector"
CAMERA_KEY = "observation.images.camera"
TOPICS = (m.STATE, m.TRANSITIONS, m.CMD_CHUNK, m.CHUNK_STATUS, m.TARGET, m.CAMERA, m.CAMERA_ANNOTATED)
FPS_TOLERANCE = 0.1  # the measured rate is within 10 % of a whole number of ticks per second


class ExportError(AdaptiveHError, ValueError):
    """A recording that cannot be exported as it is; the text names the file and the channel."""


@dataclass
class Stream:
    """One channel's messages, ordered by their ``stamp``, for as-of look-ups."""

    key: str
    msgs: list[Any] = field(default_factory=list)
    stamps: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def sort(self) -> None:
        order = sorted(range(len(self.msgs)), key=lambda i: self.msgs[i].stamp)
        self.msgs = [self.msgs[i] for i in order]
        self.stamps = np.array([msg.stamp for msg in self.msgs], dtype=float)

    def index_at(self, t: float) -> int:
        """The index of the newest message stamped at or before ``t``; -1 when none is."""
        return bisect_right(self.stamps, t) - 1


@dataclass
class Recording:
    """The channels of one recording the export reads, decoded and checked."""

    path: Path
    robot: str
    streams: dict[str, Stream]

    def stream(self, topic: m.Topic) -> Stream:
        return self.streams.get(topic.name) or Stream(m.key(self.robot, topic.name))


def load(path: str | Path) -> Recording:
    """Decode the channels the export uses; a message that does not decode is an ExportError.

    Rejected bytes (``_rejected/...``) and the derived Foxglove channels are not the robot's messages and
    are not read; every other message of a used channel must decode as its type (a recording written by
    this stack always does: the recorder keeps bad bytes apart). A message recorded twice, byte for byte,
    is read once."""
    path = Path(path)
    if not path.exists():
        raise ExportError(f"{path}: no such recording")
    wanted = {t.name: t for t in TOPICS}
    robots: set[str] = set()
    streams: dict[str, Stream] = {}
    seen: dict[tuple[str, int, float], bytes] = {}
    for key, _, log_time, data in read(path):
        topic = m.topic_of_key(key)
        if topic is None:  # rejected bytes, derived Foxglove channels
            continue
        robots.add(key.split("/")[1])
        if topic.name not in wanted:
            continue
        try:
            msg = topic.decode(data)
        except m.MessageError as exc:
            raise ExportError(f"{path}: channel {key}: message logged at {log_time} ns: {exc}") from None
        if seen.get((key, msg.seq, msg.stamp)) == data:
            continue  # the same message recorded twice (a copy recovered from the publisher's cache)
        seen[(key, msg.seq, msg.stamp)] = data
        streams.setdefault(topic.name, Stream(key)).msgs.append(msg)
    if len(robots) != 1:
        raise ExportError(f"{path}: expected the channels of one robot, found {sorted(robots) or 'none'}")
    for stream in streams.values():
        stream.sort()
    return Recording(path, robots.pop(), streams)


def control_rate(rec: Recording) -> int:
    """Ticks per second, from the ``state`` stream: the median stamp step between consecutive ticks."""
    states = rec.stream(m.STATE)
    steps = [
        b.stamp - a.stamp
        for a, b in zip(states.msgs, states.msgs[1:], strict=False)
        if b.tick == a.tick + 1 and a.instance == b.instance
    ]
    if not steps:
        raise ExportError(f"{rec.path}: channel {states.key}: no two consecutive ticks to measure the rate")
    rate = 1.0 / float(np.median(steps))
    if abs(rate - round(rate)) > FPS_TOLERANCE * rate:
        raise ExportError(f"{rec.path}: channel {states.key}: {rate:.2f} ticks/s is not a whole rate")
    return round(rate)


# -- the frames ------------------------------------------------------------------------------------------
@dataclass
class Episode:
    """One environment episode's frames, column by column (numpy arrays of one row a frame)."""

    recording: Path
    number: int  # the actor's episode number in its recording
    columns: dict[str, np.ndarray]
    camera: Images  # the recording's camera stream
    images: np.ndarray  # each frame's image: its index in ``camera``; -1: none yet

    def __len__(self) -> int:
        return len(self.images)


def _state_key(values: Sequence[float]) -> bytes:
    """A state's (commanded TCP, velocity) as the learner's float32 observation holds them."""
    return np.asarray(values, dtype=np.float32).tobytes()


class TickFinder:
    """Finds the robot tick of an observation: the earliest state from ``start`` on, stamped no later
    than ``until``, whose (ee_cmd, ee_vel) equal the observation's first six values."""

    def __init__(self, rec: Recording) -> None:
        self.rec = rec
        self.states = rec.stream(m.STATE)
        self.keys = [_state_key([*s.ee_cmd, *s.ee_vel]) for s in self.states.msgs]

    def find(self, obs: Sequence[float], start: int, until: float, what: str) -> int:
        wanted = _state_key(obs[:6])
        stop = self.states.index_at(until)
        for i in range(start, stop + 1):
            if self.keys[i] == wanted:
                return i
        raise ExportError(
            f"{self.rec.path}: channel {self.states.key}: no state at or after index {start} stamped "
            f"by {until:.3f} matches the observation of {what}"
        )


def _chunks(rec: Recording) -> dict[tuple[str, int, float], m.ActionChunk]:
    return {(c.session, c.seq, c.stamp): c for c in rec.stream(m.CMD_CHUNK).msgs}


def played_step(rec: Recording, state: m.RobotState, chunks: dict) -> np.ndarray:
    """The Cartesian step the tick of ``state`` played: its chunk's action, zeros on a hold."""
    if state.played_chunk < 0:
        return np.zeros(3)
    chunk = chunks.get((state.session, state.played_chunk, state.played_stamp))
    if chunk is None or not 0 <= state.played_index < len(chunk.actions) // 3:
        raise ExportError(
            f"{rec.path}: channel {rec.stream(m.CMD_CHUNK).key}: tick {state.tick} played chunk "
            f"{state.played_chunk} action {state.played_index}, which the recording does not hold"
        )
    return m.action_array(chunk)[state.played_index]


def target_age(rec: Recording, t: float) -> float:
    """The age at ``t`` of the newest target fix stamped by then (the learner's rule:
    ``deploy.zenoh_env.target_at``); -1 when there is none."""
    targets = rec.stream(m.TARGET)
    i = targets.index_at(t)
    if i < 0:
        return -1.0
    fix = targets.msgs[i]
    return max(0.0, t - (fix.frame_stamp if fix.frame_stamp > 0 else fix.stamp))


def _episodes_of(transitions: list[m.Transition]) -> Iterator[list[m.Transition]]:
    """Runs of consecutive Transitions of one episode number (a restarted actor, counting its steps from
    0 again, begins a new one too)."""
    run: list[m.Transition] = []
    for tr in transitions:
        if run and (tr.episode != run[-1].episode or tr.step == 0):
            yield run
            run = []
        run.append(tr)
    if run:
        yield run


def _check_steps(rec: Recording, transitions: list[m.Transition]) -> None:
    """Every executed tick once: a gap in the actor's step count is a lost Transition."""
    for a, b in zip(transitions, transitions[1:], strict=False):
        if b.step != a.step + 1 and b.step != 0:  # 0: a restarted actor counts again
            raise ExportError(
                f"{rec.path}: channel {rec.stream(m.TRANSITIONS).key}: step {a.step} is followed by "
                f"{b.step}: {b.step - a.step - 1} executed ticks are missing from the recording"
            )


class Images:
    """The camera stream the video is made of: raw frames when recorded, else the annotated JPEGs."""

    def __init__(self, rec: Recording, source: str) -> None:
        self.rec = rec
        raw, annotated = rec.stream(m.CAMERA), rec.stream(m.CAMERA_ANNOTATED)
        if source == "auto":
            source = "frame" if raw.msgs else "annotated" if annotated.msgs else "none"
        self.source = source
        self.stream = {"frame": raw, "annotated": annotated}.get(source, Stream(""))
        if source != "none" and not self.stream.msgs:
            raise ExportError(
                f"{rec.path}: channel {self.stream.key}: no images recorded (--camera {source})"
            )

    def at(self, t: float) -> tuple[int, float]:
        """(index of the newest image stamped at or before ``t``, its age at ``t``); (-1, -1) for none."""
        i = self.stream.index_at(t)
        return (i, float(t - self.stream.stamps[i])) if i >= 0 else (-1, -1.0)

    def decode(self, i: int) -> np.ndarray:
        """Image ``i`` as HxWx3 RGB uint8."""
        msg = self.stream.msgs[i]
        if self.source == "frame":
            try:
                return m.frame_images(msg)[0].copy()
            except m.MessageError as exc:
                raise ExportError(f"{self.rec.path}: channel {self.stream.key}: {exc}") from None
        bgr = cv2.imdecode(np.frombuffer(msg.jpeg, np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ExportError(f"{self.rec.path}: channel {self.stream.key}: image {msg.seq} is no JPEG")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def frame_ticks(finder: TickFinder, tr: m.Transition, at: int, first: bool) -> tuple[int, int, bool]:
    """(the state of the frame's tick, the state of the tick that played its action, whether the first
    is the state the observation came from).

    An episode's first observation is robot-io's reset reply, which is not published on ``state`` when
    the reset is instant (the PyBullet mock; franky's homing publishes it): the frame's tick is then the
    newest published state before the tick that played the action, and the flag is False. A later
    observation is always a published state: not finding it is an error."""
    what = f"step {tr.step} (episode {tr.episode})"
    try:
        i = finder.find(tr.obs, at, tr.stamp, f"{what}'s obs")
    except ExportError:
        if not first:
            raise
        j = finder.find(tr.next_obs, at, tr.stamp, f"{what}'s next_obs")
        if j == 0:
            raise
        return j - 1, j, False
    return i, finder.find(tr.next_obs, i + 1, tr.stamp, f"{what}'s next_obs"), True


def episodes(rec: Recording, camera: str = "auto") -> list[Episode]:
    """The recording's environment episodes as frames (see the module docstring for the alignment)."""
    transitions = rec.stream(m.TRANSITIONS).msgs
    if not transitions:
        raise ExportError(
            f"{rec.path}: channel {rec.stream(m.TRANSITIONS).key}: no transitions recorded (the export "
            "reads the actor's: learner.execution actor)"
        )
    transitions = each_tick_once(sorted(transitions, key=lambda tr: tr.stamp))
    _check_steps(rec, transitions)
    finder, chunks, images = TickFinder(rec), _chunks(rec), Images(rec, camera)
    states, statuses = rec.stream(m.STATE), rec.stream(m.CHUNK_STATUS)
    out, at, last_t = [], 0, -np.inf
    for run in _episodes_of(transitions):
        rows: list[dict[str, Any]] = []
        frame_images: list[int] = []
        prev_age = None
        for tr in run:
            i, j, published = frame_ticks(finder, tr, at, first=not rows)
            state, t = states.msgs[i], float(states.stamps[i])
            age = target_age(rec, t) if prev_age is None else prev_age
            img, img_age = images.at(t)
            frame_images.append(img)
            lo, hi = statuses.index_at(last_t), statuses.index_at(t)
            obs = np.asarray(tr.obs, dtype=np.float32)
            rows.append(
                {
                    "observation.state": np.concatenate([state.q, state.ee_pos, obs[6:12], [age]]),
                    "observation.learner": obs,
                    "action": played_step(rec, states.msgs[j], chunks),
                    "next.reward": [tr.reward],
                    "next.done": [tr.terminated or tr.truncated],
                    "next.success": [tr.success],
                    "segment.index": [tr.segment],
                    "segment.end": m.label(tr, "end"),  # learner.segments.SegmentEnd's names
                    "retreat.statistic": [tr.statistic if tr.HasField("statistic") else 0.0],
                    "retreat.evaluated": [tr.HasField("statistic")],
                    "plan.dropped": [sum(s.dropped for s in statuses.msgs[lo + 1 : hi + 1])],
                    "observation.camera_age": [img_age],
                    "robot.tick": [state.tick],
                    "robot.stamp_ns": [int(t * 1e9)],  # as the MCAP publish time (recording.publish_time)
                    "robot.published": [published],
                }
            )
            at, last_t, prev_age = j, t, tr.target_age
        out.append(Episode(rec.path, run[0].episode, _stack(rows), images, np.asarray(frame_images)))
    return out


DTYPES = {
    "next.done": np.bool_,
    "next.success": np.bool_,
    "retreat.evaluated": np.bool_,
    "segment.index": np.int64,
    "plan.dropped": np.int64,
    "robot.tick": np.int64,
    "robot.stamp_ns": np.int64,
    "robot.published": np.bool_,
}


def _stack(rows: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """Rows of values to columns of the features' dtypes (float32 unless ``DTYPES`` says otherwise)."""
    return {
        key: np.asarray(
            [row[key] for row in rows], dtype=object if key == "segment.end" else DTYPES.get(key, np.float32)
        )
        for key in rows[0]
    }


# -- the dataset --------------------------------------------------------------------------------------------
def features(
    n_joints: int, image_shape: tuple[int, int, int] | None, learner_names: Sequence[str]
) -> dict[str, dict]:
    """LeRobot's feature spec of the columns ``episodes`` makes."""

    def vector(names: Sequence[str], dtype: str = "float32") -> dict:
        return {"dtype": dtype, "shape": (len(names),), "names": list(names)}

    state_names = [f"joint_{i + 1}" for i in range(n_joints)]
    state_names += [f"ee_{a}" for a in "xyz"] + [f"target_{a}" for a in "xyz"]
    state_names += [f"target_v{a}" for a in "xyz"] + ["target_age_s"]
    spec = {
        "observation.state": vector(state_names),
        "observation.learner": vector(learner_names),
        "action": vector([f"d{a}" for a in "xyz"]),
        "next.reward": vector(["reward"]),
        "next.done": vector(["done"], "bool"),
        "next.success": vector(["success"], "bool"),
        "segment.index": vector(["segment"], "int64"),
        "segment.end": {"dtype": "string", "shape": (1,), "names": None},
        "retreat.statistic": vector(["statistic"]),
        "retreat.evaluated": vector(["evaluated"], "bool"),
        "plan.dropped": vector(["dropped"], "int64"),
        "observation.camera_age": vector(["camera_age_s"]),
        "robot.tick": vector(["tick"], "int64"),
        "robot.stamp_ns": vector(["stamp_ns"], "int64"),
        "robot.published": vector(["published"], "bool"),
    }
    if image_shape is not None:
        spec[CAMERA_KEY] = {"dtype": "video", "shape": image_shape, "names": ["height", "width", "channels"]}
    return spec


_TORCHVISION_OPS: Any = None  # the schemas declared below live as long as this module


def _declare_missing_torchvision_ops() -> None:
    """Let torchvision's Python part import beside a CPU-only torch build.

    PyPI's torchvision is built against CUDA torch: beside ours its C++ ops (detection's ``nms`` and
    friends, which LeRobot's dataset code never calls) fail to load, which torchvision tolerates, but it
    still registers fake kernels for ``nms`` and ``qnms`` and torch refuses those for an undeclared op.
    Declaring the two schemas (as torchvision's C++ declares them) is all it lacks; a torchvision whose
    ops load is left alone."""
    global _TORCHVISION_OPS
    try:
        importlib.import_module("torchvision")
        return
    except RuntimeError as exc:
        if "torchvision::nms" not in str(exc):
            raise
    for name in [n for n in sys.modules if n == "torchvision" or n.startswith("torchvision.")]:
        del sys.modules[name]  # the half-imported package, to import again
    import torch

    _TORCHVISION_OPS = torch.library.Library("torchvision", "FRAGMENT")
    for op in ("nms", "qnms"):
        _TORCHVISION_OPS.define(f"{op}(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
    importlib.import_module("torchvision")


def lerobot_dataset_class() -> type:
    """LeRobot's ``LeRobotDataset``; an ExportError saying how to install it when it is not."""
    try:
        _declare_missing_torchvision_ops()
        module = importlib.import_module("lerobot.datasets.lerobot_dataset")
    except ImportError as exc:
        raise ExportError(
            f"LeRobot is not installed ({exc}); install it as the README says (scripts/setup.sh does)"
        ) from None
    return module.LeRobotDataset


def _image_shape(eps: list[Episode]) -> tuple[int, int, int] | None:
    """The shape of the first frame's image that has one; None when no frame has an image."""
    for ep in eps:
        seen = ep.images[ep.images >= 0]
        if seen.size:
            return ep.camera.decode(int(seen[0])).shape
    return None


class FrameImages:
    """Each frame's image, decoded once per image (a camera slower than the ticks repeats it)."""

    def __init__(self, shape: tuple[int, int, int]) -> None:
        self.shape = shape
        self.blank = np.zeros(shape, np.uint8)  # before the first image (``camera_age`` says -1)
        self._last: tuple[Images | None, int, np.ndarray] = (None, -1, self.blank)

    def of(self, ep: Episode, k: int) -> np.ndarray:
        i = int(ep.images[k])
        if i < 0:
            return self.blank
        if self._last[:2] != (ep.camera, i):
            image = ep.camera.decode(i)
            if image.shape != self.shape:
                raise ExportError(
                    f"{ep.recording}: channel {ep.camera.stream.key}: an image of {image.shape} after "
                    f"{self.shape}: one video needs one size"
                )
            self._last = (ep.camera, i, image)
        return self._last[2]


def _scalar_columns(buffer: dict[str, Any], spec: dict[str, dict]) -> None:
    """One-value numeric columns as scalars in LeRobot's episode buffer.

    LeRobot 0.4 stacks a ``shape (1,)`` column to (N, 1), which ``datasets`` cannot encode as the scalar
    it declares under numpy >= 2.4 ("only 0-dimensional arrays can be converted"); LeRobot's later
    releases make the same change in ``save_episode`` (its issue 3343). Statistics keep their (1,)."""
    for key, ft in spec.items():
        values = buffer.get(key)
        if (
            ft["shape"] == (1,)
            and ft["dtype"] not in ("string", "image", "video")
            and isinstance(values, list)
        ):
            if values and np.ndim(values[0]) == 1:
                buffer[key] = list(np.asarray(values).reshape(-1))


def write(
    eps: list[Episode],
    out: Path,
    fps: int,
    robot: str,
    repo_id: str,
    vcodec: str = "libsvtav1",
    learner_names: Sequence[str] | None = None,
) -> None:
    """Write ``eps`` with LeRobot's writer, the video encoded while the frames go in (its streaming
    encoder, with room for a whole episode so it never drops a frame)."""
    dataset_class = lerobot_dataset_class()
    importlib.import_module("datasets").disable_progress_bars()  # one bar an episode, in a log
    shape = _image_shape(eps)
    n_joints = eps[0].columns["observation.state"].shape[1] - 10
    dataset = dataset_class.create(
        repo_id,
        fps,
        features(n_joints, shape, learner_names or _numbered(eps[0].columns["observation.learner"])),
        root=out,
        robot_type=robot,
        use_videos=True,
        vcodec=vcodec,
        streaming_encoding=shape is not None,
        encoder_queue_maxsize=max(len(ep) for ep in eps) + 1,
    )
    images = FrameImages(shape) if shape is not None else None
    try:
        for ep in eps:
            for k in range(len(ep)):
                frame = {key: col[k] for key, col in ep.columns.items()}
                frame["task"] = TASK_TEXT
                if images is not None:
                    frame[CAMERA_KEY] = images.of(ep, k)
                dataset.add_frame(frame)
            _scalar_columns(dataset.episode_buffer, dataset.features)
            dataset.save_episode()
    finally:
        dataset.finalize()


def _numbered(column: np.ndarray) -> list[str]:
    return [f"obs_{i}" for i in range(column.shape[1])]


def export(
    recordings: Sequence[str | Path],
    out: str | Path,
    repo_id: str | None = None,
    camera: str = "auto",
    vcodec: str = "libsvtav1",
    fps: int | None = None,
    learner_names: Sequence[str] | None = None,
) -> dict[str, Any]:
    """Export ``recordings`` (in order) into a new LeRobotDataset at ``out``; what was written.

    ``learner_names``: the names of the learner's observation values (the task's, ``tasks.reach``
    ``OBSERVATION_NAMES``, which the caller knows: monitor/ sits below the tasks); default obs_0, ..."""
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise ExportError(f"{out}: exists and is not empty; give a new folder")
    if out.exists():
        out.rmdir()  # LeRobot makes the folder itself
    eps: list[Episode] = []
    rates, robots = set(), set()
    for path in recordings:
        rec = load(path)
        rates.add(fps or control_rate(rec))
        robots.add(rec.robot)
        eps += episodes(rec, camera)
    if len(rates) != 1:
        raise ExportError(f"the recordings' control rates differ ({sorted(rates)} Hz): one dataset, one fps")
    rate, robot = rates.pop(), sorted(robots)[0]
    try:
        write(eps, out, rate, robot, repo_id or f"adaptiveh/{robot}", vcodec, learner_names)
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)  # the folder is ours (new or empty): no half dataset
        raise
    return {
        "episodes": len(eps),
        "frames": sum(len(ep) for ep in eps),
        "fps": rate,
        "camera": sorted({ep.camera.source for ep in eps}),
        "out": str(out),
    }
