"""Vision benchmark: detection + deprojection speed, sim render speed, end-to-end latency over Zenoh.

    python bench/vision_bench.py [--config configs/sim.yaml] [--seconds 10] [--out results/vision_bench.json]

1. Detection + deprojection (+ base-frame transform) at 640x480 on one core (CPU affinity 1 core,
   OpenCV single-threaded), on rendered frames of the Panda scene; also the full per-frame pipeline
   (validation, detection, deprojection, tracking).
2. Sim render side by side (MuJoCo's renderer on EGL, PyBullet's TinyRenderer, PyBullet's EGL plugin;
   with depth conversion and noise) at the configured size and at 640x480, of the full scene (Panda,
   table, target); and render + detection + deprojection at 640x480.
3. End to end: this process renders and publishes ``camera/frame`` at the configured rate
   (``vision.camera: frames``); ``adaptiveh vision`` runs in another process; this process receives
   ``target``. Latency from the frame's capture stamp (taken before rendering, like a camera's
   exposure stamp) to receipt, and from publication to receipt (render time excluded).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from unittest import mock

import cv2
import numpy as np
import pybullet as pb
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # free ports and unique names: the tests' helper

from loopback import free_port, unique_name  # noqa: E402

from bus import messages as m  # noqa: E402
from bus.transport import Bus, ZenohConfig, open_session  # noqa: E402
from deploy.config import compose_stack_yaml, load_stack_config  # noqa: E402
from deploy.vision_node import SimFramePublisher  # noqa: E402
from sim.panda_scene import PandaScene  # noqa: E402
from vision.camera_model import Intrinsics  # noqa: E402
from vision.cameras.sim import SimRGBDCamera  # noqa: E402
from vision.config import VisionConfig  # noqa: E402
from vision.pipeline import VisionPipeline  # noqa: E402


def _rate(fn, seconds: float = 3.0, min_iters: int = 20) -> float:
    n, t0 = 0, time.perf_counter()
    while n < min_iters or time.perf_counter() - t0 < seconds:
        fn(n)
        n += 1
    return n / (time.perf_counter() - t0)


def bench_detection(vision, scene: PandaScene) -> dict:
    k = vision.intrinsics.scaled(640, 480)
    camera = SimRGBDCamera(scene.client_id, k, vision.sim_pose(), vision.sim)
    rng = np.random.default_rng(0)
    lo, hi = (np.asarray(b) for b in scene.motion.box)
    frames = []
    for _ in range(20):
        p = rng.uniform(lo, hi).tolist()
        pb.resetBasePositionAndOrientation(scene.target_id, p, [0, 0, 0, 1], physicsClientId=scene.client_id)
        frames.append(camera.capture())
    pipeline = VisionPipeline(vision)
    located = _rate(lambda i: pipeline.locate(frames[i % len(frames)]))
    stamp0 = time.time()

    def full(i: int) -> None:
        f = frames[i % len(frames)]
        pipeline.process(type(f)(f.rgb, f.depth, f.intrinsics, stamp0 + i / 30.0, i))

    return {
        "size": "640x480",
        "detect_deproject_fps": round(located, 1),
        "full_pipeline_fps": round(_rate(full), 1),
    }


def _camera(scene: PandaScene, vision: VisionConfig, k: Intrinsics, renderer: str) -> SimRGBDCamera:
    camera = SimRGBDCamera(
        scene.client_id, k, vision.sim_pose(), vision.sim.model_copy(update={"renderer": renderer})
    )
    if camera.renderer_name != renderer:  # it fell back (and said why): measuring it would mislabel it
        raise RuntimeError(f"the {renderer} renderer is not available here")
    return camera


def _pybullet_egl_fps(vision: VisionConfig, k: Intrinsics) -> float:
    """PyBullet's own EGL renderer plugin (OpenGL through Mesa's llvmpipe here), the other candidate.

    The plugin draws only bodies created after it is loaded, so it is loaded as the scene connects.
    """
    plugin = importlib.util.find_spec("eglRenderer")
    if plugin is None or plugin.origin is None:
        raise RuntimeError("pybullet has no eglRenderer plugin")
    connect = pb.connect

    def connect_with_egl(*args: object, **kwargs: object) -> int:
        cid = connect(*args, **kwargs)
        pb.loadPlugin(plugin.origin, "_eglRendererPlugin", physicsClientId=cid)
        return cid

    with mock.patch.object(pb, "connect", connect_with_egl):
        scene = PandaScene(motion="slow", seed=0)
    try:
        camera = _camera(scene, vision, k, "tiny")  # the plugin answers getCameraImage itself
        if not (camera.capture().depth > 0).any():
            raise RuntimeError("pybullet's EGL plugin rendered nothing")
        return _rate(lambda i: (scene.step(1), camera.capture()), seconds=4.0, min_iters=10)
    finally:
        scene.close()


def bench_render(vision: VisionConfig, scene: PandaScene) -> dict:
    """Each renderer side by side on the same scene in the same run (render, depth conversion, noise),
    at the configured size and at 640x480; then the whole camera path a frame takes at 640x480 with the
    configured renderer: render, detection and deprojection."""
    sizes = {"configured": vision.intrinsics, "640x480": vision.intrinsics.scaled(640, 480)}
    out: dict = {}
    for renderer in ("mujoco", "tiny"):
        out[renderer] = {}
        for label, k in sizes.items():
            camera = _camera(scene, vision, k, renderer)
            fps = _rate(lambda i, c=camera: (scene.step(1), c.capture()), seconds=4.0, min_iters=10)
            out[renderer][label] = {"size": f"{k.width}x{k.height}", "fps": round(fps, 1)}
            camera.close()
    k = sizes["640x480"]
    out["pybullet_egl"] = {"640x480": {"size": "640x480", "fps": round(_pybullet_egl_fps(vision, k), 1)}}
    camera = _camera(scene, vision, k, vision.sim.renderer)
    pipeline = VisionPipeline(vision.model_copy(update={"intrinsics": k}))
    fps = _rate(lambda i: (scene.step(1), pipeline.locate(camera.capture())), seconds=4.0, min_iters=10)
    out["render_detect_deproject_640x480"] = {"renderer": vision.sim.renderer, "fps": round(fps, 1)}
    camera.close()
    return out


def bench_tracking(vision, seconds: float = 10.0) -> dict:
    """Tracking the scene's own target motion presets at the configured size and rate.

    The presets turn the heading by a random walk (rough at short time scales), so the truth is the
    target's mean velocity over each frame interval. Reported, not asserted (the tests assert on
    smooth paths at the same speeds).
    """
    out = {}
    for preset in ("slow", "fast"):
        scene = PandaScene(motion=preset, seed=7)
        camera = SimRGBDCamera(scene.client_id, vision.intrinsics, vision.sim_pose(), vision.sim)
        pipeline = VisionPipeline(vision)
        n = scene.steps_for(1.0 / vision.rate_hz)
        pos_err, v_true, v_est = [], [], []
        for _ in range(round(seconds * vision.rate_hz)):
            p0 = scene.target_pose()[0]
            scene.step(n)
            p1 = scene.target_pose()[0]
            f = camera.capture()
            est = pipeline.process(type(f)(f.rgb, f.depth, f.intrinsics, scene.time, f.seq)).estimate
            if scene.time > 1.0 and est.valid:
                pos_err.append(np.linalg.norm(est.position - p1))
                v_true.append((p1 - p0) / (n * scene.time_step))
                v_est.append(est.velocity)
        scene.close()
        vt, ve = np.array(v_true), np.array(v_est)
        speed_rms = np.sqrt(np.mean(np.sum(vt**2, axis=1)))
        rms = np.sqrt(np.mean(np.sum((ve - vt) ** 2, axis=1))) / speed_rms
        jump = np.sqrt(np.mean(np.sum(np.diff(vt, axis=0) ** 2, axis=1))) / speed_rms
        out[preset] = {
            "frames": len(pos_err),
            "mean_speed_m_s": round(float(np.mean(np.linalg.norm(vt, axis=1))), 3),
            "position_error_mm": {
                "median": round(1000 * float(np.median(pos_err)), 1),
                "p95": round(1000 * float(np.percentile(pos_err, 95)), 1),
            },
            "velocity_rms_error_rel": round(float(rms), 3),
            # How much the true velocity itself changes from one frame to the next (relative RMS):
            # a causal estimator lags by about a frame, so this is roughly its floor on this motion.
            "truth_frame_to_frame_change_rel": round(float(jump), 3),
        }
    return out


def bench_latency(config_path: Path, seconds: float) -> dict:
    raw = compose_stack_yaml(config_path)
    port = free_port()
    raw["name"] = unique_name("bench")
    raw["zenoh"] = {"mode": "peer", "listen": [f"tcp/127.0.0.1:{port}"]}
    raw["vision"]["camera"] = "frames"  # this process renders and publishes; vision only processes
    tmp = Path(tempfile.mkdtemp(prefix="vision_bench_")) / "config.yaml"
    tmp.write_text(yaml.safe_dump(raw))
    vision = VisionConfig.model_validate(raw["vision"])
    proc = subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "vision", "--config", str(tmp), "--log-level", "WARNING"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    bus = Bus(open_session(ZenohConfig(connect=(f"tcp/127.0.0.1:{port}",))), raw["name"])
    received: dict[float, float] = {}
    alive = threading.Event()
    lock = threading.Lock()

    def on_target(t: m.Target) -> None:
        now = time.time()
        with lock:
            received.setdefault(round(t.frame_stamp, 6), now)

    bus.subscribe(m.TARGET, on_target)
    bus.watch_alive(lambda name, up: alive.set() if name == "vision" and up else None)
    scene = PandaScene(motion="slow", seed=1)
    published: dict[float, float] = {}
    valid = 0
    try:
        if not alive.wait(60):
            raise RuntimeError(f"vision process did not start:\n{proc.communicate(timeout=5)[0]}")
        publisher = SimFramePublisher(bus, scene.client_id, vision)
        capture = publisher.camera.capture

        def stamped_capture():
            frame = capture()
            stamped_capture.last = frame.stamp
            return frame

        publisher.camera.capture = stamped_capture  # type: ignore[method-assign]
        period = 1.0 / vision.rate_hz
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            t0 = time.monotonic()
            scene.step(scene.steps_for(period))
            publisher()
            published[round(stamped_capture.last, 6)] = time.time()
            time.sleep(max(0.0, period - (time.monotonic() - t0)))
        time.sleep(1.0)
        valid = len(received)
    finally:
        scene.close()
        bus.close()
        proc.terminate()
        proc.wait(timeout=10)
    with lock:
        pairs = [(s, published[s], received[s]) for s in published if s in received]
    capture_to_target = np.array([r - s for s, _, r in pairs]) * 1000
    publish_to_target = np.array([r - p for _, p, r in pairs]) * 1000
    return {
        "frames_published": len(published),
        "targets_received": len(pairs),
        "target_messages_distinct": valid,  # includes lost reports sent while no frame came
        "size": f"{vision.intrinsics.width}x{vision.intrinsics.height}",
        "rate_hz": vision.rate_hz,
        "capture_to_target_ms": {
            "p50": round(float(np.percentile(capture_to_target, 50)), 1),
            "p99": round(float(np.percentile(capture_to_target, 99)), 1),
        },
        "publish_to_target_ms": {
            "p50": round(float(np.percentile(publish_to_target, 50)), 1),
            "p99": round(float(np.percentile(publish_to_target, 99)), 1),
        },
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(ROOT / "configs" / "sim.yaml"))
    ap.add_argument("--seconds", type=float, default=10.0, help="end-to-end run length")
    ap.add_argument("--out", default=str(ROOT / "results" / "vision_bench.json"))
    args = ap.parse_args()
    vision = load_stack_config(args.config).vision
    scene = PandaScene(motion="slow", seed=0)
    original = os.sched_getaffinity(0)
    cores_available = len(original)
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core for the in-process parts
    cv2.setNumThreads(1)
    try:
        detection = bench_detection(vision, scene)
        render = bench_render(vision, scene)
        tracking = bench_tracking(vision)
    finally:
        scene.close()
        os.sched_setaffinity(0, original)
    latency = bench_latency(Path(args.config), args.seconds)
    result = {
        "machine": {
            "cpu": platform.processor() or platform.machine(),
            "cores_available": cores_available,
            "load_avg_1min": round(os.getloadavg()[0], 2),
            "python": platform.python_version(),
            "opencv": cv2.__version__,
        },
        "note": "in-process parts pinned to one core; the machine is shared, so treat rates as lower bounds",
        "detection": detection,
        "sim_render": render,
        "tracking_scene_presets": tracking,
        "end_to_end": latency,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
