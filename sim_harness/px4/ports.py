"""OS-chosen UDP ports for tests and tools that run in parallel."""

from __future__ import annotations

import socket

__all__ = ["free_udp_port"]


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port on ``host`` that the OS reports free right now.

    The port is released before returning, so another process could take it in between; on
    loopback with the kernel's ephemeral-port rotation this is practically never an issue.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])
