"""Depth from an Intel RealSense D435 as a plain UVC camera (no librealsense): OpenCV's V4L2 backend.

The D435's depth node streams Z16 (uint16 millimetres, 0 = no data). OpenCV is told not to convert
to RGB (``CAP_PROP_CONVERT_RGB = 0``) and to hand over raw buffers (``CAP_PROP_FORMAT = -1``), with
the ``Z16 `` FOURCC, the configured resolution and rate, and a short driver queue
(``CAP_PROP_BUFFERSIZE``), so that a frame read is the newest one, not one that waited in a queue.

**The mode is negotiated, not assumed.** A V4L2 driver answers a mode it cannot do with the nearest
one it can; OpenCV's ``set`` then returns True or False depending on the property. So after asking,
the source reads back FOURCC, size and rate (``get``) and refuses to start, naming the asked and the
granted mode, when any ``set`` was refused or any read-back differs.

**Capture time.** OpenCV's V4L2 backend reports the driver's buffer timestamp as
``CAP_PROP_POS_MSEC`` (uvcvideo stamps buffers with CLOCK_MONOTONIC, the clock of
``time.monotonic()``). It is used when it is plausible (not after the arrival, at most
:data:`MAX_BUFFER_AGE_S` before it); otherwise the frame's arrival time in this process is.

**Which node.** A D435 has several V4L2 nodes (depth, infrared, colour, metadata), all named alike
(``Intel(R) RealSense(TM) Depth Ca``). ``device: auto`` finds the node whose name contains
``RealSense`` and which offers Z16, from ``/sys/class/video4linux`` and the driver's format list
(:func:`find_depth_node`). Reads block, so they run on one dedicated thread.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import fcntl
import math
import os
import struct
import time
from collections.abc import AsyncIterator, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.logs import get_logger
from quadnav_onboard.sources.base import DepthFrame

__all__ = [
    "AUTO_DEVICE",
    "DepthSourceError",
    "UvcDepthSource",
    "V4l2Mode",
    "V4l2Node",
    "find_depth_node",
    "list_v4l2_nodes",
    "raw_to_depth_mm",
    "v4l2_capture_formats",
]

log = get_logger("quadnav.uvc")

Z16 = cv2.VideoWriter_fourcc("Z", "1", "6", " ")
AUTO_DEVICE = "auto"
"""``depth.device`` value that means: find the camera's depth node (:func:`find_depth_node`)."""
V4L2_SYSFS = Path("/sys/class/video4linux")
MAX_BUFFER_AGE_S = 1.0
"""A driver timestamp more than this before the frame's arrival is not believed (another clock)."""
FPS_TOLERANCE = 0.01
"""Relative difference between asked and granted frame rate that still counts as granted."""

# VIDIOC_ENUM_FMT = _IOWR('V', 2, struct v4l2_fmtdesc): index, type, flags, description[32],
# pixelformat, mbus_code, reserved[3] -> 64 bytes (linux/videodev2.h).
_FMTDESC = struct.Struct("=III32sII3I")
_VIDIOC_ENUM_FMT = (3 << 30) | (_FMTDESC.size << 16) | (ord("V") << 8) | 2
_V4L2_BUF_TYPE_VIDEO_CAPTURE = 1


class DepthSourceError(RuntimeError):
    """The camera cannot be opened or stopped delivering usable frames (message names the device)."""


def fourcc_str(code: float | int) -> str:
    """A FOURCC as its four characters (``'Z16 '``); ``'?'`` for a value that is not one."""
    try:
        raw = int(code).to_bytes(4, "little")
    except (OverflowError, ValueError):
        return "?"
    return raw.decode("ascii") if all(32 <= b < 127 for b in raw) else "?"


@dataclass(frozen=True)
class V4l2Mode:
    """A V4L2 capture mode: pixel format, size (px) and frame rate (Hz)."""

    fourcc: str
    width: int
    height: int
    fps: float

    def __str__(self) -> str:
        return f"{self.fourcc.strip() or '?'} {self.width}x{self.height} @ {self.fps:g} Hz"

    def grants(self, asked: V4l2Mode) -> bool:
        """This (granted) mode is the ``asked`` one, the rate within :data:`FPS_TOLERANCE`."""
        return (
            (self.fourcc, self.width, self.height) == (asked.fourcc, asked.width, asked.height)
            and math.isfinite(self.fps)
            and abs(self.fps - asked.fps) <= FPS_TOLERANCE * asked.fps
        )


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


# --- finding the depth node -------------------------------------------------------------------


