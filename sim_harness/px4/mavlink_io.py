"""MAVLink 2 over UDP for the emulated PX4: one :class:`MavlinkLink` per remote port.

Like PX4 SITL, the vehicle *sends* to a fixed port on loopback (the client listens there with
``udpin://``) from an OS-chosen local port, and answers whoever sends to it. Packets can be
dropped or delayed by the fault schedule; delayed packets wait in a bounded queue.
"""

from __future__ import annotations

import heapq
import itertools
import socket
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

__all__ = ["MAX_DELAYED_PACKETS", "MavlinkLink", "mavlink2"]

MAX_DELAYED_PACKETS = 2000
"""Bound on packets held back by a delay fault, per direction (oldest dropped beyond it)."""


class MavlinkLink:
    """A MAVLink 2 endpoint (system ``system_id``, component 1 = autopilot) on a UDP socket.

    Not thread-safe: owned by the emulator thread.
    """

    def __init__(
        self,
        remote_port: int,
        system_id: int = 1,
        remote_host: str = "127.0.0.1",
        fault_delay_s: Callable[[float], float] | None = None,
        fault_drop: Callable[[float], bool] | None = None,
    ) -> None:
        self.remote = (remote_host, int(remote_port))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((remote_host, 0))
        self.sock.setblocking(False)
        self.mav = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=mavlink2.MAV_COMP_ID_AUTOPILOT1)
        self.mav.robust_parsing = True
        self._delay = fault_delay_s or (lambda _t: 0.0)
        self._drop = fault_drop or (lambda _t: False)
        self._tx_held: list[tuple[float, int, bytes]] = []
        self._rx_held: list[tuple[float, int, bytes]] = []
        self._counter = itertools.count()
        self.peer: tuple[str, int] | None = None
        self.rx_count = 0
        self.tx_count = 0

    @property
    def local_port(self) -> int:
        return int(self.sock.getsockname()[1])

    def fileno(self) -> int:
        return self.sock.fileno()

    def close(self) -> None:
        self.sock.close()

    # --- sending ---------------------------------------------------------------------------------
    def send(self, msg: mavlink2.MAVLink_message, t_mono_s: float) -> None:
        """Encode and send one message now, or later if a delay fault is active."""
        data = msg.pack(self.mav)
        if self._drop(t_mono_s):
            return
        delay = self._delay(t_mono_s)
        if delay > 0.0:
            self._hold(self._tx_held, t_mono_s + delay, data)
        else:
            self._sendto(data)

    def _sendto(self, data: bytes) -> None:
        try:
            self.sock.sendto(data, self.remote)
            self.tx_count += 1
        except OSError:  # ICMP port unreachable from an earlier send: nobody listening yet
            pass

    def _hold(self, heap: list[tuple[float, int, bytes]], t_release: float, data: bytes) -> None:
        heapq.heappush(heap, (t_release, next(self._counter), data))
        if len(heap) > MAX_DELAYED_PACKETS:
            heap.remove(min(heap, key=lambda e: e[1]))
            heapq.heapify(heap)

    def flush_delayed(self, t_mono_s: float) -> None:
        """Send held-back packets whose time has come."""
        while self._tx_held and self._tx_held[0][0] <= t_mono_s:
            self._sendto(heapq.heappop(self._tx_held)[2])

    # --- receiving -------------------------------------------------------------------------------
    def receive(self, t_mono_s: float) -> list[mavlink2.MAVLink_message]:
        """Read every waiting datagram (non-blocking) and return the messages due now."""
        due: list[bytes] = []
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # ECONNREFUSED surfaced from a previous send
                continue
            if self._drop(t_mono_s):
                continue
            self.peer = addr
            delay = self._delay(t_mono_s)
            if delay > 0.0:
                self._hold(self._rx_held, t_mono_s + delay, data)
            else:
                due.append(data)
        while self._rx_held and self._rx_held[0][0] <= t_mono_s:
            due.append(heapq.heappop(self._rx_held)[2])
        messages: list[mavlink2.MAVLink_message] = []
        for data in due:
            try:
                parsed = self.mav.parse_buffer(data) or []
            except mavlink2.MAVError:
                continue
            messages.extend(m for m in parsed if m.get_type() != "BAD_DATA")
        self.rx_count += len(messages)
        return messages
