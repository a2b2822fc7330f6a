"""Depth frames from a camera process over a local (Unix domain) stream socket.

A camera driver in another process (the sim's camera, or a lab's own RealSense SDK process)
listens on a socket path; the daemon connects and reads frames as they come. Each frame is a
32-byte header and the pixels::

    magic b"QNDF" | version u16 | reserved u16 | width u16 | height u16 | seq u64 |
    t_capture_mono_s f64 | payload bytes u32 | uint16 depth (mm, 0 = invalid), row-major

all little-endian. ``t_capture_mono_s`` is the producer's ``time.monotonic()`` at capture: on
Linux that clock is shared by every process of the machine, so the daemon measures a frame's real
age. Why a socket and not shared memory: 30 fps of 424x240x16-bit is ~6 MB/s, which a Unix socket
carries with one copy of ~0.2 MB per frame (tens of microseconds); the socket also tells the daemon
at once when the camera process dies (end of stream) and needs no second channel to say a new
frame is there. The producer drops frames rather than queue them when the daemon falls behind
(latest wins).
"""

from __future__ import annotations

import asyncio
import struct
import time
from collections.abc import AsyncIterator

import numpy as np

from quadnav_onboard.sources.base import DepthFrame

__all__ = ["HEADER", "MAGIC", "DepthWireError", "SocketDepthSource", "encode_frame"]

MAGIC = b"QNDF"
VERSION = 1
HEADER = struct.Struct("<4sHHHHQdI")
"""The frame header (32 bytes)."""
assert HEADER.size == 32


class DepthWireError(RuntimeError):
    """The stream does not carry depth frames of the configured size (the message says what)."""


def encode_frame(depth_mm: np.ndarray, seq: int, t_capture_mono_s: float) -> tuple[bytes, memoryview]:
    """Header and pixel buffer of one frame (send both, in order)."""
    arr = np.ascontiguousarray(depth_mm, dtype="<u2")
    h, w = arr.shape
    header = HEADER.pack(MAGIC, VERSION, 0, w, h, seq, t_capture_mono_s, arr.nbytes)
    return header, memoryview(arr).cast("B")


class SocketDepthSource:
    """:class:`~quadnav_onboard.sources.base.DepthSource` reading a camera process's socket.

    ``connect_timeout_s``: how long to keep trying to connect (the camera process may still be
    starting). The stream ends with a :class:`ConnectionError` when the producer goes away, and
    with :class:`DepthWireError` on a frame of another size or format; the daemon's supervisor
    then stops the flight for stale depth.
    """

    def __init__(self, path: str, width: int, height: int, connect_timeout_s: float = 10.0) -> None:
        self.path = path
        self.width, self.height = int(width), int(height)
        self.connect_timeout_s = float(connect_timeout_s)
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self.frames_received = 0

    async def __aenter__(self) -> SocketDepthSource:
        deadline = time.monotonic() + self.connect_timeout_s
        while True:
            try:
                self._reader, self._writer = await asyncio.open_unix_connection(
                    self.path, limit=4 * HEADER.size + 4 * self.width * self.height
                )
                return self
            except (FileNotFoundError, ConnectionRefusedError) as exc:
                if time.monotonic() > deadline:
                    raise ConnectionError(
                        f"depth: no camera process listening at {self.path} "
                        f"after {self.connect_timeout_s:g} s ({type(exc).__name__})"
                    ) from None
                await asyncio.sleep(0.05)

    async def __aexit__(self, *exc: object) -> None:
        if self._writer is not None:
            self._writer.close()
        self._reader = self._writer = None

    def frames(self) -> AsyncIterator[DepthFrame]:
        if self._reader is None:
            raise RuntimeError("SocketDepthSource.frames() outside 'async with'")
        return self._frames(self._reader)

    async def _frames(self, reader: asyncio.StreamReader) -> AsyncIterator[DepthFrame]:
        expected = self.width * self.height * 2
        while True:
            try:
                header = await reader.readexactly(HEADER.size)
            except asyncio.IncompleteReadError:
                raise ConnectionError(f"depth: the camera process closed {self.path}") from None
            magic, version, _, w, h, seq, t_capture, nbytes = HEADER.unpack(header)
            if magic != MAGIC or version != VERSION:
                raise DepthWireError(f"depth: {self.path} does not speak the depth frame protocol "
                                     f"(magic {magic!r}, version {version})")
            if (w, h) != (self.width, self.height) or nbytes != expected:
                raise DepthWireError(f"depth: {self.path} sends {w}x{h} frames ({nbytes} bytes), "
                                     f"configured {self.width}x{self.height}")
            try:
                payload = await reader.readexactly(nbytes)
            except asyncio.IncompleteReadError:
                raise ConnectionError(f"depth: the camera process closed {self.path} mid-frame") from None
            # A writeable copy: numba kernels downstream are compiled for writeable arrays.
            depth_mm = np.frombuffer(payload, dtype="<u2").reshape(h, w).astype(np.uint16, copy=True)
            self.frames_received += 1
            yield DepthFrame(depth_mm=depth_mm, t_capture_mono_s=t_capture, seq=seq)
