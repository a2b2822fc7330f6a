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
    telemetry_hz: Annotated[float, pydantic.Field(gt=0, le=250)] = 30.0
    """Rate (Hz) of LOCAL_POSITION_NED, ATTITUDE_QUATERNION and ODOMETRY (unless a client sets an
    interval with SET_MESSAGE_INTERVAL). PX4 v1.16 SITL sent ODOMETRY at ~30 Hz on its API link;
    50 is the old idealised rate."""
    telemetry_jitter: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.5
    """Each fast message leaves up to this fraction of its interval late (uniform), on a regular
    grid: at 30 Hz, gaps of up to ~49 ms as measured on PX4 SITL. 0: the old idealised stream."""
    ground_offset_m: Annotated[float, pydantic.Field(ge=-10, le=10)] | None = None
    """PX4's local height (up, m) of the ground at boot: the estimator's origin is this far below
    the ground. None: drawn at boot, uniform in [-0.38, 0.33] m (PX4 SITL with
    ``EKF2_HGT_REF=1``, GPS, on the ground over 11 starts); 0: the old idealised ground at z = 0.
    Always 0 in ``vision_only`` mode (the vision frame is the height reference)."""
    seed: Annotated[int, pydantic.Field(ge=0, le=2**32 - 1)] | None = None
    """Seed of the emulator's random draws (ground offset, jitter); None: fresh entropy."""
    offboard_refusals: Annotated[int, pydantic.Field(ge=0, le=10)] = 0
    """Refuse the first this many switches to OFFBOARD although the setpoint stream is live (PX4
    SITL refused one start once in ten flights)."""
    status_hz: Annotated[float, pydantic.Field(gt=0, le=50)] = 5.0
    """Rate (Hz) of SYS_STATUS, EXTENDED_SYS_STATE, HOME_POSITION and GLOBAL_POSITION_INT."""
    physics_hz: Annotated[float, pydantic.Field(ge=100, le=1000)] = 100.0
    """Integration rate (Hz) of the quad model in the emulator thread (>= 100)."""
    com_of_loss_t_s: _Pos = 1.0
    """COM_OF_LOSS_T (s): offboard setpoints missing this long in OFFBOARD triggers the failsafe."""
    offboard_loss_action: Literal["px4", "hold", "land"] = "px4"
    """What the offboard-loss failsafe does. px4: PX4 v1.16 without RC (``COM_OBL_RC_ACT=0``,
    Position mode, unavailable without manual control): "Failsafe activated", hold for
    ``failsafe_delay_s``, then land and auto-disarm. hold / land: the old idealised switch to that
    mode at once."""
    failsafe_delay_s: Annotated[float, pydantic.Field(ge=0, le=60)] = 5.0
    """COM_FAIL_ACT_T (s): the failsafe holds this long before its action (px4 action only)."""
    companion_loss_s: Annotated[float, pydantic.Field(gt=0, le=60)] = 5.0
    """COM_OBC_LOSS_T (s): no heartbeat from the companion this long after one was heard announces
    "Connection to mission computer lost"."""
    rc_in_mode: Annotated[int, pydantic.Field(ge=0, le=4)] = 1
    """COM_RC_IN_MODE reported as a parameter (SITL default 1; the emulator has no RC either way)."""
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

    @classmethod
    def idealised(cls, **overrides: object) -> EmulatorConfig:
        """The emulator before it followed PX4 SITL: ground at z = 0, 50 Hz telemetry without
        jitter, the offboard-loss failsafe switching to HOLD at once (``overrides`` win)."""
        ideal: dict[str, object] = {"ground_offset_m": 0.0, "telemetry_hz": 50.0, "telemetry_jitter": 0.0,
                                    "offboard_loss_action": "hold"}
        return cls(**{**ideal, **overrides})  # type: ignore[arg-type]
