"""Odometry from a motion-capture system through the ``motioncapture`` library.

Any system the library supports (optitrack, vicon, qualisys, vrpn, mock, ...) by
``odometry.system_type``, the server at ``odometry.host`` and the vehicle's rigid body by name.
Mocap frames differ from ours (OptiTrack streams y-up), so a configured rotation ``R_wm``
(``rotation_world_from_mocap``) and translation ``t_w`` map them into the world frame:
``p_world = R_wm p_mocap + t_w``. The rigid body is assumed to have been created with the vehicle
level and facing world +x, so its attitude maps as ``R_world_body = R_wm R_mocap_rb R_wm^T``.
``waitForNextFrame`` blocks (releasing the GIL), so it runs on one dedicated daemon thread; each
sample is stamped on arrival and handed to the event loop, newest wins. A frame without the body
(occluded) or with NaN is skipped: the feed goes stale and the supervisor acts. A server that dies
leaves that thread waiting forever, which is why it is a daemon thread: it never holds up the exit.

The library's ``connect`` waits for the server's answer without a timeout and holds the GIL while
it does, which would freeze the whole daemon. For OptiTrack (NatNet) the source first asks the
server itself, with a timeout, and refuses with the address when nobody answers.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import socket
import struct
import sys
import threading
import time
from collections.abc import AsyncIterator, Iterator, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.frames import quat_from_rotmat, quat_multiply
from quadnav_onboard.sources.base import OdometrySample

__all__ = ["NATNET_COMMAND_PORT", "MocapError", "MocapOdometrySource", "MocapTransform", "probe_natnet"]

NATNET_COMMAND_PORT = 1510
"""Motive's default NatNet command port."""


class MocapError(RuntimeError):
    """The mocap system cannot be reached (the message names system type and host)."""


class MocapTransform:
    """The configured map from the mocap frame into the world frame (pure)."""

    def __init__(
        self, rotation_world_from_mocap: Sequence[Sequence[float]], translation_world_m: Sequence[float]
    ):
        self.r_wm = np.asarray(rotation_world_from_mocap, dtype=np.float64)
        self.q_wm = quat_from_rotmat(self.r_wm)
        self.q_mw = self.q_wm * np.array([1.0, -1.0, -1.0, -1.0])
        self.t_w = np.asarray(translation_world_m, dtype=np.float64)

    def apply(
        self, pos_mocap_m: NDArray[np.float64], quat_mocap_body: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(position m, quaternion w,x,y,z) in the mocap frame -> the world frame."""
        pos = self.r_wm @ np.asarray(pos_mocap_m, dtype=np.float64) + self.t_w
        q = quat_multiply(quat_multiply(self.q_wm, np.asarray(quat_mocap_body, dtype=np.float64)), self.q_mw)
        return pos, q / np.linalg.norm(q)


@contextlib.contextmanager
def _stdout_to_stderr() -> Iterator[None]:
    """Send what native code writes to file descriptor 1 to descriptor 2 for a while."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def probe_natnet(host: str, port: int, timeout_s: float) -> str:
    """Ask a NatNet server for its info (``NAT_CONNECT`` -> ``NAT_SERVERINFO``); its NatNet version
    ("3.0.0.0"). Raises :class:`MocapError` when nothing answers within ``timeout_s``."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(timeout_s)
        try:
            sock.sendto(struct.pack("<HH", 0, 0), (host, port))
            while True:
                data, _ = sock.recvfrom(4096)
                if len(data) >= 268 and struct.unpack_from("<H", data)[0] == 1:
                    return ".".join(str(b) for b in data[264:268])
        except (TimeoutError, OSError) as exc:
            raise MocapError(
                f"odometry: no NatNet server answers at {host}:{port} within {timeout_s:g} s "
                f"(is Motive streaming, unicast, to this machine?): {type(exc).__name__}"
            ) from None


class MocapOdometrySource:
    """:class:`~quadnav_onboard.sources.base.OdometrySource` over ``motioncapture``.

    ``port_command``: the NatNet command port (optitrack only; Motive's default 1510).
    """

    def __init__(
        self,
        system_type: str,
        host: str,
        rigid_body: str,
        transform: MocapTransform,
        *,
        port_command: int | None = None,
        connect_args: dict[str, Any] | None = None,
        connect_timeout_s: float = 3.0,
    ) -> None:
        self.system_type, self.host, self.rigid_body = system_type, host, rigid_body
        self.transform = transform
        self.port_command = port_command
        self.connect_timeout_s = float(connect_timeout_s)
        if connect_args is None:
            connect_args = {"hostname": host}
            if port_command is not None:
                connect_args["port_command"] = str(int(port_command))
        self._connect_args = connect_args
        self._mc: Any = None
        self._closed = threading.Event()
        self._latest: tuple[NDArray[np.float64], NDArray[np.float64], float] | None = None
        self._error: BaseException | None = None
        self._wake: asyncio.Event | None = None
        self.skipped = 0
        """Frames without a usable pose of the rigid body."""
        self.server_version = ""
        """The NatNet version the server announced (optitrack)."""

    def _connect(self) -> Any:
        import motioncapture

        try:
            with _stdout_to_stderr():  # the library prints to stdout, where the summary goes
                return motioncapture.connect(self.system_type, self._connect_args)
        except Exception as exc:
            raise MocapError(
                f"odometry: cannot connect to {self.system_type} at {self.host!r}: {exc}"
            ) from exc

    async def __aenter__(self) -> MocapOdometrySource:
        if self.system_type == "optitrack":
            port = self.port_command if self.port_command is not None else NATNET_COMMAND_PORT
            self.server_version = await asyncio.to_thread(
                probe_natnet, self.host, port, self.connect_timeout_s
            )
        self._mc = await asyncio.to_thread(self._connect)
        loop = asyncio.get_running_loop()
        self._wake = asyncio.Event()
        self._closed.clear()
        threading.Thread(
            target=self._read_frames, args=(self._mc, loop, self._wake), name="mocap", daemon=True
        ).start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        self._closed.set()  # the reader thread ends after its current wait

    def _pose(self, mc: Any) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        body = mc.rigidBodies.get(self.rigid_body)
        if body is None:
            return None
        r = body.rotation
        pos = np.asarray(body.position, dtype=np.float64)
        q = np.array([r.w, r.x, r.y, r.z], dtype=np.float64)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(q))) or np.linalg.norm(q) < 0.5:
            return None
        return pos, q

    def _read_frames(self, mc: Any, loop: asyncio.AbstractEventLoop, wake: asyncio.Event) -> None:
        """The reader thread: wait for frames (GIL released), keep the newest, wake the loop."""
        try:
            while not self._closed.is_set():
                mc.waitForNextFrame()
                t = time.monotonic()
                got = self._pose(mc)
                if got is None:
                    self.skipped += 1
                    continue
                self._latest = (*got, t)
                loop.call_soon_threadsafe(wake.set)
        except BaseException as exc:  # delivered to the consumer, which ends the feed
            self._error = exc
            if not loop.is_closed():
                loop.call_soon_threadsafe(wake.set)

    async def samples(self) -> AsyncIterator[OdometrySample]:
        wake = self._wake
        if wake is None:
            raise RuntimeError("MocapOdometrySource.samples() outside 'async with'")
        while True:
            await wake.wait()
            wake.clear()
            if self._error is not None:
                raise MocapError(f"odometry: {self.system_type} reader failed: {self._error}")
            latest, self._latest = self._latest, None
            if latest is None:
                continue
            pos_m, q_m, t = latest
            pos, q = self.transform.apply(pos_m, q_m)
            yield OdometrySample(pos, q, t)
