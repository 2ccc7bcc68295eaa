"""What every camera backend returns, and the check a frame must pass before the pipeline uses it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from common.errors import AdaptiveHError
from vision.camera_model import Intrinsics


class FrameError(AdaptiveHError, ValueError):
    """A frame the pipeline cannot use (wrong shape, wrong type, no depth, NaN); the text says why."""


class CameraError(AdaptiveHError, RuntimeError):
    """The camera could not deliver a frame (timeout, disconnected); the text says why."""


@dataclass(frozen=True)
class Frame:
    """One RGB-D capture: colour uint8 HxWx3 (RGB order), depth float32 HxW in metres (0 = no depth).

    ``stamp`` is the capture time (seconds since the epoch): latency and tracking are measured from it.
    Depth is registered to colour (same pixel grid and intrinsics).
    """

    rgb: np.ndarray
    depth: np.ndarray
    intrinsics: Intrinsics
    stamp: float
    seq: int = 0


class Camera(Protocol):
    """A source of registered RGB-D frames."""

    @property
    def intrinsics(self) -> Intrinsics: ...

    def capture(self) -> Frame:
        """The next frame; raises ``CameraError`` when none can be had."""
        ...

    def close(self) -> None: ...


def validate_frame(frame: Frame) -> None:
    """Raise ``FrameError`` unless ``frame`` is usable: right shapes and types, finite depth, some depth."""
    k = frame.intrinsics
    rgb, depth = frame.rgb, frame.depth
    if not isinstance(rgb, np.ndarray) or not isinstance(depth, np.ndarray):
        raise FrameError("rgb and depth must be numpy arrays")
    if rgb.shape != (k.height, k.width, 3):
        raise FrameError(f"rgb shape {rgb.shape}, expected {(k.height, k.width, 3)} from the intrinsics")
    if depth.shape != (k.height, k.width):
        raise FrameError(f"depth shape {depth.shape}, expected {(k.height, k.width)} from the intrinsics")
    if rgb.dtype != np.uint8:
        raise FrameError(f"rgb dtype {rgb.dtype}, expected uint8")
    if depth.dtype.kind != "f":
        raise FrameError(f"depth dtype {depth.dtype}, expected float metres")
    if not np.isfinite(depth).all():
        raise FrameError(f"depth has {int((~np.isfinite(depth)).sum())} NaN/inf pixels")
    if (depth < 0).any():
        raise FrameError("depth has negative values")
    if not (depth > 0).any():
        raise FrameError("depth is all zero (no valid pixel)")
