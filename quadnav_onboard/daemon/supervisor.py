"""The safety supervisor: why a flight stops, pre-flight checks, in-flight checks.

Pure functions of their inputs (times are passed in, never read here), so every check is unit
tested with fake time. The daemon calls :func:`check_in_flight` at ``safety.check_rate_hz`` and
acts on the first reason it returns; the order below is the priority.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.daemon.config import SafetyConfig
from quadnav_onboard.preprocess import DepthFrameError, PreprocessConfig, preprocess_depth_mm
from quadnav_onboard.sources.base import DepthFrame, OdometrySample
from quadnav_onboard.vehicle import MAV_STATE_EMERGENCY, VehicleState

__all__ = [
    "CRASH_TILT_RAD",
    "LINK_QUIET_FRACTION",
    "ExitCode",
    "FlightSnapshot",
    "FrozenPositionWatch",
    "OdometryRate",
    "PreflightCheck",
    "PreflightError",
    "Response",
    "StopReason",
    "check_depth_frame",
    "check_in_flight",
    "check_odometry",
    "check_odometry_rate",
    "check_vehicle_ready",
    "crash_evidence",
    "in_flight_stale_odometry_s",
    "link_quiet",
    "measure_odometry_rate",
    "response_for",
]

CRASH_TILT_RAD = math.radians(60.0)
"""A tilt past this is a crash: the primitives command accelerations of ~1 m/s2 (a few degrees
of tilt); PX4's failure detector trips at the same angle (FD_FAIL_R / FD_FAIL_P, 60 deg)."""


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
    """A crash: the vehicle reported an emergency, a tilt or a touchdown no primitive commands (or,
    in a dry run, the emulator's collision)."""


class StopReason(enum.Enum):
    """Why a flight ended; written into every log line and record that ends a flight."""

    GOAL_REACHED = "goal_reached"
    STEP_LIMIT = "step_limit"
    CRASH = "crash"
    LINK_LOST = "link_lost"
    LINK_SOURCE_CHANGED = "link_source_changed"
    """The bound vehicle's system ID was heard from another address."""
    PILOT_TAKEOVER = "pilot_takeover"
    DISARMED = "disarmed"
    STALE_ODOMETRY = "stale_odometry"
    BAD_ODOMETRY = "bad_odometry"
    """Not finite, or a position that does not move while the vehicle is commanded to."""
    VISION_FORWARD_FAILED = "vision_forward_failed"
    """Forwarding mocap to PX4's estimator failed for longer than ``link_timeout_s``."""
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
    """Pilot takeover, link loss and a disarm release the vehicle; everything else climbs the
    ladder (a changed link source too: commands reach only the bound address, and the ladder
    releases instead if that address has fallen silent)."""
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
    frozen_position: str | None = None
    """A position source does not move while the vehicle is commanded to (message), else None."""
    vision_forward_failing_s: float = 0.0
    """How long (s) every vision forward to PX4 has failed (0 when the last one went out)."""


def crash_evidence(v: VehicleState, in_mission: bool) -> str | None:
    """What the vehicle itself reports that only a crash explains, else None: PX4's emergency
    state, a tilt past :data:`CRASH_TILT_RAD`, or a touchdown in the middle of the mission."""
    if v.system_status == MAV_STATE_EMERGENCY:
        return "PX4 reports an emergency (MAV_STATE_EMERGENCY)"
    if v.tilt_rad > CRASH_TILT_RAD:
        return f"tilted {math.degrees(v.tilt_rad):.0f} deg > {math.degrees(CRASH_TILT_RAD):.0f} deg"
    if in_mission and v.landed:
        return "PX4 reports the vehicle on the ground in the middle of the mission"
    return None


LINK_QUIET_FRACTION = 0.5
"""The link is quiet after this fraction of ``min(stale_odometry_s, link_timeout_s)`` without a
message: odometry riding a dying link is then found stale only while the link is already quiet
(the two fall silent within a telemetry period of each other)."""


def link_quiet(s: FlightSnapshot, cfg: SafetyConfig) -> bool:
    """Nothing heard from the vehicle for a while (:data:`LINK_QUIET_FRACTION`): another stop found
    now may be the link dying (odometry and telemetry ride it), so it waits for the link's verdict
    (back: that stop; silent past ``link_timeout_s``: ``link_lost``). A live link ends the wait
    with its next message (PX4 streams at 30-50 Hz), so a false alarm costs a few milliseconds."""
    quiet_s = LINK_QUIET_FRACTION * min(cfg.stale_odometry_s, cfg.link_timeout_s)
    return s.t_mono_s - s.vehicle.t_last_msg_mono_s > quiet_s


