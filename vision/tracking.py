"""Constant-velocity Kalman filter on the target's base-frame position, with a lost flag.

State [p, v] (6), white-acceleration process noise, position measurements. It estimates velocity for
the learner, rejects implausible jumps with a Mahalanobis gate (a wrong blob for a frame), restarts the
track when consecutive rejected detections agree (the target really moved: ``reacquire_after``), and
declares the target lost after ``lost_after_s`` without an accepted measurement: a lost target is
reported, never extrapolated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vision.config import TrackingConfig


@dataclass(frozen=True)
class TrackEstimate:
    """What the tracker says at ``stamp``: ``valid`` is False when there is no track or it is lost."""

    stamp: float
    position: np.ndarray
    velocity: np.ndarray
    covariance: np.ndarray  # 3x3 position covariance
    valid: bool
    status: str  # tracking | coasting | lost | none
    last_measurement_stamp: float


class KalmanTracker:
    """Feed it ``update(stamp, measurement_or_None)`` once per frame, in capture-time order."""

    def __init__(self, config: TrackingConfig) -> None:
        self.config = config
        self.x = np.zeros(6)
        self.P = np.eye(6)
        self.stamp: float | None = None
        self.last_measurement: float | None = None
        self.initialised = False
        self.rejected = 0
        self.reacquired = 0
        self._outliers: list[tuple[float, np.ndarray]] = []  # consecutive gated-out detections
        self.last_fused = np.zeros(3)

    def reset(self) -> None:
        self.initialised = False
        self.stamp = None
        self.last_measurement = None

    def _predict(self, stamp: float) -> None:
        assert self.stamp is not None
        dt = stamp - self.stamp
        if dt <= 0:
            return
        dt = min(dt, self.config.max_dt)
        F = np.eye(6)
        F[:3, 3:] = dt * np.eye(3)
        q = self.config.accel_sigma**2
        # Discrete white-noise-acceleration model, per axis.
        Q1 = q * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
        Q = np.kron(Q1, np.eye(3))
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + Q
        self.stamp = stamp

    def _start(self, stamp: float, z: np.ndarray) -> None:
        r2 = self.config.measurement_sigma**2
        self.x = np.concatenate([z, np.zeros(3)])
        # Unknown velocity: a prior wide enough for any target speed we care about (~1 m/s).
        self.P = np.diag([r2] * 3 + [1.0] * 3)
        self.stamp = stamp
        self.last_measurement = stamp
        self.last_fused = z.copy()
        self.initialised = True
        self._outliers = []

    def update(self, stamp: float, measurement: np.ndarray | None) -> TrackEstimate:
        """Advance to ``stamp`` and fuse ``measurement`` (base-frame position) when there is one."""
        cfg = self.config
        if self.initialised and self.stamp is not None and stamp < self.stamp:
            measurement = None  # an out-of-order frame: never rewind the filter
            stamp = self.stamp
        if self.initialised and self.last_measurement is not None:
            if stamp - self.last_measurement > cfg.lost_after_s:
                self.initialised = False  # lost: the next detection starts a fresh track
        if measurement is not None:
            z = np.asarray(measurement, float)
            if not self.initialised:
                self._start(stamp, z)
            else:
                self._predict(stamp)
                H = np.hstack([np.eye(3), np.zeros((3, 3))])
                R = cfg.measurement_sigma**2 * np.eye(3)
                innovation = z - H @ self.x
                S = H @ self.P @ H.T + R
                d2 = float(innovation @ np.linalg.solve(S, innovation))
                if d2 <= cfg.gate_sigma**2:
                    K = self.P @ H.T @ np.linalg.inv(S)
                    self.x = self.x + K @ innovation
                    self.P = (np.eye(6) - K @ H) @ self.P
                    self.P = 0.5 * (self.P + self.P.T)
                    self.last_measurement = stamp
                    self.last_fused = self.x[:3].copy()
                    self._outliers = []
                else:
                    self.rejected += 1
                    if self._moved(stamp, z):
                        self.reacquired += 1
                        self._start(stamp, z)
        return self.estimate(stamp)

    def _moved(self, stamp: float, z: np.ndarray) -> bool:
        """Record a gated-out detection; True once the last ``reacquire_after`` agree with each other."""
        cfg = self.config
        if self._outliers:
            t_prev, z_prev = self._outliers[-1]
            reach = cfg.max_speed * max(stamp - t_prev, 0.0) + 2 * cfg.gate_sigma * cfg.measurement_sigma
            if np.linalg.norm(z - z_prev) > reach:
                self._outliers = []
        self._outliers.append((stamp, z))
        return len(self._outliers) >= cfg.reacquire_after

    def estimate(self, stamp: float) -> TrackEstimate:
        """The state at ``stamp`` without fusing anything (coasting), or a lost/none report.

        A lost report carries the last fused position (where it was last seen) and zero velocity.
        """
        last = self.last_measurement if self.last_measurement is not None else 0.0
        if self.initialised and self.last_measurement is not None:
            if stamp - self.last_measurement > self.config.lost_after_s:
                self.initialised = False
        if not self.initialised or self.last_measurement is None:
            status = "lost" if self.last_measurement is not None else "none"
            return TrackEstimate(
                stamp, self.last_fused.copy(), np.zeros(3), np.full((3, 3), 0.0), False, status, last
            )
        age = stamp - self.last_measurement
        if self.stamp is not None and stamp > self.stamp:
            self._predict(stamp)
        status = "tracking" if age == 0 else "coasting"
        return TrackEstimate(
            stamp, self.x[:3].copy(), self.x[3:].copy(), self.P[:3, :3].copy(), True, status, last
        )
