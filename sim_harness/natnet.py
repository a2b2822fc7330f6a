"""An emulated OptiTrack Motive server speaking NatNet 3.0 over UDP, unicast.

The daemon's mocap source reads it through the ``motioncapture`` library's ``optitrack`` backend,
the same code path a lab's Motive feeds: the client sends ``NAT_CONNECT`` to the command port and
gets ``NAT_SERVERINFO`` (NatNet version, the data port, unicast); it asks for the model
definitions (``NAT_REQUEST_MODELDEF`` -> ``NAT_MODELDEF``: one rigid body by name and ID); then
``NAT_FRAMEOFDATA`` packets arrive on the data port of the client's address at the frame rate.

Like Motive's default streaming, positions are in a y-up frame (mocap x = world x, mocap y =
world z, mocap z = -world y); the daemon maps them back with ``odometry.rotation_world_from_mocap``
exactly as in a lab. A rigid body that is not tracked is sent with its "tracking valid" flag
cleared, which the library drops, as Motive does for an occluded body.

Packet layouts follow NatNet's documented format for version 3.0 (little-endian): a 2-byte
message ID and a 2-byte payload size, then the payload.
"""

from __future__ import annotations

import socket
import struct
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.frames import quat_from_rotmat, quat_multiply

__all__ = [
    "NATNET_VERSION",
    "NAT_CONNECT",
    "NAT_FRAMEOFDATA",
    "NAT_MODELDEF",
    "NAT_REQUEST_MODELDEF",
    "NAT_SERVERINFO",
    "ROTATION_WORLD_FROM_MOTIVE",
    "NatNetCommandServer",
    "frame_of_data",
    "model_def",
    "server_info",
    "world_to_motive",
]

NAT_CONNECT = 0
NAT_SERVERINFO = 1
NAT_REQUEST_MODELDEF = 4
NAT_MODELDEF = 5
NAT_FRAMEOFDATA = 7
NAT_KEEPALIVE = 10

NATNET_VERSION = (3, 0, 0, 0)
"""The protocol version announced (Motive 2.x): no per-section byte counts, high-res timestamps."""

CLOCK_HZ = 1_000_000
"""Ticks per second of the timestamps in a frame (the server's high-resolution clock: µs)."""

ROTATION_WORLD_FROM_MOTIVE = ((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0))
"""``odometry.rotation_world_from_mocap`` for Motive's default y-up frame."""

_R_WM = np.asarray(ROTATION_WORLD_FROM_MOTIVE, dtype=np.float64)
_Q_WM = quat_from_rotmat(_R_WM)
_Q_MW = _Q_WM * np.array([1.0, -1.0, -1.0, -1.0])


def _packet(message_id: int, payload: bytes) -> bytes:
    return struct.pack("<HH", message_id, len(payload) & 0xFFFF) + payload


def server_info(data_port: int, app_name: str = "quadnav-sim Motive") -> bytes:
    """``NAT_SERVERINFO``: app name (256 bytes), app and NatNet versions, clock rate, data port,
    unicast (no multicast group)."""
    payload = (
        app_name.encode()[:255].ljust(256, b"\0")
        + bytes((2, 2, 0, 0))
        + bytes(NATNET_VERSION)
        + struct.pack("<QH?4B", CLOCK_HZ, data_port, False, 0, 0, 0, 0)
    )
    return _packet(NAT_SERVERINFO, payload)


def model_def(bodies: Sequence[tuple[str, int]]) -> bytes:
    """``NAT_MODELDEF`` with one rigid-body description (name, ID, no parent, no offset, no
    markers) per ``(name, id)``."""
    parts = [struct.pack("<i", len(bodies))]
    for name, body_id in bodies:
        description = name.encode() + b"\0" + struct.pack("<ii3fi", body_id, -1, 0, 0, 0, 0)
        parts.append(struct.pack("<i", 1) + description)  # dataset type 1: a rigid body
    return _packet(NAT_MODELDEF, b"".join(parts))


def frame_of_data(
    frame_number: int,
    bodies: Sequence[tuple[int, NDArray[np.float64], NDArray[np.float64], bool]],
    t_ticks: int,
) -> bytes:
    """``NAT_FRAMEOFDATA``: rigid bodies ``(id, pos (3,) m, quat (w, x, y, z), tracked)`` in the
    mocap frame; no marker sets, skeletons, labeled markers, force plates or devices."""
    rb = [
        struct.pack("<i7ffh", body_id, *(float(v) for v in pos), float(q[1]), float(q[2]), float(q[3]),
                    float(q[0]), 0.0, 1 if tracked else 0)
        for body_id, pos, q, tracked in bodies
    ]
    payload = (
        struct.pack("<iii", frame_number, 0, 0)  # frame, marker sets, other markers
        + struct.pack("<i", len(rb)) + b"".join(rb)
        + struct.pack("<iiii", 0, 0, 0, 0)  # skeletons, labeled markers, force plates, devices
        + struct.pack("<IId", 0, 0, t_ticks / CLOCK_HZ)  # timecode, subframe, timestamp (s)
        + struct.pack("<QQQ", t_ticks, t_ticks, t_ticks)  # mid-exposure, received, transmit
        + struct.pack("<hi", 0, 0)  # frame params, end of data
    )
    return _packet(NAT_FRAMEOFDATA, payload)


def world_to_motive(
    pos_world_m: NDArray[np.float64], quat_world_body: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A world-frame pose as Motive's y-up frame reports it (the inverse of the daemon's map)."""
    pos = _R_WM.T @ np.asarray(pos_world_m, dtype=np.float64)
    q = quat_multiply(quat_multiply(_Q_MW, np.asarray(quat_world_body, dtype=np.float64)), _Q_WM)
    return pos, q / np.linalg.norm(q)


class NatNetCommandServer:
    """The command side: answers connect and model-definition requests and remembers who asked.

    ``poll()`` handles whatever is waiting (non-blocking); ``clients`` are the data addresses
    ``(ip, data_port)`` frames go to.
    """

    def __init__(self, host: str, command_port: int, data_port: int, bodies: Sequence[tuple[str, int]]):
        self.data_port = int(data_port)
        self.bodies = list(bodies)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, int(command_port)))
        self.sock.setblocking(False)
        self.command_port = self.sock.getsockname()[1]
        self.clients: list[tuple[str, int]] = []
        self.requests = 0
        """Well-formed requests answered."""
        self.rejected = 0
        """Datagrams that were not a NatNet request (ignored)."""

    def poll(self) -> None:
        while True:
            try:
                data, addr = self.sock.recvfrom(2048)
            except (BlockingIOError, InterruptedError):
                return
            if len(data) < 4:
                self.rejected += 1
                continue
            message_id = struct.unpack_from("<H", data)[0]
            if message_id == NAT_CONNECT:
                self.sock.sendto(server_info(self.data_port), addr)
                client = (addr[0], self.data_port)
                if client not in self.clients:
                    self.clients.append(client)
            elif message_id == NAT_REQUEST_MODELDEF:
                self.sock.sendto(model_def(self.bodies), addr)
            elif message_id == NAT_KEEPALIVE:
                pass
            else:
                self.rejected += 1
                continue
            self.requests += 1

    def close(self) -> None:
        self.sock.close()
