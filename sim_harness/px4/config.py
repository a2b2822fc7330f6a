"""Configuration of the emulated PX4 (one frozen dataclass, loadable from YAML)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal

import pydantic

from sim_harness.quad import QuadParams

__all__ = ["EmulatorConfig"]

_Pos = Annotated[float, pydantic.Field(gt=0)]


@dataclass(frozen=True)
class EmulatorConfig:
    """How the emulated PX4 talks and behaves. Defaults follow PX4's parameter defaults."""

    __pydantic_config__ = {"extra": "forbid"}  # config files: unknown keys are errors

    heartbeat_hz: Annotated[float, pydantic.Field(gt=0, le=100)] = 1.0
    """HEARTBEAT rate (Hz): PX4 sends 1 Hz; tests use 10 Hz to connect faster."""
    telemetry_hz: Annotated[float, pydantic.Field(gt=0, le=250)] = 50.0
    """Rate (Hz) of LOCAL_POSITION_NED, ATTITUDE_QUATERNION and ODOMETRY (unless a client sets an
    interval with SET_MESSAGE_INTERVAL)."""
    status_hz: Annotated[float, pydantic.Field(gt=0, le=50)] = 5.0
    """Rate (Hz) of SYS_STATUS, EXTENDED_SYS_STATE, HOME_POSITION and GLOBAL_POSITION_INT."""
    physics_hz: Annotated[float, pydantic.Field(ge=100, le=1000)] = 100.0
    """Integration rate (Hz) of the quad model in the emulator thread (>= 100)."""
    com_of_loss_t_s: _Pos = 1.0
    """COM_OF_LOSS_T (s): offboard setpoints missing this long in OFFBOARD triggers the failsafe."""
    offboard_loss_action: Literal["hold", "land"] = "hold"
    """COM_OBL_RC_ACT equivalent: the mode the offboard-loss failsafe switches to."""
    offboard_stream_window_s: _Pos = 0.5
    """A switch to OFFBOARD is refused unless a setpoint arrived within this many seconds."""
    vision_only: bool = False
    """Local position comes only from the companion's VISION_POSITION_ESTIMATE/ODOMETRY (mocap
    lab, EKF2_EV_CTRL): without them the position is invalid."""
    vision_timeout_s: _Pos = 0.5
    """In vision-only mode, position is invalid this long (s) after the last vision message."""
    takeoff_alt_m: _Pos = 2.5
    """MIS_TAKEOFF_ALT (m above the floor) used when NAV_TAKEOFF gives no altitude."""
    land_speed_m_s: _Pos = 0.7
    """MPC_LAND_SPEED (m/s): descent rate in LAND."""
    land_disarm_s: Annotated[float, pydantic.Field(ge=0)] = 2.0
    """COM_DISARM_LAND (s): auto-disarm this long after touchdown (after a flight)."""
    preflight_disarm_s: _Pos = 10.0
    """COM_DISARM_PRFLT (s): auto-disarm when armed this long without taking off."""
    max_yaw_rate_rad_s: _Pos = 1.57
    """Yaw rate limit (rad/s) while turning towards a yaw setpoint (MPC_YAWRAUTO_MAX-like)."""
    crash_speed_m_s: _Pos = 2.0
    """Hitting the floor faster than this (m/s, vertical) counts as a crash."""
    home_lat_deg: Annotated[float, pydantic.Field(ge=-90, le=90)] = 47.397742
    """Latitude (deg) of the world origin, for GLOBAL_POSITION_INT/HOME_POSITION (PX4 SITL's)."""
    home_lon_deg: Annotated[float, pydantic.Field(ge=-180, le=180)] = 8.545594
    """Longitude (deg) of the world origin."""
    home_amsl_m: float = 488.0
    """Altitude (m AMSL) of the world's z = 0."""
    system_id: Annotated[int, pydantic.Field(ge=1, le=255)] = 1
    """MAVLink system id of the vehicle (PX4: MAV_SYS_ID)."""
    quad: QuadParams = field(default_factory=QuadParams)
    """Tracking dynamics and collision radius of the quad (its dt_s is replaced by 1/physics_hz)."""