def check_in_flight(s: FlightSnapshot, cfg: SafetyConfig) -> tuple[StopReason, str] | None:
    """The first reason to stop now, with a message; None when all is well. Order = priority."""
    v = s.vehicle
    if s.crashed:
        return StopReason.CRASH, "collision reported"
    crash = crash_evidence(v, s.in_mission)
    if crash is not None:
        return StopReason.CRASH, crash
    link_age = s.t_mono_s - v.t_last_msg_mono_s
    if link_age > cfg.link_timeout_s:
        return StopReason.LINK_LOST, f"nothing from the vehicle for {link_age:.2f} s > {cfg.link_timeout_s} s"
    if v.source_changed is not None:
        return StopReason.LINK_SOURCE_CHANGED, (
            f"vehicle {v.source_changed.bound} heard from another address: {v.source_changed.heard}"
        )
    if not v.armed:
        return StopReason.DISARMED, "the vehicle disarmed"
    if v.mode != s.expected_mode:
        return StopReason.PILOT_TAKEOVER, f"mode changed to {v.mode} (expected {s.expected_mode})"
    odom_age = s.t_mono_s - s.t_odom_mono_s
    if odom_age > cfg.stale_odometry_s:
        return StopReason.STALE_ODOMETRY, f"odometry {odom_age:.3f} s old > {cfg.stale_odometry_s} s"
    if not np.all(np.isfinite(s.pos_world_m)):
        return StopReason.BAD_ODOMETRY, f"odometry position {np.asarray(s.pos_world_m).tolist()} not finite"
    if s.frozen_position is not None:
        return StopReason.BAD_ODOMETRY, s.frozen_position
    if s.vision_forward_failing_s > cfg.link_timeout_s:
        return StopReason.VISION_FORWARD_FAILED, (
            f"every vision forward to PX4 failed for {s.vision_forward_failing_s:.2f} s "
            f"> {cfg.link_timeout_s} s"
        )
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


class FrozenPositionWatch:
    """Is a position source stuck while the vehicle is commanded to move?

    Fed each fresh report of the source (its own timestamp; a repeated timestamp is not a new
    report) with the setpoint commanded then. Frozen: over the last ``window_s``, at least
    ``min_reports`` reports, the setpoint travelled at least ``min_commanded_m`` and the reported
    position stayed within ``max_still_m`` of where the window began. A live estimate (mocap or
    PX4's EKF) moves by more than a millimetre under any commanded motion, so identical positions
    with fresh timestamps are a frozen estimator.
    """

    def __init__(
        self,
        name: str,
        window_s: float = 0.3,
        min_commanded_m: float = 0.15,
        max_still_m: float = 1e-3,
        min_reports: int = 4,
    ) -> None:
        self.name = name
        self.window_s = window_s
        self.min_commanded_m = min_commanded_m
        self.max_still_m = max_still_m
        self.min_reports = min_reports
        self._samples: deque[tuple[float, NDArray[np.float64], NDArray[np.float64]]] = deque()

    def reset(self) -> None:
        self._samples.clear()

    def add(
        self,
        t_report_mono_s: float,
        commanded_world_m: NDArray[np.float64],
        reported_world_m: NDArray[np.float64],
    ) -> None:
        """One report of the source at ``t_report_mono_s`` (monotonic s); world frame, m, (3,)."""
        if self._samples and t_report_mono_s <= self._samples[-1][0]:
            return  # not a new report
        cmd = np.asarray(commanded_world_m, dtype=np.float64)
        rep = np.asarray(reported_world_m, dtype=np.float64)
        if not (math.isfinite(t_report_mono_s) and np.all(np.isfinite(cmd)) and np.all(np.isfinite(rep))):
            self.reset()
            return
        self._samples.append((t_report_mono_s, cmd, rep))
        while len(self._samples) > 2 and self._samples[1][0] <= t_report_mono_s - self.window_s:
            self._samples.popleft()

    def verdict(self, now_mono_s: float) -> str | None:
        """A message when frozen now, else None (also when the newest report is older than the
        window: a silent source is the staleness checks' business)."""
        if len(self._samples) < self.min_reports:
            return None
        t_first, t_last = self._samples[0][0], self._samples[-1][0]
        if t_last - t_first < self.window_s or now_mono_s - t_last > self.window_s:
            return None
        cmds = np.stack([c for _, c, _ in self._samples])
        reps = np.stack([r for _, _, r in self._samples])
        commanded = float(np.linalg.norm(np.diff(cmds, axis=0), axis=1).sum())
        moved = float(np.linalg.norm(reps - reps[0], axis=1).max())
        if commanded >= self.min_commanded_m and moved <= self.max_still_m:
            return (
                f"{self.name} frozen: moved {moved * 1e3:.1f} mm in {t_last - t_first:.2f} s "
                f"({len(self._samples)} reports) while the setpoint moved {commanded:.2f} m"
            )
        return None


