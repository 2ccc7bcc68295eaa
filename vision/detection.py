"""Finding the coloured target in an RGB-D frame with OpenCV.

HSV thresholds (several ranges, since red wraps around hue 0), morphological opening and closing to
remove speckle and fill holes, the largest contour above a minimum area, its centroid, and a robust
depth: the median of valid depth pixels of the mask inside a small patch around the centroid.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vision.config import DetectionConfig

PATCH_FRACTION = 0.12  # patch half-width as a fraction of the blob's equivalent side (sqrt(area))


@dataclass(frozen=True)
class Detection:
    """A target blob: centroid pixel (u, v), its depth (m), area (px), bounding box (x, y, w, h)."""

    u: float
    v: float
    depth: float
    area: float
    bbox: tuple[int, int, int, int]
    valid_depth_fraction: float


class Detector:
    """Colour-blob detector; returns ``None`` when no usable target is in the frame."""

    def __init__(self, config: DetectionConfig) -> None:
        self.config = config
        self._lower = [np.array(r[:3], np.uint8) for r in config.hsv_ranges]
        self._upper = [np.array(r[3:], np.uint8) for r in config.hsv_ranges]
        k = config.morph_kernel
        self._kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)) if k > 1 else None
        self.last_mask: np.ndarray | None = None
        self.last_reason = ""

    def mask(self, rgb: np.ndarray) -> np.ndarray:
        """Binary mask (uint8 0/255) of target-coloured pixels after morphology."""
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        mask = cv2.inRange(hsv, self._lower[0], self._upper[0])
        for lo, hi in zip(self._lower[1:], self._upper[1:], strict=True):
            mask |= cv2.inRange(hsv, lo, hi)
        if self._kernel is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._kernel)
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self._kernel)
        return mask

    def detect(self, rgb: np.ndarray, depth: np.ndarray) -> Detection | None:
        """The largest target blob with a trustworthy depth, or ``None`` (``last_reason`` says why)."""
        cfg = self.config
        mask = self.mask(rgb)
        self.last_mask = mask
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if not contours:
            self.last_reason = "no target-coloured pixels"
            return None
        contour = max(contours, key=cv2.contourArea)
        moments = cv2.moments(contour)
        area = moments["m00"]
        if area < cfg.min_area_px:
            self.last_reason = f"largest blob {area:.0f} px < min_area_px {cfg.min_area_px}"
            return None
        u, v = moments["m10"] / area, moments["m01"] / area
        blob = np.zeros_like(mask)
        cv2.drawContours(blob, [contour], -1, 255, thickness=cv2.FILLED)
        h, w = mask.shape
        # The patch stays well inside the blob (a fraction of its size, at most depth_patch) so the
        # median is the depth where the centre ray enters, not a mix of faces; it grows only if it
        # holds too few blob pixels.
        r = int(np.clip(round(PATCH_FRACTION * np.sqrt(area)), 1, max(1, cfg.depth_patch // 2)))
        for radius in (r, 2 * r + 1, 4 * r + 3):
            y0, y1 = max(0, round(v) - radius), min(h, round(v) + radius + 1)
            x0, x1 = max(0, round(u) - radius), min(w, round(u) + radius + 1)
            inside = (blob[y0:y1, x0:x1] > 0) & (mask[y0:y1, x0:x1] > 0)
            if inside.sum() >= 5:
                break
        d = depth[y0:y1, x0:x1][inside]
        good = d[(d >= cfg.min_depth) & (d <= cfg.max_depth)]
        fraction = good.size / max(d.size, 1)
        if d.size == 0 or fraction < cfg.min_valid_fraction:
            self.last_reason = f"too little valid depth on the target ({fraction:.0%} of {d.size} px)"
            return None
        x, y, bw, bh = cv2.boundingRect(contour)
        self.last_reason = ""
        return Detection(float(u), float(v), float(np.median(good)), float(area), (x, y, bw, bh), fraction)
