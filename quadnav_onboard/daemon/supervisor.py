"""The safety supervisor: why a flight stops, pre-flight checks, in-flight checks.

Pure functions of their inputs (times are passed in, never read here), so every check is unit
tested with fake time. The daemon calls :func:`check_in_flight` at ``safety.check_rate_hz`` and
acts on the first reason it returns; the order below is the priority.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.daemon.config import SafetyConfig
from quadnav_onboard.preprocess import DepthFrameError, PreprocessConfig, preprocess_depth_mm
from quadnav_onboard.sources.base import DepthFrame, OdometrySample
from quadnav_onboard.vehicle import VehicleState

__all__ = [
    "ExitCode",
    "FlightSnapshot",
    "PreflightCheck",
    "PreflightError",
    "Response",
    "StopReason",
    "check_depth_frame",
    "check_in_flight",
    "check_odometry",
    "check_vehicle_ready",
    "response_for",
]


class ExitCode(enum.IntEnum):
    """Process exit codes of ``quadnav-onboard`` (documented in docs/daemon.md)."""

    SUCCESS = 0
    """Goal reached (and landed or holding as configured)."""
    ERROR = 1
    """Unexpected internal error (a bug); the vehicle was commanded to hold/land if it flew."""
    REFUSED = 2
    """Bad config, bad model or a failed pre-flight check: nothing armed."""
    SAFE_ABORT = 3
    """The supervisor or the operator stopped the flight; it ended holding or landed."""
    CRASH = 4
    """A collision was reported (dry run: the emulator's crash)."""


class StopReason(enum.Enum):
    """Why a flight ended; written into every log line and record that ends a flight."""

    GOAL_REACHED = "goal_reached"
    STEP_LIMIT = "step_limit"
    CRASH = "crash"
    LINK_LOST = "link_lost"
    PILOT_TAKEOVER = "pilot_takeover"
    DISARMED = "disarmed"
    STALE_ODOMETRY = "stale_odometry"
    BAD_ODOMETRY = "bad_odometry"
    STALE_DEPTH = "stale_depth"
    BAD_DEPTH = "bad_depth"
    GEOFENCE = "geofence"
    ALTITUDE = "altitude"
    DEVIATION = "deviation"
    INFERENCE_OVERRUN = "inference_overrun"
    TAKEOFF_TIMEOUT = "takeoff_timeout"
    OPERATOR_STOP = "operator_stop"
    VEHICLE_ERROR = "vehicle_error"
    PREFLIGHT_FAILED = "preflight_failed"
    INTERNAL_ERROR = "internal_error"

    @property
    def exit_code(self) -> ExitCode:
        if self is StopReason.GOAL_REACHED:
            return ExitCode.SUCCESS
        if self is StopReason.CRASH:
            return ExitCode.CRASH
        if self is StopReason.PREFLIGHT_FAILED:
            return ExitCode.REFUSED
        if self is StopReason.INTERNAL_ERROR:
            return ExitCode.ERROR
        return ExitCode.SAFE_ABORT


class Response(enum.Enum):
    """What the daemon commands after a stop."""

    LADDER = "ladder"
    """Stop streaming, hold, then land (if configured), then disarm (if configured)."""
    RELEASE = "release"
    """Stop commanding at all: the pilot or PX4's own failsafe is in charge; never fight back."""


def response_for(reason: StopReason) -> Response:
    """Pilot takeover and link loss release the vehicle; everything else climbs the ladder."""
    if reason in (StopReason.PILOT_TAKEOVER, StopReason.LINK_LOST, StopReason.DISARMED):
        return Response.RELEASE
    return Response.LADDER


@dataclass(frozen=True)
class FlightSnapshot:
    """What the supervisor looks at, sampled at one instant (monotonic seconds)."""

    t_mono_s: float
    """Now."""
    vehicle: VehicleState
    """Latest autopilot telemetry."""
    t_depth_mono_s: float
    """Capture time of the newest depth frame (-inf if none)."""
    t_odom_mono_s: float
    """Arrival time of the newest odometry sample (-inf if none)."""
    pos_world_m: NDArray[np.float64]
    """Newest odometry position (world, m), shape (3,)."""
    deviation_m: float
    """Distance (m) from the rough path."""
    in_mission: bool
    """True once the mission began (altitude floor and deviation apply from then on)."""
    expected_mode: str = "OFFBOARD"
    """Mode the daemon put the vehicle in."""
    inference_s: float = 0.0
    """Duration (s) of the decision in progress (0 when none runs) or of the last one."""
    crashed: bool = False
    """A collision was reported."""
    depth_error: str | None = None
    """The newest depth frame was unusable (message), else None."""


def check_in_flight(s: FlightSnapshot, cfg: SafetyConfig) -> tuple[StopReason, str] | None:
    """The first reason to stop now, with a message; None when all is well. Order = priority."""
    v = s.vehicle
    if s.crashed:
        return StopReason.CRASH, "collision reported"
    link_age = s.t_mono_s - v.t_last_msg_mono_s
    if link_age > cfg.link_timeout_s:
        return StopReason.LINK_LOST, f"nothing from the vehicle for {link_age:.2f} s > {cfg.link_timeout_s} s"
    if not v.armed:
        return StopReason.DISARMED, "the vehicle disarmed"
    if v.mode != s.expected_mode:
        return StopReason.PILOT_TAKEOVER, f"mode changed to {v.mode} (expected {s.expected_mode})"
    odom_age = s.t_mono_s - s.t_odom_mono_s
    if odom_age > cfg.stale_odometry_s:
        return StopReason.STALE_ODOMETRY, f"odometry {odom_age:.3f} s old > {cfg.stale_odometry_s} s"
    if not np.all(np.isfinite(s.pos_world_m)):
        return StopReason.BAD_ODOMETRY, f"odometry position {np.asarray(s.pos_world_m).tolist()} not finite"
    depth_age = s.t_mono_s - s.t_depth_mono_s
    if depth_age > cfg.stale_depth_s:
        return StopReason.STALE_DEPTH, f"depth {depth_age:.3f} s old > {cfg.stale_depth_s} s"
    if s.depth_error is not None:
        return StopReason.BAD_DEPTH, s.depth_error
    p = np.asarray(s.pos_world_m)
    lo, hi = np.asarray(cfg.geofence_min_m), np.asarray(cfg.geofence_max_m)
    if np.any(p < lo) or np.any(p > hi):
        return StopReason.GEOFENCE, f"position {np.round(p, 2).tolist()} outside the geofence {lo} .. {hi}"
    if p[2] > cfg.altitude_ceiling_m or (s.in_mission and p[2] < cfg.altitude_floor_m):
        return StopReason.ALTITUDE, (
            f"altitude {p[2]:.2f} m outside [{cfg.altitude_floor_m}, {cfg.altitude_ceiling_m}] m"
        )
    if s.in_mission and s.deviation_m > cfg.max_deviation_m:
        return StopReason.DEVIATION, f"deviation {s.deviation_m:.2f} m > {cfg.max_deviation_m} m"
    if s.inference_s > cfg.inference_budget_s:
        budget = cfg.inference_budget_s
        return StopReason.INFERENCE_OVERRUN, f"decision took {s.inference_s:.3f} s > {budget} s"
    return None


# --- pre-flight ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class PreflightCheck:
    """One pre-flight check's outcome."""

    name: str
    ok: bool
    detail: str


class PreflightError(RuntimeError):
    """A pre-flight check failed: the daemon refuses to arm. ``check`` names it."""

    def __init__(self, check: PreflightCheck) -> None:
        super().__init__(f"pre-flight check '{check.name}' failed: {check.detail}")
        self.check = check


def check_depth_frame(
    frame: DepthFrame | None, now_mono_s: float, max_age_s: float, cfg: PreprocessConfig
) -> PreflightCheck:
    """Depth is present, fresh, uint16 of a usable shape and not (nearly) all invalid."""
    if frame is None:
        return PreflightCheck("depth", False, "no depth frame received")
    age = now_mono_s - frame.t_capture_mono_s
    if age > max_age_s:
        return PreflightCheck("depth", False, f"newest depth frame is {age:.2f} s old (> {max_age_s} s)")
    try:
        preprocess_depth_mm(frame.depth_mm, cfg)
    except DepthFrameError as exc:
        return PreflightCheck("depth", False, str(exc))
    h, w = np.asarray(frame.depth_mm).shape
    return PreflightCheck("depth", True, f"{w}x{h} uint16, {age * 1e3:.0f} ms old")


def check_odometry(sample: OdometrySample | None, now_mono_s: float, max_age_s: float) -> PreflightCheck:
    """Odometry is present, fresh, finite, with a unit quaternion."""
    if sample is None:
        return PreflightCheck("odometry", False, "no odometry sample received")
    age = now_mono_s - sample.t_arrival_mono_s
    if age > max_age_s:
        return PreflightCheck("odometry", False, f"newest odometry is {age:.2f} s old (> {max_age_s} s)")
    pos = np.asarray(sample.pos_world_m, dtype=np.float64)
    q = np.asarray(sample.quat_world_body, dtype=np.float64)
    if pos.shape != (3,) or q.shape != (4,):
        return PreflightCheck("odometry", False, f"bad shapes: position {pos.shape}, quaternion {q.shape}")
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(q))):
        return PreflightCheck("odometry", False, f"NaN/Inf: pos {pos.tolist()}, quat {q.tolist()}")
    if abs(float(np.linalg.norm(q)) - 1.0) > 0.05:
        return PreflightCheck("odometry", False, f"quaternion {q.tolist()} is not unit length")
    return PreflightCheck("odometry", True, f"at {np.round(pos, 2).tolist()} m, {age * 1e3:.0f} ms old")


