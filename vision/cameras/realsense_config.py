"""Configuration of a RealSense device (``vision.realsense``), beside its backend
(``vision/cameras/realsense.py``)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from common.config import Section


class RealSenseConfig(Section):
    """A RealSense device: colour and depth streams at one size, depth aligned to colour."""

    serial: str = ""  # the device's serial number; empty: the first device found
    width: int = Field(
        640, gt=0, description="colour and depth stream width in pixels (a mode the device supports)"
    )
    height: int = Field(
        480, gt=0, description="colour and depth stream height in pixels (a mode the device supports)"
    )
    fps: Literal[6, 15, 30, 60, 90] = Field(30, description="frames per second of both streams")
    timeout_ms: int = Field(
        1000, gt=0, description="how long to wait for one frameset (milliseconds) before counting a timeout"
    )
    max_timeouts: int = Field(3, ge=1)  # consecutive frame timeouts before a reconnect (hardware reset)
    reconnect_wait_s: float = Field(
        3.0,
        ge=0,
        description="after a hardware reset, how long to wait (seconds) for the device to come back before"
        " restarting it",
    )
