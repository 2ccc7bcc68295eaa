"""One frame in, one target estimate out: validate, detect, deproject, to base frame, track.

The same object runs in the vision process (fed by Zenoh camera frames or a RealSense) and in-process
(tests, benchmarks). A bad frame never raises: it yields an output whose ``error`` says why, and the
tracker still advances so a long run of bad frames ends in a lost report.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vision.cameras.protocol import Frame, FrameError, validate_frame
from vision.config import VisionConfig
from vision.deprojection import deproject, surface_to_centre
from vision.detection import Detection, Detector
from vision.extrinsics import apply, pose_to_matrix
from vision.tracking import KalmanTracker, TrackEstimate


@dataclass(frozen=True)
class PipelineOutput:
    """The result for one frame: the track, the raw detection and measurement, or the frame error."""

    frame_stamp: float
    estimate: TrackEstimate
    detection: Detection | None
    measurement: np.ndarray | None  # base-frame position from this frame alone
    error: str | None  # why the frame was unusable (a bad frame), else None
    reason: str  # why nothing was detected in a good frame ("" when detected)


class VisionPipeline:
    """Stateful (the tracker): feed frames in capture order."""

    def __init__(self, config: VisionConfig) -> None:
        self.config = config
        self.detector = Detector(config.detection)
        self.tracker = KalmanTracker(config.tracking)
        self.set_extrinsics(pose_to_matrix(config.extrinsics))

    def set_extrinsics(self, base_from_camera: np.ndarray) -> None:
        self.base_from_camera = np.asarray(base_from_camera, float)

    def locate(self, frame: Frame) -> tuple[Detection | None, np.ndarray | None]:
        """Detection and base-frame target centre from one (valid) frame, without tracking."""
        det = self.detector.detect(frame.rgb, frame.depth)
        if det is None:
            return None, None
        cfg = self.config.detection
        surface = deproject(frame.intrinsics, det.u, det.v, det.depth)
        centre = surface_to_centre(surface, cfg.target_shape, cfg.target_size, self.base_from_camera[:3, :3])
        return det, apply(self.base_from_camera, centre)

    def process(self, frame: Frame) -> PipelineOutput:
        stamp = float(frame.stamp)
        try:
            validate_frame(frame)
        except FrameError as exc:
            return PipelineOutput(stamp, self.tracker.update(stamp, None), None, None, str(exc), "bad frame")
        det, point = self.locate(frame)
        estimate = self.tracker.update(stamp, point)
        return PipelineOutput(stamp, estimate, det, point, None, self.detector.last_reason)

    def idle(self, stamp: float, error: str | None = None) -> PipelineOutput:
        """The track at ``stamp`` when no usable frame came (camera silent, undecodable frame)."""
        estimate = self.tracker.estimate(float(stamp))
        return PipelineOutput(float(stamp), estimate, None, None, error, "no frame")


def annotate(frame: Frame, output: PipelineOutput, width: int = 320, jpeg_quality: int = 70) -> bytes:
    """A downscaled JPEG of the frame with the detection and track status drawn (for the monitor)."""
    rgb = frame.rgb
    if not isinstance(rgb, np.ndarray) or rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        rgb = np.zeros((frame.intrinsics.height, frame.intrinsics.width, 3), np.uint8)
    scale = width / rgb.shape[1]
    bgr = cv2.resize(
        rgb[:, :, ::-1], (width, max(1, round(rgb.shape[0] * scale))), interpolation=cv2.INTER_AREA
    )
    det = output.detection
    if det is not None:
        x, y, w, h = (round(c * scale) for c in det.bbox)
        cv2.rectangle(bgr, (x, y), (x + w, y + h), (0, 255, 0), 1)
        cv2.drawMarker(bgr, (round(det.u * scale), round(det.v * scale)), (0, 255, 0), cv2.MARKER_CROSS, 8, 1)
    est = output.estimate
    if output.error:
        text = "bad frame"
    elif est.valid:
        text = f"{est.status} {est.position[0]:+.2f} {est.position[1]:+.2f} {est.position[2]:+.2f}"
    else:
        text = est.status
    color = (0, 255, 0) if est.valid else (0, 0, 255)
    cv2.putText(bgr, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, color, 1, cv2.LINE_AA)
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()
