"""Depth from an Intel RealSense D435 as a plain UVC camera (no librealsense): OpenCV's V4L2 backend.

The D435's depth node streams Z16 (uint16 millimetres, 0 = no data). OpenCV is told not to convert
to RGB (``CAP_PROP_CONVERT_RGB = 0``) and to hand over raw buffers (``CAP_PROP_FORMAT = -1``), with
the ``Z16 `` FOURCC, the configured resolution and rate. Raw buffers arrive either as (H, W) uint16
or as a flat uint8 byte buffer of H*W*2 bytes; both are returned as (H, W) uint16. Reads block, so
they run on one dedicated thread. V4L2 buffer timestamps are not exposed reliably by OpenCV, so the
capture time is the arrival time (monotonic) of the frame in this process.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.sources.base import DepthFrame

__all__ = ["DepthSourceError", "UvcDepthSource", "raw_to_depth_mm"]

Z16 = cv2.VideoWriter_fourcc("Z", "1", "6", " ")


class DepthSourceError(RuntimeError):
    """The camera cannot be opened or stopped delivering usable frames (message names the device)."""


def raw_to_depth_mm(raw: NDArray[Any], width: int, height: int) -> NDArray[np.uint16]:
    """A raw V4L2 Z16 buffer from OpenCV -> (height, width) uint16 mm; raises ValueError otherwise."""
    arr = np.asarray(raw)
    if arr.dtype == np.uint16 and arr.shape == (height, width):
        return arr
    if arr.dtype == np.uint8 and arr.size == width * height * 2:
        return np.ascontiguousarray(arr).reshape(-1).view("<u2").reshape(height, width)
    raise ValueError(
        f"frame of dtype {arr.dtype} shape {arr.shape} is not Z16 {width}x{height} "
        "(RGB conversion on? wrong /dev/video node?)"
    )


def _device_arg(device: str) -> int | str:
    return int(device) if device.isdigit() else device


class UvcDepthSource:
    """:class:`~quadnav_onboard.sources.base.DepthSource` for a D435 depth node over V4L2."""

    def __init__(
        self,
        device: str,
        width: int = 424,
        height: int = 240,
        fps: float = 30.0,
        *,
        max_consecutive_failures: int = 30,
        capture_factory: Callable[..., Any] = cv2.VideoCapture,
    ) -> None:
        self.device, self.width, self.height, self.fps = device, int(width), int(height), float(fps)
        self.max_consecutive_failures = max_consecutive_failures
        self._factory = capture_factory
        self._cap: Any = None
        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="uvc")

    def _open(self) -> Any:
        cap = self._factory(_device_arg(self.device), cv2.CAP_V4L2)
        if not cap.isOpened():
            raise DepthSourceError(f"depth.device {self.device!r}: cannot open with V4L2")
        cap.set(cv2.CAP_PROP_FOURCC, Z16)
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        cap.set(cv2.CAP_PROP_FPS, self.fps)
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        cap.set(cv2.CAP_PROP_FORMAT, -1)
        return cap

    async def __aenter__(self) -> UvcDepthSource:
        loop = asyncio.get_running_loop()
        self._cap = await loop.run_in_executor(self._thread, self._open)
        return self

    async def __aexit__(self, *exc: object) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
        self._thread.shutdown(wait=False, cancel_futures=True)

    async def frames(self) -> AsyncIterator[DepthFrame]:
        loop = asyncio.get_running_loop()
        failures, seq = 0, 0
        while True:
            ok, raw = await loop.run_in_executor(self._thread, self._cap.read)
            t = time.monotonic()
            if not ok or raw is None:
                failures += 1
                if failures >= self.max_consecutive_failures:
                    raise DepthSourceError(f"depth.device {self.device!r}: {failures} reads in a row failed")
                continue
            try:
                depth = raw_to_depth_mm(raw, self.width, self.height)
            except ValueError as exc:
                raise DepthSourceError(f"depth.device {self.device!r}: {exc}") from None
            failures = 0
            seq += 1
            yield DepthFrame(depth, t, seq)
