"""What the emulated PX4 reports: pure builders of MAVLink messages from the vehicle's state.

World positions (x fwd, y left, z up) are converted to PX4's NED local frame only through
:mod:`quadnav_onboard.frames`; the local NED origin is the world origin (a mocap lab's frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.frames import flu_to_frd, quat_from_yaw, quat_world_to_ned, yaw_flu_to_frd
from sim_harness.px4.config import EmulatorConfig
from sim_harness.px4.mavlink_io import mavlink2 as m
from sim_harness.px4.modes import encode_custom_mode

__all__ = [
    "LANDED_STATE_CODES",
    "SENSORS_PRESENT",
    "TruePose",
    "VehicleSnapshot",
    "attitude_quaternion",
    "autopilot_version",
    "extended_sys_state",
    "global_position_int",
    "heartbeat",
    "home_position",
    "local_position_ned",
    "odometry",
    "sys_status",
    "world_to_global",
]

_EARTH_RADIUS_M = 6_371_000.0

LANDED_STATE_CODES = {"ON_GROUND": 1, "IN_AIR": 2, "TAKING_OFF": 3, "LANDING": 4}
"""MAV_LANDED_STATE values by name."""

SENSORS_PRESENT = (
    m.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | m.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | m.MAV_SYS_STATUS_SENSOR_3D_MAG
    | m.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | m.MAV_SYS_STATUS_SENSOR_VISION_POSITION
    | m.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | m.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | m.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | m.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | m.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | m.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | m.MAV_SYS_STATUS_AHRS
    | m.MAV_SYS_STATUS_PREARM_CHECK
)
"""SYS_STATUS sensor bits of a mocap-lab quad: no GPS; local position = the vision bit."""

_POSITION_BITS = m.MAV_SYS_STATUS_SENSOR_VISION_POSITION | m.MAV_SYS_STATUS_PREARM_CHECK


@dataclass(frozen=True)
class TruePose:
    """Ground truth of the simulated vehicle (world frame: x fwd, y left, z up)."""

    pos_world_m: NDArray[np.float64]
    """Position (m), shape (3,)."""
    vel_world_m_s: NDArray[np.float64]
    """Velocity (m/s), shape (3,)."""
    quat_world_body: NDArray[np.float64]
    """Attitude (w, x, y, z), body FLU -> world, shape (4,)."""
    t_mono_s: float
    """When this pose was true (time.monotonic() s)."""


@dataclass(frozen=True)
class VehicleSnapshot:
    """What the telemetry builders need, captured once per emulator tick."""

    t_boot_ms: int
    pos_world_m: NDArray[np.float64]
    vel_world_m_s: NDArray[np.float64]
    yaw_rad: float
    armed: bool
    mode: str
    crashed: bool
    landed_state: str
    position_valid: bool
    home_world_m: NDArray[np.float64]
    local_offset_m: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    """Estimator-local minus world position (m), shape (3,): the estimator's origin (PX4 on GPS
    height: not the ground)."""


def heartbeat(s: VehicleSnapshot) -> m.MAVLink_message:
    base = (
        m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        | m.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        | m.MAV_MODE_FLAG_STABILIZE_ENABLED
        | m.MAV_MODE_FLAG_GUIDED_ENABLED
    )
    if s.armed:
        base |= m.MAV_MODE_FLAG_SAFETY_ARMED
    state = m.MAV_STATE_EMERGENCY if s.crashed else m.MAV_STATE_ACTIVE if s.armed else m.MAV_STATE_STANDBY
    return m.MAVLink_heartbeat_message(
        m.MAV_TYPE_QUADROTOR, m.MAV_AUTOPILOT_PX4, base, encode_custom_mode(s.mode), state, 3
    )


def system_time(s: VehicleSnapshot, unix_time_s: float) -> m.MAVLink_message:
    """PX4's clock: its UTC (``unix_time_s``, the host's, as SITL takes it) and its time since boot."""
    return m.MAVLink_system_time_message(int(unix_time_s * 1e6), s.t_boot_ms & 0xFFFFFFFF)


def _quat_ned(yaw_rad: float) -> list[float]:
    return [float(v) for v in quat_world_to_ned(quat_from_yaw(yaw_rad))]


_ON_ITS_SIDE = np.array([math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0])
"""Rolled 90 deg about the body's x axis (w, x, y, z): how a crashed quad lies."""


def _attitude_world(s: VehicleSnapshot) -> NDArray[np.float64]:
    """Body FLU -> world quaternion (w, x, y, z): level at the yaw in flight, on its side once
    crashed (what a real vehicle's attitude estimate shows after an impact)."""
    q = quat_from_yaw(s.yaw_rad)
    if not s.crashed:
        return q
    w1, x1, y1, z1 = q
    w2, x2, y2, z2 = _ON_ITS_SIDE
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def local_position_ned(s: VehicleSnapshot) -> m.MAVLink_message:
    p, v = flu_to_frd(s.pos_world_m + s.local_offset_m), flu_to_frd(s.vel_world_m_s)
    return m.MAVLink_local_position_ned_message(s.t_boot_ms, *map(float, p), *map(float, v))