@dataclass(frozen=True)
class V4l2Node:
    """One entry of ``/sys/class/video4linux``."""

    node: str
    """Kernel name, e.g. ``video2``."""
    device: str
    """Device file, e.g. ``/dev/video2``."""
    name: str
    """The driver's name for it (sysfs ``name``; uvcvideo: the USB product, cut to 31 characters)."""


def _node_number(name: str) -> tuple[int, str]:
    digits = name.removeprefix("video")
    return (int(digits), name) if digits.isdigit() else (1 << 30, name)


def list_v4l2_nodes(sysfs_root: Path = V4L2_SYSFS, dev_root: Path = Path("/dev")) -> list[V4l2Node]:
    """The V4L2 nodes under ``sysfs_root`` (``videoN`` entries), in number order."""
    if not sysfs_root.is_dir():
        return []
    nodes = []
    for entry in sorted(sysfs_root.iterdir(), key=lambda p: _node_number(p.name)):
        if not entry.name.startswith("video"):
            continue
        try:
            name = (entry / "name").read_text(errors="replace").strip()
        except OSError:
            name = ""
        nodes.append(V4l2Node(entry.name, str(dev_root / entry.name), name))
    return nodes


def v4l2_capture_formats(device: str) -> list[str]:
    """The FOURCCs a V4L2 node offers for video capture (``VIDIOC_ENUM_FMT``); [] for a metadata node.

    Raises OSError when the node cannot be opened (permissions: group quadnav, the udev rule).
    """
    fd = os.open(device, os.O_RDWR | os.O_NONBLOCK)
    formats = []
    try:
        for index in range(64):
            buf = bytearray(_FMTDESC.pack(index, _V4L2_BUF_TYPE_VIDEO_CAPTURE, 0, b"", 0, 0, 0, 0, 0))
            try:
                fcntl.ioctl(fd, _VIDIOC_ENUM_FMT, buf)
            except OSError as exc:
                if exc.errno in (errno.EINVAL, errno.ENOTTY):  # past the last format / not capture
                    break
                raise
            formats.append(fourcc_str(_FMTDESC.unpack(bytes(buf))[4]))
    finally:
        os.close(fd)
    return formats


def find_depth_node(
    name_contains: str = "RealSense",
    fourcc: str = "Z16 ",
    *,
    sysfs_root: Path = V4L2_SYSFS,
    dev_root: Path = Path("/dev"),
    list_formats: Callable[[str], list[str]] = v4l2_capture_formats,
) -> str:
    """The device file of the one V4L2 node whose name contains ``name_contains`` and which offers
    ``fourcc``. Raises DepthSourceError listing what was seen when there is none or more than one."""
    seen, hits = [], []
    for node in list_v4l2_nodes(sysfs_root, dev_root):
        if name_contains.lower() not in node.name.lower():
            seen.append(f"{node.device} ({node.name or 'no name'})")
            continue
        try:
            formats = list_formats(node.device)
        except OSError as exc:
            seen.append(f"{node.device} ({node.name}: cannot open: {exc.strerror or exc})")
            continue
        seen.append(
            f"{node.device} ({node.name}: {' '.join(f.strip() for f in formats) or 'no capture formats'})"
        )
        if fourcc in formats:
            hits.append(node.device)
    if len(hits) == 1:
        return hits[0]
    what = f"V4L2 node named *{name_contains}* offering {fourcc.strip()}"
    if not hits:
        raise DepthSourceError(
            f"depth.device 'auto': no {what} under {sysfs_root}; seen: {', '.join(seen) or 'no nodes'}"
        )
    raise DepthSourceError(
        f"depth.device 'auto': {len(hits)} nodes ({', '.join(hits)}) are each a {what}: "
        "set depth.device to one of them"
    )


# --- the source -------------------------------------------------------------------------------


def _device_arg(device: str) -> int | str:
    return int(device) if device.isdigit() else device


