"""The sim camera as its own device: renders a kinematic replica of the simulated world.

PyBullet holds the GIL for the whole of ``getCameraImage`` (50-180 ms at 320x240 here), so rendering
inside the physics owner stalls its control loop, and a stalled loop broke learning over the stack. A
real RealSense runs beside the arm, not inside its controller; this camera does the same: it keeps its
own PyBullet client with the same scene, poses it from the physics owner's published world (joint
positions and the target's position: ``set_joints``, ``set_target``), and renders at its own rate in
whatever process owns it (the vision node). A frame's ``stamp`` is when that world was observed, not
when it was rendered, so latency and tracking are measured from the moment the picture shows.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from vision.cameras.protocol import CameraError, Frame
from vision.cameras.sim import camera_from_config
from vision.config import Intrinsics, VisionConfig


@dataclass(frozen=True)
class WorldSnapshot:
    q: np.ndarray  # 7 arm joint positions
    target_position: np.ndarray  # 3, base frame
    stamp: float  # wall clock when observed


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

    def __init__(self, config: VisionConfig, scene: ReplicaScene, stale_after_s: float = 0.5) -> None:
        """``scene``: the world to pose and render, handed in (``tasks.sim_world.replica_scene``); the
        camera owns it from here and closes it."""
        self.scene = scene
        self._camera = camera_from_config(self.scene.client_id, config)
        self.period = 1.0 / config.rate_hz
        self.stale_after_s = float(stale_after_s)
        self._lock = threading.Lock()
        self._q: np.ndarray | None = None
        self._target: tuple[np.ndarray, float] | None = None
        self._next = time.monotonic()

    @property
    def intrinsics(self) -> Intrinsics:
        return self._camera.intrinsics

    def set_joints(self, q: np.ndarray) -> None:
        q = np.asarray(q, float)
        if q.shape != (7,) or not np.isfinite(q).all():
            raise ValueError(f"joint positions must be 7 finite values, got {q!r}")
        with self._lock:
            self._q = q

    def set_target(self, position: np.ndarray, stamp: float) -> None:
        p = np.asarray(position, float)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f"target position must be 3 finite values, got {p!r}")
        with self._lock:
            self._target = (p, float(stamp))

    def world(self) -> WorldSnapshot:
        """The newest complete world, or ``CameraError`` saying what is missing."""
        with self._lock:
            q, target = self._q, self._target
        if q is None or target is None:
            missing = [n for n, v in (("joint state", q), ("target pose", target)) if v is None]
            raise CameraError(f"sim camera: no {' or '.join(missing)} from the physics owner yet")
        age = time.time() - target[1]
        if age > self.stale_after_s:
            raise CameraError(f"sim camera: the newest world is {age:.1f} s old (physics owner gone?)")
        return WorldSnapshot(q=q, target_position=target[0], stamp=target[1])

    def capture(self) -> Frame:
        """Wait for the next frame time, then render the newest world."""
        delay = self._next - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        self._next = max(self._next + self.period, time.monotonic())
        world = self.world()
        self.scene.show(world.q, world.target_position)
        frame = self._camera.capture()
        return Frame(
            rgb=frame.rgb, depth=frame.depth, intrinsics=frame.intrinsics, stamp=world.stamp, seq=frame.seq
        )

    def close(self) -> None:
        self.scene.close()
