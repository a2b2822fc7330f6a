"""The vehicle link: PX4 through MAVSDK's asyncio API (the real-vehicle boundary).

Everything above this module speaks the world frame (x forward, y left, z up, m; yaw CCW from +x,
rad). PX4 speaks NED/FRD; the conversion happens here and only here, through
:mod:`quadnav_onboard.frames`. Every command is bounded by ``asyncio.timeout``. Telemetry updates a
:class:`VehicleState` (latest value wins) that the supervisor reads; times are ``time.monotonic()``.

MAVSDK's offboard plugin also re-sends the last setpoint by itself; the daemon nevertheless streams
its own setpoints at a fixed rate and stops offboard (``stop_offboard``/``hold``) on every stop, so
a dead planner is caught by the supervisor and a hung process by the systemd watchdog (after which
PX4's offboard-loss failsafe takes over).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.frames import (
    enu_to_ned,
    ned_to_enu,
    quat_to_rotmat,
    quat_world_to_ned,
    yaw_enu_to_ned,
)
from quadnav_onboard.logs import get_logger
from quadnav_onboard.sources.base import OdometrySample

__all__ = ["MavsdkVehicle", "VehicleError", "VehicleLink", "VehicleState"]

log = get_logger("quadnav.vehicle")


class VehicleError(RuntimeError):
    """A vehicle command failed, was refused or timed out; the message says which."""


@dataclass
class VehicleState:
    """Latest telemetry from the autopilot (mutated in place by the telemetry task)."""

    connected: bool = False
    """An autopilot was found and has not timed out."""
    armed: bool = False
    """Motors armed."""
    mode: str = "UNKNOWN"
    """PX4 flight mode name: OFFBOARD, HOLD, LAND, POSCTL, MANUAL, TAKEOFF, ..."""
    local_position_ok: bool = False
    """PX4's local position estimate is valid (health)."""
    armable: bool = False
    """PX4's pre-arm checks pass (health)."""
    landed: bool | None = None
    """On the ground (landed state ON_GROUND); None until reported."""
    pos_world_m: NDArray[np.float64] = field(default_factory=lambda: np.full(3, np.nan))
    """PX4's position estimate (world, m), shape (3,)."""
    vel_world_m_s: NDArray[np.float64] = field(default_factory=lambda: np.full(3, np.nan))
    """PX4's velocity estimate (world, m/s), shape (3,)."""
    t_last_msg_mono_s: float = -math.inf
    """Monotonic time (s) of the newest message of any kind from the autopilot."""
    t_mode_mono_s: float = -math.inf
    """Monotonic time (s) of the newest mode report."""


@runtime_checkable
class VehicleLink(Protocol):
    """What the daemon needs from a vehicle. MAVSDK implements it; tests use fakes."""

    state: VehicleState

    async def connect(self) -> None:
        """Find the autopilot; raise VehicleError on timeout."""

    async def run_telemetry(self) -> None:
        """Keep :attr:`state` up to date until cancelled."""

    async def arm(self) -> None: ...

    async def disarm(self) -> None: ...

    async def start_offboard(self) -> None:
        """Switch to offboard (a setpoint must have been sent)."""

    async def stop_offboard(self) -> None: ...

    async def hold(self) -> None:
        """Switch to PX4 Hold (position hold where it is)."""

    async def land(self) -> None: ...

    async def set_setpoint(
        self, pos_world_m: NDArray[np.float64], vel_world_m_s: NDArray[np.float64], yaw_rad: float
    ) -> None:
        """Send one position (+ velocity feed-forward) and yaw setpoint, world frame."""

    async def send_vision_position(
        self, pos_world_m: NDArray[np.float64], quat_world_body: NDArray[np.float64], t_mono_s: float
    ) -> None:
        """Forward an external pose estimate (mocap) to PX4's estimator."""

    async def close(self) -> None: ...


