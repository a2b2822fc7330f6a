"""A minimal raw-MAVLink ground station (pymavlink) for tests, benchmarks and poking the emulator.

It listens like ``udpin://127.0.0.1:<port>`` and answers the vehicle at the address the vehicle
sends from. Synchronous and single-threaded: every wait has a timeout (monotonic clock).
MAVSDK is the real client; this one exists to send what MAVSDK will not (e.g. a mode switch with
no setpoint stream) and to read replies without MAVSDK's retries in the way.
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable
from typing import Any

from sim_harness.px4.mavlink_io import mavlink2 as m
from sim_harness.px4.modes import AUTO_SUB_MODES, MAIN_MODES

__all__ = ["RawGcs"]


class RawGcs:
    """A GCS (system 255, component 190) on UDP ``127.0.0.1:port``."""

    def __init__(self, port: int, host: str = "127.0.0.1") -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.mav = m.MAVLink(None, srcSystem=255, srcComponent=m.MAV_COMP_ID_MISSIONPLANNER)
        self.mav.robust_parsing = True
        self.vehicle_addr: tuple[str, int] | None = None
        self.latest: dict[str, Any] = {}
        """The last message of each type received."""

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> RawGcs:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- receiving -----------------------------------------------------------------------------
    def _read(self, timeout_s: float) -> list[Any]:
        self.sock.settimeout(max(timeout_s, 1e-3))
        try:
            data, addr = self.sock.recvfrom(65535)
        except TimeoutError:
            return []
        self.vehicle_addr = addr
        msgs = [x for x in (self.mav.parse_buffer(data) or []) if x.get_type() != "BAD_DATA"]
        for x in msgs:
            self.latest[x.get_type()] = x
        return msgs

    def wait(self, kind: str, timeout_s: float, predicate: Callable[[Any], bool] | None = None) -> Any | None:
        """The next ``kind`` message (satisfying ``predicate``) within ``timeout_s``, else None."""
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            for x in self._read(left):
                if x.get_type() == kind and (predicate is None or predicate(x)):
                    return x
        return None

    def pump(self, duration_s: float) -> None:
        """Read for ``duration_s`` seconds, keeping :attr:`latest` current."""
        deadline = time.monotonic() + duration_s
        while (left := deadline - time.monotonic()) > 0:
            self._read(left)

    # --- sending -------------------------------------------------------------------------------
    def send(self, msg: Any) -> None:
        if self.vehicle_addr is None:
            self.wait("HEARTBEAT", 5.0)
        if self.vehicle_addr is None:
            raise TimeoutError("no HEARTBEAT from the vehicle")
        self.sock.sendto(msg.pack(self.mav), self.vehicle_addr)

    def command(self, command: int, *params: float, timeout_s: float = 1.0) -> int | None:
        """Send COMMAND_LONG (params default NaN) and return the COMMAND_ACK result, None if none."""
        p = [*params, *([math.nan] * (7 - len(params)))]
        self.send(m.MAVLink_command_long_message(1, 1, command, 0, *p))
        ack = self.wait("COMMAND_ACK", timeout_s, lambda a: a.command == command)
        return None if ack is None else int(ack.result)

    def set_mode(self, mode: str, timeout_s: float = 1.0) -> int | None:
        main, sub = (MAIN_MODES["AUTO"], AUTO_SUB_MODES[mode]) if mode in AUTO_SUB_MODES else (
            MAIN_MODES[mode], 0)
        return self.command(m.MAV_CMD_DO_SET_MODE, m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub,
                            timeout_s=timeout_s)

    def arm(self, arm: bool = True, timeout_s: float = 1.0) -> int | None:
        return self.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if arm else 0.0, timeout_s=timeout_s)

    def setpoint_ned(self, north_m: float, east_m: float, down_m: float, yaw_rad: float = 0.0) -> None:
        """One SET_POSITION_TARGET_LOCAL_NED with position and yaw only."""
        mask = 0b0000_1101_1111_1000  # ignore vel, acc, yaw rate; use position and yaw
        self.send(m.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, m.MAV_FRAME_LOCAL_NED, mask, north_m, east_m, down_m, 0, 0, 0, 0, 0, 0, yaw_rad, 0))

    def vision(self, north_m: float, east_m: float, down_m: float) -> None:
        """One VISION_POSITION_ESTIMATE (what a mocap bridge sends)."""
        self.send(m.MAVLink_vision_position_estimate_message(
            int(time.monotonic() * 1e6), north_m, east_m, down_m, 0.0, 0.0, 0.0))
