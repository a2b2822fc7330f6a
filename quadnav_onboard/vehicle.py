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
import enum
import json
import math
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.frames import (
    flu_to_frd,
    frd_to_flu,
    quat_to_rotmat,
    quat_world_to_ned,
    yaw_flu_to_frd,
)
from quadnav_onboard.logs import get_logger
from quadnav_onboard.sources.base import OdometrySample
from quadnav_onboard.vehicle_binding import (
    Binding,
    BindingError,
    Candidate,
    LinkGuard,
    SourceChange,
    guarded_address,
)

__all__ = [
    "MAV_STATE_EMERGENCY",
    "MavsdkVehicle",
    "Px4Setup",
    "VehicleError",
    "VehicleErrorKind",
    "VehicleLink",
    "VehicleState",
]

log = get_logger("quadnav.vehicle")


MAV_STATE_EMERGENCY = 6
"""HEARTBEAT system_status of a vehicle in an emergency (PX4: crashed, flight termination)."""


class VehicleErrorKind(enum.Enum):
    """Why a vehicle call failed."""

    NOT_CONNECTED = "not_connected"
    TIMEOUT = "timeout"
    REFUSED = "refused"
    NOT_SENT = "not_sent"
    """A message (setpoint, vision estimate) could not be handed to the link."""
    BINDING = "binding"
    """Not exactly one autopilot on the link: the daemon refuses to pick one."""
    CONNECT = "connect"
    """The connection could not be opened, or no autopilot answered."""


class VehicleError(RuntimeError):
    """A vehicle command failed, was refused or timed out; ``kind`` says which, ``result`` names
    MAVSDK's result (e.g. ``NO_SETPOINT_SET``, ``COMMAND_DENIED``) when it gave one."""

    def __init__(
        self, message: str, kind: VehicleErrorKind = VehicleErrorKind.REFUSED, result: str | None = None
    ) -> None:
        super().__init__(message)
        self.kind = kind
        self.result = result


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
    t_position_mono_s: float = -math.inf
    """Monotonic time (s) the newest position estimate arrived."""
    t_last_msg_mono_s: float = -math.inf
    """Monotonic time (s) of the newest message of any kind from the autopilot."""
    t_mode_mono_s: float = -math.inf
    """Monotonic time (s) of the newest mode report."""
    binding: Binding | None = None
    """The one autopilot flown (system, component, the address first heard from); None on links
    the daemon does not own (serial, TCP)."""
    source_changed: SourceChange | None = None
    """Set when the bound system ID was heard from another address (a link fault)."""
    other_autopilots: tuple[Candidate, ...] = ()
    """Autopilots of other system IDs heard on the link after binding (never relayed)."""
    tilt_rad: float = math.nan
    """Angle (rad) between the body's up axis and the vertical, from the attitude telemetry; NaN
    until reported."""
    system_status: int | None = None
    """HEARTBEAT system_status (MAV_STATE) of the autopilot; None until reported."""
    px4_time: tuple[float, int, int] | None = None
    """Newest SYSTEM_TIME: (arrival, monotonic s; PX4's time since boot, us; PX4's UTC, us, 0 when
    unknown); None until reported. Lines the flight record up with PX4's ULog."""


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


@runtime_checkable
class Px4Setup(Protocol):
    """What preflight asks of a PX4 link beyond :class:`VehicleLink` (MAVSDK implements it)."""

    async def request_telemetry_rates(self, rate_hz: float) -> None:
        """Ask PX4 for ODOMETRY and LOCAL_POSITION_NED at ``rate_hz``; VehicleError if refused."""

    async def read_parameters(self, names: dict[str, str]) -> dict[str, float | None]:
        """Read each ``name -> "int" | "float"`` parameter; None for one PX4 did not answer."""


def _result_name(exc: BaseException) -> str | None:
    """The name of the result enum a MAVSDK error carries (its first argument), else None."""
    first = exc.args[0] if exc.args else None
    return first.name if isinstance(first, enum.Enum) else None


MAVSDK_VERSION = "4.1.0"
"""The MAVSDK release :func:`_sync_setpoint_sender` is written against (pinned in pyproject.toml)."""