class MavsdkVehicle:
    """:class:`VehicleLink` over MAVSDK (native asyncio binding) at ``url``."""

    def __init__(self, url: str, *, connect_timeout_s: float = 15.0, command_timeout_s: float = 5.0) -> None:
        self.url = url
        self.connect_timeout_s = connect_timeout_s
        self.command_timeout_s = command_timeout_s
        self.state = VehicleState()
        self._mavsdk = None
        self._telemetry = self._action = self._offboard = self._mocap = None

    async def connect(self) -> None:
        from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
        from mavsdk.asyncio.plugins.action import ActionAsync
        from mavsdk.asyncio.plugins.mocap import MocapAsync
        from mavsdk.asyncio.plugins.offboard import OffboardAsync
        from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

        cfg = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
        self._mavsdk = Mavsdk(cfg)
        try:
            async with asyncio.timeout(self.connect_timeout_s):
                await self._mavsdk.add_any_connection(self.url)
                system = await self._mavsdk.first_autopilot(timeout_s=self.connect_timeout_s)
        except TimeoutError:
            system = None
        except Exception as exc:
            raise VehicleError(f"vehicle.url {self.url!r}: cannot open the connection: {exc}") from exc
        if system is None:
            raise VehicleError(f"vehicle.url {self.url!r}: no autopilot within {self.connect_timeout_s:g} s")
        self._telemetry = TelemetryAsync(system)
        self._action = ActionAsync(system)
        self._offboard = OffboardAsync(system)
        self._mocap = MocapAsync(system)
        self.state.connected = True
        self.state.t_last_msg_mono_s = time.monotonic()
        log.info("vehicle_connected", url=self.url)

    # --- telemetry -------------------------------------------------------------------------

    async def run_telemetry(self) -> None:
        async with asyncio.TaskGroup() as tg:
            tg.create_task(self._watch_armed())
            tg.create_task(self._watch_mode())
            tg.create_task(self._watch_health())
            tg.create_task(self._watch_position())
            tg.create_task(self._watch_landed())

    def _touch(self) -> float:
        now = time.monotonic()
        self.state.t_last_msg_mono_s = now
        return now

    async def _watch_armed(self) -> None:
        async for armed in self._telemetry.subscribe_armed():
            self._touch()
            self.state.armed = bool(armed)

    async def _watch_mode(self) -> None:
        async for mode in self._telemetry.subscribe_flight_mode():
            self.state.t_mode_mono_s = self._touch()
            self.state.mode = getattr(mode, "name", str(mode))

    async def _watch_health(self) -> None:
        async for health in self._telemetry.subscribe_health():
            self._touch()
            self.state.local_position_ok = bool(health.is_local_position_ok)
            self.state.armable = bool(health.is_armable)

    async def _watch_position(self) -> None:
        async for pv in self._telemetry.subscribe_position_velocity_ned():
            self._touch()
            p, v = pv.position, pv.velocity
            self.state.pos_world_m = ned_to_enu([p.north_m, p.east_m, p.down_m])
            self.state.vel_world_m_s = ned_to_enu([v.north_m_s, v.east_m_s, v.down_m_s])

    async def _watch_landed(self) -> None:
        async for landed in self._telemetry.subscribe_landed_state():
            self._touch()
            self.state.landed = getattr(landed, "name", "") == "ON_GROUND"

    # --- commands --------------------------------------------------------------------------

    async def _command(self, name: str, coro_fn) -> None:
        if self._action is None:
            raise VehicleError(f"{name}: not connected")
        try:
            async with asyncio.timeout(self.command_timeout_s):
                await coro_fn()
        except TimeoutError:
            raise VehicleError(f"{name}: no answer within {self.command_timeout_s:g} s") from None
        except VehicleError:
            raise
        except Exception as exc:  # MAVSDK raises ActionError/OffboardError with the PX4 result
            raise VehicleError(f"{name}: refused: {exc}") from exc
        log.info("vehicle_command", command=name)

    async def arm(self) -> None:
        await self._command("arm", self._action.arm)

    async def disarm(self) -> None:
        await self._command("disarm", self._action.disarm)

    async def start_offboard(self) -> None:
        await self._command("offboard_start", self._offboard.start)

    async def stop_offboard(self) -> None:
        await self._command("offboard_stop", self._offboard.stop)

    async def hold(self) -> None:
        await self._command("hold", self._action.hold)

    async def land(self) -> None:
        await self._command("land", self._action.land)

    async def set_setpoint(
        self, pos_world_m: NDArray[np.float64], vel_world_m_s: NDArray[np.float64], yaw_rad: float
    ) -> None:
        from mavsdk.asyncio.plugins.offboard import PositionNedYaw, VelocityNedYaw

        n, e, d = (float(x) for x in enu_to_ned(pos_world_m))
        vn, ve, vd = (float(x) for x in enu_to_ned(vel_world_m_s))
        yaw_deg = math.degrees(float(yaw_enu_to_ned(yaw_rad)))
        # Sending a setpoint is one non-blocking MAVLink write in MAVSDK (no acknowledgement), so it
        # is called directly on the loop: a hop through the default executor cost ~1 ms of decision
        # latency under load (benchmarks/bench_daemon.py).
        try:
            self._offboard._plugin.set_position_velocity_ned(
                PositionNedYaw(n, e, d, yaw_deg), VelocityNedYaw(vn, ve, vd, yaw_deg)
            )
        except Exception as exc:
            raise VehicleError(f"setpoint: not sent: {exc}") from exc

    async def send_vision_position(
        self, pos_world_m: NDArray[np.float64], quat_world_body: NDArray[np.float64], t_mono_s: float
    ) -> None:
        from mavsdk.asyncio.plugins.mocap import AngleBody, Covariance, PositionBody, VisionPositionEstimate

        x, y, z = (float(v) for v in enu_to_ned(pos_world_m))
        r = quat_to_rotmat(quat_world_to_ned(quat_world_body))  # FRD body -> NED
        roll = math.atan2(r[2, 1], r[2, 2])
        pitch = -math.asin(max(-1.0, min(1.0, r[2, 0])))
        yaw = math.atan2(r[1, 0], r[0, 0])
        msg = VisionPositionEstimate(
            int(t_mono_s * 1e6), PositionBody(x, y, z), AngleBody(roll, pitch, yaw), Covariance([math.nan])
        )
        async with asyncio.timeout(self.command_timeout_s):
            await self._mocap.set_vision_position_estimate(msg)

    async def odometry_samples(self) -> AsyncIterator[OdometrySample]:
        """PX4's own estimate (ODOMETRY) as world-frame samples, stamped on arrival."""
        while self._telemetry is None:  # the daemon connects after the sources open
            await asyncio.sleep(0.05)
        async for odo in self._telemetry.subscribe_odometry():
            t = self._touch()
            p, q = odo.position_body, odo.q
            pos = ned_to_enu([p.x_m, p.y_m, p.z_m])
            quat = quat_world_to_ned([q.w, q.x, q.y, q.z])  # its own inverse: FRD/NED -> FLU/world
            yield OdometrySample(pos, quat, t)

    async def close(self) -> None:
        if self._mavsdk is not None:
            with contextlib.suppress(Exception):
                self._mavsdk.destroy()
            self._mavsdk = None
        self.state.connected = False