class UvcDepthSource:
    """:class:`~quadnav_onboard.sources.base.DepthSource` for a D435 depth node over V4L2.

    ``device``: ``/dev/videoN``, an index (``"2"``) or ``"auto"`` (:func:`find_depth_node` over
    ``sysfs_root``). ``buffers``: V4L2 buffers asked for (``CAP_PROP_BUFFERSIZE``).
    """

    def __init__(
        self,
        device: str,
        width: int = 424,
        height: int = 240,
        fps: float = 30.0,
        *,
        buffers: int = 2,
        max_consecutive_failures: int = 30,
        capture_factory: Callable[..., Any] = cv2.VideoCapture,
        sysfs_root: Path = V4L2_SYSFS,
        list_formats: Callable[[str], list[str]] = v4l2_capture_formats,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.device, self.width, self.height, self.fps = device, int(width), int(height), float(fps)
        self.buffers = int(buffers)
        self.max_consecutive_failures = max_consecutive_failures
        self.opened_device: str | None = None
        """The device file or index actually opened (the node found, with ``device: auto``)."""
        self.granted: V4l2Mode | None = None
        """The mode the driver granted (equal to the asked one once open)."""
        self.timestamps = "none"
        """Where capture times come from: ``driver`` (buffer timestamps) or ``arrival``."""
        self._factory = capture_factory
        self._sysfs_root = sysfs_root
        self._list_formats = list_formats
        self._clock = clock
        self._cap: Any = None
        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="uvc")

    @property
    def asked(self) -> V4l2Mode:
        """The mode asked of the driver."""
        return V4l2Mode("Z16 ", self.width, self.height, self.fps)

    def _open(self) -> Any:
        device = self.device
        if device == AUTO_DEVICE:
            device = find_depth_node(sysfs_root=self._sysfs_root, list_formats=self._list_formats)
        cap = self._factory(_device_arg(device), cv2.CAP_V4L2)
        if not cap.isOpened():
            raise DepthSourceError(f"depth.device {device!r}: cannot open with V4L2")
        try:
            self.granted = self._negotiate(cap, device)
        except BaseException:
            cap.release()
            raise
        self.opened_device = device
        log.info(
            "depth_camera_open",
            device=device,
            mode=str(self.granted),
            buffers=cap.get(cv2.CAP_PROP_BUFFERSIZE),
        )
        return cap

    def _negotiate(self, cap: Any, device: str) -> V4l2Mode:
        """Ask for the mode (FOURCC before size, as V4L2 wants), read back what was granted."""
        asks = [
            ("fourcc", cv2.CAP_PROP_FOURCC, Z16),
            ("width", cv2.CAP_PROP_FRAME_WIDTH, self.width),
            ("height", cv2.CAP_PROP_FRAME_HEIGHT, self.height),
            ("fps", cv2.CAP_PROP_FPS, self.fps),
        ]
        refused = [what for what, prop, value in asks if not cap.set(prop, value)]
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        cap.set(cv2.CAP_PROP_FORMAT, -1)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, self.buffers)
        granted = V4l2Mode(
            fourcc_str(cap.get(cv2.CAP_PROP_FOURCC)),
            int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
            int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)),
            float(cap.get(cv2.CAP_PROP_FPS)),
        )
        if refused or not granted.grants(self.asked):
            detail = f" (set refused: {', '.join(refused)})" if refused else ""
            raise DepthSourceError(
                f"depth.device {device!r}: asked {self.asked}, the driver granted {granted}{detail}: "
                "not the depth node, a USB 2 link, or a mode this camera lacks "
                "(v4l2-ctl -d DEVICE --list-formats-ext)"
            )
        return granted

    def _read(self) -> tuple[bool, Any, float, float]:
        """On the camera thread: (ok, raw frame, arrival time, driver timestamp in s or NaN)."""
        ok, raw = self._cap.read()
        t_arrival_s = self._clock()
        t_driver_s = math.nan
        if ok:
            with contextlib.suppress(Exception):
                t_driver_s = float(self._cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0
        return ok, raw, t_arrival_s, t_driver_s

    def _capture_time(self, t_arrival_s: float, t_driver_s: float) -> float:
        """The driver's buffer timestamp when it is on this clock, else the arrival time."""
        usable = math.isfinite(t_driver_s) and 0.0 <= t_arrival_s - t_driver_s <= MAX_BUFFER_AGE_S
        source = "driver" if usable else "arrival"
        if source != self.timestamps:
            log.info("depth_timestamps", source=source, device=self.opened_device)
            self.timestamps = source
        return t_driver_s if usable else t_arrival_s

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
        name = self.opened_device or self.device
        while True:
            ok, raw, t_arrival_s, t_driver_s = await loop.run_in_executor(self._thread, self._read)
            if not ok or raw is None:
                failures += 1
                if failures >= self.max_consecutive_failures:
                    raise DepthSourceError(f"depth.device {name!r}: {failures} reads in a row failed")
                continue
            try:
                depth = raw_to_depth_mm(raw, self.width, self.height)
            except ValueError as exc:
                raise DepthSourceError(f"depth.device {name!r}: {exc}") from None
            failures = 0
            seq += 1
            yield DepthFrame(depth, self._capture_time(t_arrival_s, t_driver_s), seq)