def check_vehicle_ready(v: VehicleState) -> PreflightCheck:
    """PX4 connected, local position OK, disarmed and on the ground."""
    if not v.connected:
        return PreflightCheck("vehicle", False, "not connected")
    if not v.local_position_ok:
        return PreflightCheck("vehicle", False, "PX4 does not report local position OK")
    if v.armed:
        return PreflightCheck("vehicle", False, "the vehicle is already armed; refusing to take it over")
    return PreflightCheck("vehicle", True, f"mode {v.mode}, local position OK")


def check_start_inside(start_world_m: Sequence[float], cfg: SafetyConfig) -> PreflightCheck:
    """The path start lies inside the geofence and the altitude band."""
    p = np.asarray(start_world_m, dtype=np.float64)
    lo, hi = np.asarray(cfg.geofence_min_m), np.asarray(cfg.geofence_max_m)
    if np.any(p < lo) or np.any(p > hi) or not (cfg.altitude_floor_m <= p[2] <= cfg.altitude_ceiling_m):
        return PreflightCheck("path", False, f"path start {p.tolist()} is outside the geofence/altitude band")
    return PreflightCheck("path", True, f"start {p.tolist()}")


def finite_or(value: float, default: float) -> float:
    """``value`` when finite, else ``default`` (for summaries)."""
    return value if math.isfinite(value) else default