def attitude_quaternion(s: VehicleSnapshot) -> m.MAVLink_message:
    q = [float(v) for v in quat_world_to_ned(_attitude_world(s))]
    return m.MAVLink_attitude_quaternion_message(s.t_boot_ms, *q, 0.0, 0.0, 0.0)


def odometry(s: VehicleSnapshot) -> m.MAVLink_message:
    """ODOMETRY in LOCAL_NED with the velocity in the body FRD frame (as PX4 sends it)."""
    p = flu_to_frd(s.pos_world_m + s.local_offset_m)
    yaw_ned = float(yaw_flu_to_frd(s.yaw_rad))
    v_ned = flu_to_frd(s.vel_world_m_s)
    c, sn = math.cos(yaw_ned), math.sin(yaw_ned)
    v_frd = [c * v_ned[0] + sn * v_ned[1], -sn * v_ned[0] + c * v_ned[1], v_ned[2]]
    nan21 = [math.nan] * 21
    return m.MAVLink_odometry_message(
        s.t_boot_ms * 1000, m.MAV_FRAME_LOCAL_NED, m.MAV_FRAME_BODY_FRD, *map(float, p),
        _quat_ned(s.yaw_rad), *map(float, v_frd), 0.0, 0.0, 0.0, nan21, nan21, 0,
        m.MAV_ESTIMATOR_TYPE_VISION, 100 if s.position_valid else 0,
    )


def sys_status(s: VehicleSnapshot) -> m.MAVLink_message:
    health = SENSORS_PRESENT if s.position_valid and not s.crashed else SENSORS_PRESENT & ~_POSITION_BITS
    return m.MAVLink_sys_status_message(
        SENSORS_PRESENT, SENSORS_PRESENT, health, 100, 16000, 500, 80, 0, 0, 0, 0, 0, 0
    )


def extended_sys_state(s: VehicleSnapshot) -> m.MAVLink_message:
    landed = LANDED_STATE_CODES[s.landed_state]
    return m.MAVLink_extended_sys_state_message(m.MAV_VTOL_STATE_UNDEFINED, landed)


def world_to_global(pos_world_m: NDArray[np.float64], cfg: EmulatorConfig) -> tuple[float, float, float]:
    """(lat_deg, lon_deg, alt_amsl_m) of a world position, flat-earth about the world origin."""
    north, east, down = (float(v) for v in flu_to_frd(pos_world_m))
    lat = cfg.home_lat_deg + math.degrees(north / _EARTH_RADIUS_M)
    lon = cfg.home_lon_deg + math.degrees(east / (_EARTH_RADIUS_M * math.cos(math.radians(cfg.home_lat_deg))))
    return lat, lon, cfg.home_amsl_m - down


def global_position_int(s: VehicleSnapshot, cfg: EmulatorConfig) -> m.MAVLink_message:
    lat, lon, alt = world_to_global(s.pos_world_m, cfg)
    rel_alt = float(s.pos_world_m[2] - s.home_world_m[2])
    v = flu_to_frd(s.vel_world_m_s) * 100.0
    hdg = round(math.degrees(float(yaw_flu_to_frd(s.yaw_rad))) % 360.0 * 100) % 36000
    return m.MAVLink_global_position_int_message(
        s.t_boot_ms, int(lat * 1e7), int(lon * 1e7), int(alt * 1000), int(rel_alt * 1000),
        int(v[0]), int(v[1]), int(v[2]), hdg,
    )


def home_position(s: VehicleSnapshot, cfg: EmulatorConfig) -> m.MAVLink_message:
    lat, lon, alt = world_to_global(s.home_world_m, cfg)
    p = flu_to_frd(s.home_world_m + s.local_offset_m)
    return m.MAVLink_home_position_message(
        int(lat * 1e7), int(lon * 1e7), int(alt * 1000), *map(float, p), [1.0, 0.0, 0.0, 0.0],
        0.0, 0.0, 0.0, s.t_boot_ms * 1000,
    )


def autopilot_version(system_id: int) -> m.MAVLink_message:
    caps = (
        m.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        | m.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
        | m.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
        | m.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
        | m.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    )
    px4_v1_15 = (1 << 24) | (15 << 16) | (0 << 8) | 255  # major.minor.patch.type(official)
    return m.MAVLink_autopilot_version_message(
        caps, px4_v1_15, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0x26AC, 0x11, 0x5EED0000 + system_id, [0] * 18
    )
