"""The small interfaces between the daemon and its sensors.

A depth source and an odometry source are async iterators of timestamped samples. Hardware
(UVC RealSense via OpenCV, motion capture) and sim (the sim harness's camera and mocap feed)
implement the same protocols; the daemon gets one passed in and never imports the sim.

Timestamps are ``time.monotonic()`` seconds of this process (``t_mono_s``).
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

__all__ = ["DepthFrame", "DepthSource", "OdometrySample", "OdometrySource"]


@dataclass(frozen=True)
class DepthFrame:
    """One depth image as the camera delivers it."""

    depth_mm: NDArray[np.uint16]
    """Depth in millimetres, shape (H, W), 0 = invalid."""
    t_capture_mono_s: float
    """Capture time (monotonic s); arrival time when the device gives none."""
    seq: int = 0
    """Frame counter from the source (monotonic, gaps = dropped frames)."""


@dataclass(frozen=True)
class OdometrySample:
    """Pose (and velocity when known) of the vehicle in the world frame (x fwd, y left, z up)."""

    pos_world_m: NDArray[np.float64]
    """Position (m), shape (3,)."""
    quat_world_body: NDArray[np.float64]
    """Attitude (w, x, y, z), body FLU -> world, shape (4,)."""
    t_arrival_mono_s: float
    """Arrival time in this process (monotonic s)."""
    vel_world_m_s: NDArray[np.float64] | None = None
    """Velocity (m/s), shape (3,), if the source measures it."""


@runtime_checkable
class DepthSource(Protocol):
    """A camera: ``async with source: async for frame in source.frames(): ...``."""

    async def __aenter__(self) -> DepthSource: ...

    async def __aexit__(self, *exc: object) -> None: ...

    def frames(self) -> AsyncIterator[DepthFrame]:
        """Yield frames as they arrive; raise on an unrecoverable device error."""
        ...


@runtime_checkable
class OdometrySource(Protocol):
    """A pose feed: ``async with source: async for sample in source.samples(): ...``."""

    async def __aenter__(self) -> OdometrySource: ...

    async def __aexit__(self, *exc: object) -> None: ...

    def samples(self) -> AsyncIterator[OdometrySample]:
        """Yield samples as they arrive; raise on an unrecoverable error."""
        ...