# --- pre-flight ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class PreflightCheck:
    """One pre-flight check's outcome."""

    name: str
    ok: bool
    detail: str
    retry: bool = True
    """A failure that time may fix (sensors warming up, EKF converging); False: refuse at once."""


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


@dataclass(frozen=True)
class OdometryRate:
    """The odometry stream as measured over preflight's window."""

    rate_hz: float
    """Samples per second over the window."""
    max_gap_s: float
    """Longest interval between two samples in the window (s)."""
    n: int
    """Samples in the window."""


ODOMETRY_RATE_WINDOW_S = 1.0
"""How far back (s) preflight measures the odometry stream."""


def measure_odometry_rate(arrivals_mono_s: Sequence[float], now_mono_s: float,
                          window_s: float = ODOMETRY_RATE_WINDOW_S) -> OdometryRate | None:
    """Rate and longest gap of the samples that arrived in the last ``window_s`` (the gap from the
    newest to now included); None with fewer than 3."""
    t = np.asarray([a for a in arrivals_mono_s if now_mono_s - window_s <= a <= now_mono_s], dtype=np.float64)
    if t.size < 3:
        return None
    gaps = np.diff(np.append(t, now_mono_s))
    return OdometryRate(float((t.size - 1) / max(t[-1] - t[0], 1e-9)), float(gaps.max()), int(t.size))


def check_odometry_rate(rate: OdometryRate | None, min_rate_hz: float) -> PreflightCheck:
    """The odometry stream is at least ``min_rate_hz`` (time may fix it: PX4 applies a requested
    rate within a second)."""
    if rate is None:
        return PreflightCheck("odometry_rate", False, f"fewer than 3 odometry samples in the last "
                              f"{ODOMETRY_RATE_WINDOW_S:g} s")
    detail = f"{rate.rate_hz:.1f} Hz, longest gap {rate.max_gap_s * 1e3:.0f} ms ({rate.n} samples)"
    if rate.rate_hz < min_rate_hz:
        return PreflightCheck("odometry_rate", False,
                              f"{detail}: below safety.min_odometry_rate_hz {min_rate_hz:g}")
    return PreflightCheck("odometry_rate", True, detail)


def in_flight_stale_odometry_s(cfg: SafetyConfig, rate: OdometryRate | None) -> float:
    """The in-flight stale-odometry limit: ``stale_odometry_s``, raised to cover
    ``stale_odometry_periods`` periods and twice the longest gap measured in preflight (a 30 Hz
    stream with 49 ms gaps needs 0.1 s), never above 1 s."""
    if rate is None:
        return cfg.stale_odometry_s
    sized = max(cfg.stale_odometry_s, cfg.stale_odometry_periods / rate.rate_hz, 2.0 * rate.max_gap_s)
    return float(min(sized, 1.0))


def check_vehicle_ready(v: VehicleState, allow_armed: bool = False) -> PreflightCheck:
    """PX4 connected, the only autopilot on the link, local position OK, disarmed (unless
    ``allow_armed``: a pilot who armed and switched to OFFBOARD as the go)."""
    if not v.connected:
        return PreflightCheck("vehicle", False, "not connected")
    if v.source_changed is not None:
        return PreflightCheck(
            "vehicle",
            False,
            f"vehicle {v.source_changed.bound} heard from another address: {v.source_changed.heard}",
            retry=False,
        )
    if v.other_autopilots:
        who = "; ".join(str(c) for c in v.other_autopilots)
        return PreflightCheck(
            "vehicle",
            False,
            f"more than one autopilot on the link (also {who}); refusing to pick one",
            retry=False,
        )
    if not v.local_position_ok:
        return PreflightCheck("vehicle", False, "PX4 does not report local position OK")
    if v.armed and not allow_armed:
        return PreflightCheck(
            "vehicle", False, "the vehicle is already armed; refusing to take it over", retry=False
        )
    return PreflightCheck("vehicle", True, f"mode {v.mode}, local position OK")


def check_start_inside(start_world_m: Sequence[float], cfg: SafetyConfig) -> PreflightCheck:
    """The path start lies inside the geofence and the altitude band."""
    p = np.asarray(start_world_m, dtype=np.float64)
    lo, hi = np.asarray(cfg.geofence_min_m), np.asarray(cfg.geofence_max_m)
    if np.any(p < lo) or np.any(p > hi) or not (cfg.altitude_floor_m <= p[2] <= cfg.altitude_ceiling_m):
        return PreflightCheck(
            "path", False, f"path start {p.tolist()} is outside the geofence/altitude band", retry=False
        )
    return PreflightCheck("path", True, f"start {p.tolist()}")


def finite_or(value: float, default: float) -> float:
    """``value`` when finite, else ``default`` (for summaries)."""
    return value if math.isfinite(value) else default