def _sync_setpoint_sender(offboard: Any) -> Callable[[Any, Any], Any]:
    """The synchronous ``set_position_velocity_ned`` under MAVSDK's ``OffboardAsync``.

    ``OffboardAsync`` (mavsdk 4.1.0) holds the ctypes plugin as ``_plugin`` and sends each setpoint
    through ``run_in_executor``; the daemon calls the plugin itself to save that thread hop. The
    attribute is private, so mavsdk is pinned exactly and its presence is checked here, at connect,
    before anything can arm: a MAVSDK without it is refused with the version that has it.
    """
    send = getattr(getattr(offboard, "_plugin", None), "set_position_velocity_ned", None)
    if not callable(send):
        try:
            from importlib.metadata import version

            installed = version("mavsdk")
        except Exception:  # not installed as a distribution (a source checkout)
            installed = "unknown"
        raise VehicleError(
            f"mavsdk {installed}: OffboardAsync has no synchronous set_position_velocity_ned "
            f"(_plugin); quadnav needs mavsdk=={MAVSDK_VERSION} (pip install 'mavsdk=={MAVSDK_VERSION}')",
            VehicleErrorKind.CONNECT,
        )
    return send


class MavsdkVehicle:
    """:class:`VehicleLink` over MAVSDK (native asyncio binding) at ``url``."""

    def __init__(
        self,
        url: str,
        *,
        connect_timeout_s: float = 15.0,
        command_timeout_s: float = 5.0,
        bind_listen_s: float = 1.2,
    ) -> None:
        self.url = url
        self.connect_timeout_s = connect_timeout_s
        self.command_timeout_s = command_timeout_s
        self.bind_listen_s = bind_listen_s
        """How long (s) after the first autopilot is heard the link is listened to for others."""
        self.state = VehicleState()
        self._mavsdk = None
        self._guard: LinkGuard | None = None
        self._telemetry = self._action = self._offboard = self._mocap = self._direct = None
        self._param: Any = None
        self._send_setpoint: Callable[[Any, Any], Any] | None = None

    async def connect(self) -> None:
        """Bind to the one autopilot on the link (see :mod:`quadnav_onboard.vehicle_binding`), then
        connect MAVSDK to it. Raises VehicleError: kind BINDING when more than one answers."""
        from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
        from mavsdk.asyncio.plugins.action import ActionAsync
        from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
        from mavsdk.asyncio.plugins.mocap import MocapAsync
        from mavsdk.asyncio.plugins.offboard import OffboardAsync
        from mavsdk.asyncio.plugins.param import ParamAsync
        from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

        url = await self._bind()
        cfg = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
        self._mavsdk = Mavsdk(cfg)
        try:
            async with asyncio.timeout(self.connect_timeout_s):
                await self._mavsdk.add_any_connection(url)
                system = await self._mavsdk.first_autopilot(timeout_s=self.connect_timeout_s)
                if self._guard is None and system is not None:
                    await self._refuse_merged_systems()
        except TimeoutError:
            system = None
        except VehicleError:
            raise
        except Exception as exc:
            raise VehicleError(
                f"vehicle.url {self.url!r}: cannot open the connection: {exc}", VehicleErrorKind.CONNECT
            ) from exc
        if system is None:
            raise VehicleError(
                f"vehicle.url {self.url!r}: no autopilot within {self.connect_timeout_s:g} s",
                VehicleErrorKind.CONNECT,
            )
        self._telemetry = TelemetryAsync(system)
        self._action = ActionAsync(system)
        self._offboard = OffboardAsync(system)
        self._send_setpoint = _sync_setpoint_sender(self._offboard)
        # MAVSDK answers PX4's TIMESYNC and converts the forwarded vision estimates' time_usec
        # (this process's monotonic clock) into PX4's time base (docs/hardware.md, section 5).
        await system.enable_timesync()
        self._mocap = MocapAsync(system)
        self._direct = MavlinkDirectAsync(system)
        self._param = ParamAsync(system)
        self.state.connected = True
        self.state.t_last_msg_mono_s = time.monotonic()
        log.info("vehicle_connected", url=self.url, vehicle=str(self.state.binding or "(link not owned)"))

    async def _bind(self) -> str:
        """On a udpin:// link, own the port and bind to its one autopilot; the URL MAVSDK uses."""
        if guarded_address(self.url) is None:
            return self.url
        self._guard = LinkGuard(self.url, listen_s=self.bind_listen_s)
        try:
            self.state.binding = await self._guard.bind(self.connect_timeout_s)
        except BindingError as exc:
            raise VehicleError(str(exc), VehicleErrorKind.BINDING) from exc
        except TimeoutError:
            raise VehicleError(
                f"vehicle.url {self.url!r}: no autopilot within {self.connect_timeout_s:g} s",
                VehicleErrorKind.CONNECT,
            ) from None
        except OSError as exc:
            raise VehicleError(
                f"vehicle.url {self.url!r}: cannot open the connection: {exc}", VehicleErrorKind.CONNECT
            ) from exc
        return self._guard.mavsdk_url

    async def _refuse_merged_systems(self) -> None:
        """On a link the daemon does not own (serial, TCP), MAVSDK's own view: refuse when it
        reports more than one autopilot system after the listening window."""
        await asyncio.sleep(self.bind_listen_s)
        autopilots = [s for s in await self._mavsdk.get_systems() if await s.has_autopilot()]
        if len(autopilots) > 1:
            ids = [await s.get_system_id() for s in autopilots]
            raise VehicleError(
                f"vehicle.url {self.url!r}: {len(ids)} autopilots answer on the link (system IDs {ids}); "
                "refusing to pick one",
                VehicleErrorKind.BINDING,
            )

    # --- telemetry -------------------------------------------------------------------------

    async def run_telemetry(self) -> None:
        async with asyncio.TaskGroup() as tg:
            tg.create_task(self._watch_armed())
            tg.create_task(self._watch_mode())
            tg.create_task(self._watch_health())
            tg.create_task(self._watch_position())
            tg.create_task(self._watch_landed())
            tg.create_task(self._watch_attitude())
            tg.create_task(self._watch_heartbeat())
            tg.create_task(self._watch_system_time())
            if self._guard is not None:
                tg.create_task(self._watch_source())

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
            self.state.t_position_mono_s = self._touch()
            p, v = pv.position, pv.velocity
            self.state.pos_world_m = frd_to_flu([p.north_m, p.east_m, p.down_m])
            self.state.vel_world_m_s = frd_to_flu([v.north_m_s, v.east_m_s, v.down_m_s])

    async def _watch_landed(self) -> None:
        async for landed in self._telemetry.subscribe_landed_state():
            self._touch()
            self.state.landed = getattr(landed, "name", "") == "ON_GROUND"

    async def _watch_attitude(self) -> None:
        async for q in self._telemetry.subscribe_attitude_quaternion():
            self._touch()
            r = quat_to_rotmat([q.w, q.x, q.y, q.z])  # FRD body -> NED
            self.state.tilt_rad = math.acos(max(-1.0, min(1.0, float(r[2, 2]))))

    async def _watch_heartbeat(self) -> None:
        """The autopilot's own state (MAV_STATE) from its heartbeats (MAVSDK's telemetry has none)."""
        async for msg in self._direct.subscribe_message("HEARTBEAT"):
            if msg.component_id != 1:
                continue
            with contextlib.suppress(ValueError, KeyError, TypeError):
                self.state.system_status = int(json.loads(msg.fields_json)["system_status"])

    async def _watch_system_time(self) -> None:
        """PX4's clock (SYSTEM_TIME, ~1 Hz) for the flight record; a failure only logs."""
        try:
            async for msg in self._direct.subscribe_message("SYSTEM_TIME"):
                t = time.monotonic()
                with contextlib.suppress(ValueError, KeyError, TypeError):
                    f = json.loads(msg.fields_json)
                    self.state.px4_time = (t, int(f["time_boot_ms"]) * 1000, int(f["time_unix_usec"]))
        except Exception as exc:  # the record's PX4 clock is not worth the telemetry task group
            log.warning("px4_time_unavailable", error=f"{type(exc).__name__}: {exc}")

    async def _watch_source(self) -> None:
        """Copy the guard's verdict on the link's source into the state (checked in flight)."""
        guard = self._guard
        assert guard is not None
        while self.state.source_changed is None:
            await asyncio.sleep(0.02)
            self.state.source_changed = guard.source_changed
            if len(guard.foreign) != len(self.state.other_autopilots):
                self.state.other_autopilots = tuple(guard.foreign)

    # --- commands --------------------------------------------------------------------------

    async def _command(self, name: str, coro_fn) -> None:
        if self._action is None:
            raise VehicleError(f"{name}: not connected", VehicleErrorKind.NOT_CONNECTED)
        try:
            async with asyncio.timeout(self.command_timeout_s):
                await coro_fn()
        except TimeoutError:
            raise VehicleError(
                f"{name}: no answer within {self.command_timeout_s:g} s", VehicleErrorKind.TIMEOUT
            ) from None
        except VehicleError:
            raise
        except Exception as exc:  # MAVSDK raises ActionError/OffboardError with the PX4 result
            result = _result_name(exc)
            raise VehicleError(f"{name}: refused: {result or exc}", VehicleErrorKind.REFUSED, result) from exc
        log.info("vehicle_command", command=name)

    async def request_telemetry_rates(self, rate_hz: float) -> None:
        """Ask PX4 for ODOMETRY and LOCAL_POSITION_NED at ``rate_hz`` (SET_MESSAGE_INTERVAL
        through MAVSDK's telemetry rate setters)."""
        if self._telemetry is None:
            raise VehicleError("telemetry rates: not connected", VehicleErrorKind.NOT_CONNECTED)
        tel = self._telemetry
        await self._command("set_rate_odometry", lambda: tel.set_rate_odometry(float(rate_hz)))
        await self._command("set_rate_position_velocity_ned",
                            lambda: tel.set_rate_position_velocity_ned(float(rate_hz)))

    async def read_parameters(self, names: dict[str, str]) -> dict[str, float | None]:
        """Each ``name -> "int" | "float"`` parameter over MAVLink (PARAM_REQUEST_READ through
        MAVSDK's param plugin), one at a time, each bounded by ``command_timeout_s``; None for a
        parameter PX4 did not answer or that has another type."""
        if self._param is None:
            raise VehicleError("parameters: not connected", VehicleErrorKind.NOT_CONNECTED)
        values: dict[str, float | None] = {}
        for name, kind in names.items():
            get = self._param.get_param_int if kind == "int" else self._param.get_param_float
            try:
                async with asyncio.timeout(self.command_timeout_s):
                    values[name] = float(await get(name))
            except Exception as exc:  # TimeoutError, ParamError (unknown name, wrong type)
                why = _result_name(exc) or str(exc)
                log.warning("parameter_not_read", name=name, error=f"{type(exc).__name__}: {why}")
                values[name] = None
        return values

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

        n, e, d = (float(x) for x in flu_to_frd(pos_world_m))
        vn, ve, vd = (float(x) for x in flu_to_frd(vel_world_m_s))
        yaw_deg = math.degrees(float(yaw_flu_to_frd(yaw_rad)))
        if self._send_setpoint is None:
            raise VehicleError("setpoint: not connected", VehicleErrorKind.NOT_CONNECTED)
        # Sending a setpoint is one non-blocking MAVLink write in MAVSDK (no acknowledgement), so it
        # is called directly on the loop: a hop through the default executor cost ~1 ms of decision
        # latency under load (benchmarks/bench_daemon.py). See _sync_setpoint_sender.
        try:
            self._send_setpoint(PositionNedYaw(n, e, d, yaw_deg), VelocityNedYaw(vn, ve, vd, yaw_deg))
        except Exception as exc:
            raise VehicleError(f"setpoint: not sent: {exc}", VehicleErrorKind.NOT_SENT) from exc

    async def send_vision_position(
        self, pos_world_m: NDArray[np.float64], quat_world_body: NDArray[np.float64], t_mono_s: float
    ) -> None:
        from mavsdk.asyncio.plugins.mocap import AngleBody, Covariance, PositionBody, VisionPositionEstimate

        x, y, z = (float(v) for v in flu_to_frd(pos_world_m))
        r = quat_to_rotmat(quat_world_to_ned(quat_world_body))  # FRD body -> NED
        roll = math.atan2(r[2, 1], r[2, 2])
        pitch = -math.asin(max(-1.0, min(1.0, r[2, 0])))
        yaw = math.atan2(r[1, 0], r[0, 0])
        msg = VisionPositionEstimate(
            int(t_mono_s * 1e6), PositionBody(x, y, z), AngleBody(roll, pitch, yaw), Covariance([math.nan])
        )
        if self._mocap is None:
            raise VehicleError("vision estimate: not connected", VehicleErrorKind.NOT_CONNECTED)
        try:
            async with asyncio.timeout(self.command_timeout_s):
                await self._mocap.set_vision_position_estimate(msg)
        except TimeoutError:
            raise VehicleError(
                f"vision estimate: not sent within {self.command_timeout_s:g} s", VehicleErrorKind.TIMEOUT
            ) from None
        except Exception as exc:  # MAVSDK's MocapError (and anything else the binding raises)
            raise VehicleError(f"vision estimate: not sent: {exc}", VehicleErrorKind.NOT_SENT) from exc

    async def odometry_samples(self) -> AsyncIterator[OdometrySample]:
        """PX4's own estimate (ODOMETRY) as world-frame samples, stamped on arrival."""
        while self._telemetry is None:  # the daemon connects after the sources open
            await asyncio.sleep(0.05)
        async for odo in self._telemetry.subscribe_odometry():
            t = self._touch()
            p, q = odo.position_body, odo.q
            pos = frd_to_flu([p.x_m, p.y_m, p.z_m])
            quat = quat_world_to_ned([q.w, q.x, q.y, q.z])  # its own inverse: FRD/NED -> FLU/world
            yield OdometrySample(pos, quat, t)

    async def close(self) -> None:
        if self._mavsdk is not None:
            with contextlib.suppress(Exception):
                self._mavsdk.destroy()
            self._mavsdk = None
        if self._guard is not None:
            self._guard.close()
            self._guard = None
            await asyncio.sleep(0)  # let the transports release the port
        self.state.connected = False
