"""Bind the daemon to one vehicle on a UDP link, refuse a link with more than one, watch the source.

MAVSDK merges every sender of a system ID into one system: two autopilots with system ID 1 on the
daemon's port (a second vehicle, a SITL left running, a telemetry radio) look like one vehicle, and
commands go to whichever spoke last. So on a ``udpin://`` link the daemon owns the port itself:

1. :meth:`LinkGuard.bind` listens on the configured address until the first autopilot speaks, and
   ``listen_s`` longer (past one 1 Hz heartbeat period); every autopilot heard (system ID,
   component ID, the UDP address it sent from) is a candidate. More than one candidate raises
   :class:`BindingError` (the daemon refuses to start); exactly one is the :class:`Binding`.
2. MAVSDK then connects to the guard's loopback port (:attr:`LinkGuard.mavsdk_url`). Datagrams from
   the bound address pass to MAVSDK; MAVSDK's datagrams go to the bound address only. Anything
   else is dropped: a foreign autopilot is counted, and the bound system ID heard from another
   address is a changed source (:attr:`LinkGuard.source_changed`), which the supervisor stops on.

Only the MAVLink frame headers (and a heartbeat's autopilot field) are read; payloads pass as they
are. Times are ``time.monotonic()``.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass
from urllib.parse import urlsplit

from quadnav_onboard.logs import get_logger
from quadnav_onboard.ports import free_udp_port

__all__ = [
    "Binding",
    "BindingError",
    "Candidate",
    "LinkGuard",
    "SourceChange",
    "autopilot_frames",
    "guarded_address",
]

log = get_logger("quadnav.vehicle")

MAV_COMP_ID_AUTOPILOT1 = 1
MAV_AUTOPILOT_INVALID = 8
_HEARTBEAT_ID = 0
_V1, _V2 = 0xFE, 0xFD
_SIGNED = 0x01


@dataclass(frozen=True)
class Candidate:
    """An autopilot heard on the link: who it says it is and where it sent from."""

    system_id: int
    component_id: int
    address: tuple[str, int]
    """(host, port) the datagrams came from."""

    def __str__(self) -> str:
        return f"system {self.system_id} component {self.component_id} at {self.address[0]}:{self.address[1]}"


Binding = Candidate
"""The one candidate the daemon flies."""


@dataclass(frozen=True)
class SourceChange:
    """The bound system ID was heard from another address."""

    t_mono_s: float
    bound: Binding
    heard: Candidate


class BindingError(RuntimeError):
    """Not exactly one autopilot on the link; ``candidates`` lists who was heard."""

    def __init__(self, url: str, candidates: list[Candidate], listen_s: float) -> None:
        who = "; ".join(str(c) for c in candidates)
        super().__init__(
            f"vehicle.url {url!r}: {len(candidates)} autopilots answer on the link within "
            f"{listen_s:g} s ({who}); refusing to pick one"
        )
        self.candidates = candidates


def autopilot_frames(datagram: bytes) -> Iterator[tuple[int, int]]:
    """(system ID, component ID) of each frame in ``datagram`` that comes from an autopilot: any
    message of component 1 (MAV_COMP_ID_AUTOPILOT1), or a heartbeat whose autopilot field is not
    MAV_AUTOPILOT_INVALID. Frames that do not parse end the walk (the rest is not trusted)."""
    i, n = 0, len(datagram)
    while i + 8 <= n:
        magic, length = datagram[i], datagram[i + 1]
        if magic == _V2:
            if i + 10 > n:
                return
            sysid, compid = datagram[i + 5], datagram[i + 6]
            msgid = datagram[i + 7] | datagram[i + 8] << 8 | datagram[i + 9] << 16
            payload = datagram[i + 10 : i + 10 + length]
            size = 12 + length + (13 if datagram[i + 2] & _SIGNED else 0)
        elif magic == _V1:
            sysid, compid, msgid = datagram[i + 3], datagram[i + 4], datagram[i + 5]
            payload = datagram[i + 6 : i + 6 + length]
            size = 8 + length
        else:
            return
        if i + size > n:
            return
        if compid == MAV_COMP_ID_AUTOPILOT1:
            yield sysid, compid
        elif msgid == _HEARTBEAT_ID:
            autopilot = payload[5] if len(payload) > 5 else 0  # MAVLink 2 trims trailing zeros
            if autopilot != MAV_AUTOPILOT_INVALID:
                yield sysid, compid
        i += size


def guarded_address(url: str) -> tuple[str, int] | None:
    """(host, port) the guard listens on for a MAVSDK ``udpin://`` (or legacy ``udp://``) URL, else
    None (serial, TCP and ``udpout://`` links are left to MAVSDK)."""
    parts = urlsplit(url)
    if parts.scheme not in ("udpin", "udp") or parts.port is None:
        return None
    return (parts.hostname or "0.0.0.0", int(parts.port))


class _Endpoint(asyncio.DatagramProtocol):
    def __init__(self, guard: LinkGuard, side: str) -> None:
        self.guard, self.side = guard, side

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        if self.side == "vehicle":
            self.guard._from_vehicle_side(data, addr)
        else:
            self.guard._from_mavsdk_side(data, addr)

    def error_received(self, exc: Exception) -> None:  # ICMP unreachable: nobody there (yet)
        self.guard.send_errors += 1


class LinkGuard:
    """Owns the vehicle's UDP port, binds to one autopilot and relays it to and from MAVSDK."""

    def __init__(self, url: str, *, listen_s: float = 1.2) -> None:
        address = guarded_address(url)
        if address is None:
            raise ValueError(f"{url!r} is not a udpin:// URL")
        self.url = url
        self.address = address
        self.listen_s = listen_s
        self.binding: Binding | None = None
        self.source_changed: SourceChange | None = None
        """Set (once) when the bound system ID is heard from another address."""
        self.foreign: set[Candidate] = set()
        """Other autopilots heard after binding (dropped, never relayed)."""
        self.candidates: dict[Candidate, float] = {}
        self.relayed = self.dropped = self.send_errors = 0
        self._mavsdk_addr: tuple[str, int] | None = None
        self._vehicle_tx: asyncio.DatagramTransport | None = None
        self._mavsdk_tx: asyncio.DatagramTransport | None = None
        self._first_heard = asyncio.Event()

    @property
    def mavsdk_url(self) -> str:
        """The URL MAVSDK connects with (the guard's loopback relay)."""
        assert self._mavsdk_addr is not None, "bind() first"
        return f"udpin://{self._mavsdk_addr[0]}:{self._mavsdk_addr[1]}"

    async def bind(self, timeout_s: float) -> Binding:
        """Listen for autopilots; return the only one, or raise BindingError / TimeoutError."""
        loop = asyncio.get_running_loop()
        self._vehicle_tx, _ = await loop.create_datagram_endpoint(
            lambda: _Endpoint(self, "vehicle"), local_addr=self.address
        )
        async with asyncio.timeout(timeout_s):
            await self._first_heard.wait()
        await asyncio.sleep(self.listen_s)
        found = sorted(self.candidates, key=self.candidates.__getitem__)
        if len(found) != 1:
            raise BindingError(self.url, found, self.listen_s)
        self.binding = found[0]
        self._mavsdk_tx, _ = await loop.create_datagram_endpoint(
            lambda: _Endpoint(self, "mavsdk"), local_addr=("127.0.0.1", 0)
        )
        # MAVSDK binds this port itself; it comes from below the ephemeral range so that no
        # port-0 socket (the relay's own included) can be handed it in between.
        self._mavsdk_addr = ("127.0.0.1", free_udp_port())
        log.info("vehicle_bound", vehicle=str(self.binding), url=self.url, listened_s=self.listen_s)
        return self.binding

    def close(self) -> None:
        for tx in (self._vehicle_tx, self._mavsdk_tx):
            if tx is not None:
                with contextlib.suppress(Exception):
                    tx.close()
        self._vehicle_tx = self._mavsdk_tx = None

    # --- the relay -----------------------------------------------------------------------------

    def _from_vehicle_side(self, data: bytes, addr: tuple[str, int]) -> None:
        b = self.binding
        if b is not None and addr == b.address:
            if self._mavsdk_tx is not None and self._mavsdk_addr is not None:
                self._mavsdk_tx.sendto(data, self._mavsdk_addr)
                self.relayed += 1
            return
        self.dropped += 1
        for sysid, compid in autopilot_frames(data):
            heard = Candidate(sysid, compid, (addr[0], int(addr[1])))
            if b is None:
                self.candidates.setdefault(heard, time.monotonic())
                self._first_heard.set()
            elif sysid == b.system_id and self.source_changed is None:
                self.source_changed = SourceChange(time.monotonic(), b, heard)
                log.error("vehicle_source_changed", bound=str(b), heard=str(heard))
            elif heard not in self.foreign and sysid != b.system_id:
                self.foreign.add(heard)
                log.warning("foreign_autopilot_ignored", heard=str(heard), bound=str(b))

    def _from_mavsdk_side(self, data: bytes, addr: tuple[str, int]) -> None:
        b = self.binding
        if b is None or self._vehicle_tx is None or addr != self._mavsdk_addr:
            return
        self._vehicle_tx.sendto(data, b.address)
