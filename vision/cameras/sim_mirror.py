"""The sim camera as its own device: renders a kinematic replica of the simulated world.

PyBullet holds the GIL for the whole of ``getCameraImage`` (50-180 ms at 320x240 here), so rendering
inside the physics owner stalls its control loop, and a stalled loop broke learning over the stack. A
real RealSense runs beside the arm, not inside its controller; this camera does the same: it keeps its
own PyBullet client with the same scene, poses it from the physics owner's published world (joint
positions and the target's position: ``set_joints``, ``set_target``), and renders at its own rate in
whatever process owns it (the vision node).

The physics owner publishes its world at the control rate (20 Hz), a camera exposes at its own instant
(30 Hz). The replica is posed at the render's instant, moved on from the newest published world by its
published velocities (joints' ``dq``, the target's velocity), at most ``max_extrapolation_s``: a frame's
``stamp`` is the instant its picture shows, as a real camera's exposure time is, so a frame is not a
control period old before it is drawn.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from vision.camera_model import Intrinsics
from vision.cameras.protocol import CameraError, Frame
from vision.cameras.sim import camera_from_config
from vision.config import VisionConfig


@dataclass(frozen=True)
class WorldSnapshot:
    q: np.ndarray  # 7 arm joint positions
    dq: np.ndarray  # 7 joint velocities
    q_stamp: float  # wall clock when the joints were measured
    target_position: np.ndarray  # 3, base frame
    target_velocity: np.ndarray  # 3, base frame
    stamp: float  # wall clock when the target was observed

    def at(self, t: float, max_extrapolation_s: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Joints and target at wall time ``t`` (moved on at their velocities) and the instant they
        show: ``t``, or ``stamp + max_extrapolation_s`` when ``t`` is further from the observation."""
        shown = min(max(t, self.stamp), self.stamp + max_extrapolation_s)
        target = self.target_position + self.target_velocity * (shown - self.stamp)
        dt_q = float(np.clip(shown - self.q_stamp, 0.0, max_extrapolation_s))
        return self.q + self.dq * dt_q, target, shown


class ReplicaScene(Protocol):
    """What the camera needs of its scene (``sim.panda_scene.PandaScene`` is one)."""

    client_id: int

    def show(self, q: np.ndarray, target_position: np.ndarray) -> None: ...

    def close(self) -> None: ...


class MirrorSimCamera:
    """A ``Camera`` over its own replica scene; feed it with ``set_joints``/``set_target`` from any thread.

    ``capture()`` paces itself to ``rate_hz``, renders the newest world and raises ``CameraError``
    while it has none, or when the newest is older than ``stale_after_s`` (the physics owner is gone):
    a camera that shows an old world as new would hide a dead peer.
    """

    def __init__(
        self,
        config: VisionConfig,
        scene: ReplicaScene,
        stale_after_s: float = 0.5,
        max_extrapolation_s: float = 0.1,
    ) -> None:
        """``scene``: the world to pose and render, handed in (``tasks.sim_world.replica_scene``); the
        camera owns it from here and closes it. ``max_extrapolation_s``: how far past an observation the
        replica is moved on (two 20 Hz control periods); a frame never shows a world further on."""
        self.scene = scene
        self._camera = camera_from_config(self.scene.client_id, config)
        self.period = 1.0 / config.rate_hz
        self.stale_after_s = float(stale_after_s)
        self.max_extrapolation_s = float(max_extrapolation_s)
        self._lock = threading.Lock()
        self._q: tuple[np.ndarray, np.ndarray, float] | None = None
        self._target: tuple[np.ndarray, np.ndarray, float] | None = None
        self._next = time.monotonic()

    @property
    def intrinsics(self) -> Intrinsics:
        return self._camera.intrinsics

    def set_joints(self, q: np.ndarray, dq: np.ndarray | None = None, stamp: float | None = None) -> None:
        """Joint positions (and velocities) measured at ``stamp`` (now when not given)."""
        q = _finite(q, 7, "joint positions")
        dq = np.zeros(7) if dq is None else _finite(dq, 7, "joint velocities")
        with self._lock:
            self._q = (q, dq, time.time() if stamp is None else float(stamp))

    def set_target(self, position: np.ndarray, stamp: float, velocity: np.ndarray | None = None) -> None:
        """The target's position (and velocity) observed at ``stamp``."""
        p = _finite(position, 3, "target position")
        v = np.zeros(3) if velocity is None else _finite(velocity, 3, "target velocity")
        with self._lock:
            self._target = (p, v, float(stamp))

    def world(self) -> WorldSnapshot:
        """The newest complete world, or ``CameraError`` saying what is missing."""
        with self._lock:
            q, target = self._q, self._target
        if q is None or target is None:
            missing = [n for n, v in (("joint state", q), ("target pose", target)) if v is None]
            raise CameraError(f"sim camera: no {' or '.join(missing)} from the physics owner yet")
        age = time.time() - target[2]
        if age > self.stale_after_s:
            raise CameraError(f"sim camera: the newest world is {age:.1f} s old (physics owner gone?)")
        (q, dq, q_stamp), (position, velocity, stamp) = q, target
        return WorldSnapshot(q, dq, q_stamp, target_position=position, target_velocity=velocity, stamp=stamp)

    def capture(self) -> Frame:
        """Wait for the next frame time, then render the world as it is at that instant."""
        delay = self._next - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        self._next = max(self._next + self.period, time.monotonic())
        q, target, shown = self.world().at(time.time(), self.max_extrapolation_s)
        self.scene.show(q, target)
        frame = self._camera.capture()
        return Frame(
            rgb=frame.rgb, depth=frame.depth, intrinsics=frame.intrinsics, stamp=shown, seq=frame.seq
        )

    def close(self) -> None:
        self.scene.close()


def _finite(values: np.ndarray, n: int, what: str) -> np.ndarray:
    a = np.asarray(values, float)
    if a.shape != (n,) or not np.isfinite(a).all():
        raise ValueError(f"{what} must be {n} finite values, got {a!r}")
    return a
