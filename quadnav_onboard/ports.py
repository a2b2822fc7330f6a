"""Free UDP ports for the link guard, stand-ins, tests and tools that run side by side.

A port found by binding port 0 is an *ephemeral* port: after it is released, the very next
socket that binds port 0 (a sender in a test, a MAVSDK client, another worker) may be handed the
same number before its owner binds it again, and the owner then fails with "Address already in
use". So the ports handed out here come from below the kernel's ephemeral range, which it never
assigns by itself, are picked at random from a generator no caller can seed, are checked free
with a bind, and are never handed out twice by one process.
"""

from __future__ import annotations

import random
import socket
import threading
from pathlib import Path

__all__ = ["free_udp_port"]

#: Lowest port handed out; below it sit registered services (MAVLink's 14550, PX4's 18570, ...).
LOWEST_PORT = 20000
#: Where the kernel's ephemeral range starts when it cannot be read (Linux's default).
DEFAULT_EPHEMERAL_LOW = 32768

_rng = random.Random()  # seeded from the OS; tests that seed ``random`` do not touch it
_handed_out: set[int] = set()
_lock = threading.Lock()


def ephemeral_low(path: Path = Path("/proc/sys/net/ipv4/ip_local_port_range")) -> int:
    """First port of the kernel's ephemeral range (Linux's file; the default elsewhere)."""
    try:
        return int(path.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return DEFAULT_EPHEMERAL_LOW


def _bindable(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        try:
            sock.bind((host, port))
        except OSError:
            return False
    return True


def free_udp_port(host: str = "127.0.0.1", attempts: int = 200) -> int:
    """A UDP port on ``host``, free right now, that nothing binding port 0 will be given.

    Falls back to an OS-chosen port only if the range below the ephemeral one is too small or
    every try is taken.
    """
    high = ephemeral_low()
    with _lock:
        if high - LOWEST_PORT >= 1000:
            for _ in range(attempts):
                port = _rng.randrange(LOWEST_PORT, high)
                if port not in _handed_out and _bindable(host, port):
                    _handed_out.add(port)
                    return port
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.bind((host, 0))
            port = int(sock.getsockname()[1])
        _handed_out.add(port)
        return port
