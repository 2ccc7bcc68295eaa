"""Tracking through the whole pipeline on rendered frames, and the Kalman tracker alone."""

from __future__ import annotations

import dataclasses

import numpy as np
import pybullet as pb
import pytest

from vision.cameras.sim import camera_from_config
from vision.config import TrackingConfig
from vision.pipeline import VisionPipeline
from vision.tracking import KalmanTracker

FPS = 15.0  # the configured sim camera rate (vision.rate_hz in configs/sim.yaml)
CENTRE = np.array([0.5, 0.0, 0.28])
AMPLITUDE = np.array([0.13, 0.22, 0.10])
OMEGA = np.array([0.9, 0.6, 1.1])


def lissajous(t: float, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """A smooth path through the workspace; ``scale`` sets the speed range (position, velocity)."""
    a = AMPLITUDE * scale
    return CENTRE + a * np.sin(OMEGA * t), a * OMEGA * np.cos(OMEGA * t)


def place(scene, p: np.ndarray) -> None:
    pb.resetBasePositionAndOrientation(
        scene.target_id, list(p), [0, 0, 0, 1], physicsClientId=scene.client_id
    )


def run(scene, config, frames: int, scale: float, hide=lambda t: False):
    """Render ``frames`` frames at 15 Hz of scene time; yields (t, truth pos, truth vel, output)."""
    cam = camera_from_config(scene.client_id, config)
    pipeline = VisionPipeline(config)
    occluder = None
    for i in range(frames):
        t = i / FPS
        p, v = lissajous(t, scale)
        place(scene, p)
        if hide(t) and occluder is None:
            occluder = _occluder(scene, config, p)
        elif not hide(t) and occluder is not None:
            pb.removeBody(occluder, physicsClientId=scene.client_id)
            occluder = None
        elif occluder is not None:
            _move_occluder(scene, config, occluder, p)
        out = pipeline.process(dataclasses.replace(cam.capture(), stamp=t))
        yield t, p, v, out


def _occluder_pose(config, p):
    eye = np.asarray(config.sim_pose().position)
    return (eye + 0.6 * (p - eye)).tolist()


def _occluder(scene, config, p) -> int:
    """A grey plate between the camera and the target (a person's hand, another object)."""
    vis = pb.createVisualShape(
        pb.GEOM_BOX,
        halfExtents=[0.06, 0.06, 0.06],
        rgbaColor=[0.5, 0.5, 0.5, 1],
        physicsClientId=scene.client_id,
    )
    return pb.createMultiBody(0, -1, vis, _occluder_pose(config, p), physicsClientId=scene.client_id)


def _move_occluder(scene, config, body, p) -> None:
    pb.resetBasePositionAndOrientation(
        body, _occluder_pose(config, p), [0, 0, 0, 1], physicsClientId=scene.client_id
    )


@pytest.mark.parametrize(
    "scale, speeds",
    [(1.0, (0.07, 0.18)), (0.33, (0.02, 0.06))],
    ids=["fast-preset-speeds", "slow-preset-speeds"],
)
def test_velocity_error_under_20_percent(scene, config, scale, speeds):
    """NS Reach target speeds (slow 0.02-0.06, fast 0.08-0.20 m/s): RMS velocity error < 20 % of RMS speed.

    Measured after a 1 s settling period, on 320x240 frames at 15 Hz with depth noise.
    """
    truth, estimate = [], []
    for t, _p, v, out in run(scene, config, 75, scale):
        assert out.estimate.valid or t < 0.1
        if t >= 1.0:
            truth.append(v)
            estimate.append(out.estimate.velocity)
    truth, estimate = np.array(truth), np.array(estimate)
    speed = np.linalg.norm(truth, axis=1)
    assert speeds[0] <= speed.min() and speed.max() <= speeds[1]  # the speeds the test claims
    rms_error = np.sqrt(np.mean(np.sum((estimate - truth) ** 2, axis=1))) / np.sqrt(np.mean(speed**2))
    median_error = np.median(np.linalg.norm(estimate - truth, axis=1) / speed)
    print(f"velocity error: rms {rms_error:.1%}, median {median_error:.1%}")
    assert rms_error < 0.20 and median_error < 0.20


def test_occlusion_is_reported_lost_then_recovered(scene, vision_config):
    """Hidden for 1 s: valid until at most lost_after_s after the last sighting, then lost (and never
    a guessed position); tracked again within two frames of reappearing."""
    config = vision_config(tracking=TrackingConfig(lost_after_s=0.25))
    t_hide, t_show = 2.0, 3.0
    hidden = lambda t: t_hide <= t < t_show  # noqa: E731
    first_lost, first_back, last_seen = None, None, None
    for t, p, _v, out in run(scene, config, 60, 0.6, hide=hidden):
        est = out.estimate
        if t < t_hide:
            assert est.valid and out.detection is not None
            last_seen = t
        elif t < t_show:
            assert out.detection is None, f"target detected through the occluder at t={t:.2f}"
            if est.valid:
                assert t - last_seen <= 0.25 + 1e-9 and est.status == "coasting"
            else:
                first_lost = first_lost if first_lost is not None else t
                assert est.status == "lost" and np.all(est.velocity == 0)
        elif est.valid and first_back is None:
            first_back = t
            assert est.status == "tracking"
        if first_back is not None and t >= first_back + 0.5:
            assert np.linalg.norm(est.position - p) < 0.02
    assert first_lost is not None and first_lost - last_seen <= 0.25 + 1 / FPS
    assert first_back is not None and first_back - t_show <= 2 / FPS


def test_tracker_gates_jumps_and_ignores_out_of_order():
    tracker = KalmanTracker(TrackingConfig(measurement_sigma=0.004, gate_sigma=6.0, lost_after_s=0.3))
    for i in range(10):
        est = tracker.update(i * 0.033, np.array([0.5 + 0.1 * i * 0.033, 0.0, 0.3]))
    assert est.valid and np.allclose(est.velocity, [0.1, 0, 0], atol=0.02)
    jumped = tracker.update(0.33, np.array([0.9, 0.4, 0.3]))  # 0.5 m in one frame: a wrong blob
    assert tracker.rejected == 1 and np.linalg.norm(jumped.position - [0.533, 0, 0.3]) < 0.02
    back = tracker.update(0.2, np.array([0.0, 0.0, 0.0]))  # older than the filter: not fused
    assert back.stamp == pytest.approx(0.33) and np.linalg.norm(back.position - [0.533, 0, 0.3]) < 0.02


def test_tracker_lost_reports_last_sighting_then_restarts():
    tracker = KalmanTracker(TrackingConfig(lost_after_s=0.2))
    assert tracker.update(0.0, None).status == "none"
    for i in range(5):
        tracker.update(i * 0.05, np.array([0.4 + 0.01 * i, 0.1, 0.2]))
    coasting = tracker.update(0.35, None)
    assert coasting.valid and coasting.status == "coasting"
    lost = tracker.update(0.45, None)
    assert not lost.valid and lost.status == "lost"
    assert np.allclose(lost.position, [0.44, 0.1, 0.2], atol=0.005) and np.all(lost.velocity == 0)
    again = tracker.update(1.0, np.array([0.6, -0.1, 0.3]))
    assert again.valid and np.allclose(again.position, [0.6, -0.1, 0.3]) and np.all(again.velocity == 0)


def test_tracker_reacquires_a_target_that_really_moved():
    """One wrong blob is rejected; two agreeing detections at a new place restart the track there
    (a sim reset, an object picked up and put down) instead of coasting until lost; two disagreeing
    outliers do not."""
    tracker = KalmanTracker(TrackingConfig(lost_after_s=0.3, reacquire_after=2))
    for i in range(10):
        tracker.update(i * 0.1, np.array([0.5, 0.0, 0.3]))
    first = tracker.update(1.0, np.array([0.3, 0.2, 0.2]))
    assert first.status == "coasting" and np.linalg.norm(first.position - [0.5, 0, 0.3]) < 0.01
    second = tracker.update(1.1, np.array([0.301, 0.2, 0.2]))
    assert tracker.reacquired == 1 and second.status == "tracking"
    assert np.allclose(second.position, [0.301, 0.2, 0.2]) and np.all(second.velocity == 0)
    for i in range(5):
        tracker.update(1.2 + i * 0.1, np.array([0.3, 0.2, 0.2]))
    tracker.update(1.7, np.array([0.8, -0.3, 0.5]))  # wrong blob
    est = tracker.update(1.8, np.array([0.3, 0.6, 0.1]))  # another, elsewhere: no agreement
    assert tracker.reacquired == 1 and np.linalg.norm(est.position - [0.3, 0.2, 0.2]) < 0.01
    with pytest.raises(ValueError, match="reacquire_after"):
        TrackingConfig(reacquire_after=0)
