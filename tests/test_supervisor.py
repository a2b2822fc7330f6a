"""Supervisor checks: pure functions of a snapshot and fake time."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from quadnav_onboard.daemon.config import SafetyConfig
from quadnav_onboard.daemon.supervisor import (
    LINK_QUIET_FRACTION,
    ExitCode,
    FlightSnapshot,
    FrozenPositionWatch,
    Response,
    StopReason,
    check_depth_frame,
    check_in_flight,
    check_odometry,
    check_start_inside,
    check_vehicle_ready,
    link_quiet,
    response_for,
)
from quadnav_onboard.frames import quat_from_yaw
from quadnav_onboard.preprocess import PreprocessConfig
from quadnav_onboard.sources.base import DepthFrame, OdometrySample
from quadnav_onboard.vehicle import MAV_STATE_EMERGENCY, VehicleState
from quadnav_onboard.vehicle_binding import Candidate, SourceChange

NOW = 100.0
CFG = SafetyConfig()


def healthy(**overrides: object) -> FlightSnapshot:
    vehicle = VehicleState(connected=True, armed=True, mode="OFFBOARD", local_position_ok=True)
    vehicle.t_last_msg_mono_s = NOW - 0.01
    snap = FlightSnapshot(
        t_mono_s=NOW,
        vehicle=vehicle,
        t_depth_mono_s=NOW - 0.03,
        t_odom_mono_s=NOW - 0.008,
        pos_world_m=np.array([1.0, 0.0, 1.5]),
        deviation_m=0.1,
        in_mission=True,
    )
    return dataclasses.replace(snap, **overrides)


def test_a_healthy_flight_has_no_reason_to_stop() -> None:
    assert check_in_flight(healthy(), CFG) is None


@pytest.mark.parametrize(
    ("overrides", "reason"),
    [
        ({"crashed": True}, StopReason.CRASH),
        ({"t_depth_mono_s": NOW - 0.31}, StopReason.STALE_DEPTH),
        ({"t_odom_mono_s": NOW - 0.11}, StopReason.STALE_ODOMETRY),
        ({"pos_world_m": np.array([1.0, math.nan, 1.5])}, StopReason.BAD_ODOMETRY),
        ({"depth_error": "depth frame of dtype float32"}, StopReason.BAD_DEPTH),
        ({"pos_world_m": np.array([150.0, 0.0, 1.5])}, StopReason.GEOFENCE),
        ({"pos_world_m": np.array([1.0, 0.0, 0.1])}, StopReason.ALTITUDE),
        ({"deviation_m": 5.01}, StopReason.DEVIATION),
        ({"inference_s": 0.26}, StopReason.INFERENCE_OVERRUN),
    ],
)
def test_each_limit_past_its_threshold_names_its_reason(overrides: dict, reason: StopReason) -> None:
    found = check_in_flight(healthy(**overrides), CFG)
    assert found is not None and found[0] is reason, found


def test_values_just_inside_the_limits_do_not_stop() -> None:
    snap = healthy(t_depth_mono_s=NOW - 0.29, t_odom_mono_s=NOW - 0.09, deviation_m=4.99, inference_s=0.24)
    assert check_in_flight(snap, CFG) is None


def test_altitude_floor_and_deviation_apply_only_once_the_mission_began() -> None:
    low = healthy(pos_world_m=np.array([0.0, 0.0, 0.05]), deviation_m=9.0, in_mission=False)
    assert check_in_flight(low, CFG) is None


def test_link_silence_is_link_lost_and_outranks_stale_sensors() -> None:
    snap = healthy(t_depth_mono_s=NOW - 5, t_odom_mono_s=NOW - 5)
    snap.vehicle.t_last_msg_mono_s = NOW - 0.6
    found = check_in_flight(snap, CFG)
    assert found is not None and found[0] is StopReason.LINK_LOST


def test_a_mode_change_is_a_pilot_takeover_that_releases_the_vehicle() -> None:
    snap = healthy()
    snap.vehicle.mode = "POSCTL"
    found = check_in_flight(snap, CFG)
    assert found is not None and found[0] is StopReason.PILOT_TAKEOVER
    assert response_for(StopReason.PILOT_TAKEOVER) is Response.RELEASE
    assert response_for(StopReason.LINK_LOST) is Response.RELEASE
    assert response_for(StopReason.STALE_DEPTH) is Response.LADDER


def test_exit_codes_tell_success_abort_refusal_crash_and_error_apart() -> None:
    assert StopReason.GOAL_REACHED.exit_code is ExitCode.SUCCESS
    assert StopReason.STEP_LIMIT.exit_code is ExitCode.SAFE_ABORT
    assert StopReason.OPERATOR_STOP.exit_code is ExitCode.SAFE_ABORT
    assert StopReason.PREFLIGHT_FAILED.exit_code is ExitCode.REFUSED
    assert StopReason.CRASH.exit_code is ExitCode.CRASH
    assert StopReason.INTERNAL_ERROR.exit_code is ExitCode.ERROR
    assert len({int(c) for c in ExitCode}) == len(ExitCode)


BOUND = Candidate(1, 1, ("127.0.0.1", 40001))
OTHER = Candidate(1, 1, ("127.0.0.1", 40002))


def with_vehicle(**fields: object) -> FlightSnapshot:
    snap = healthy()
    for k, v in fields.items():
        setattr(snap.vehicle, k, v)
    return snap


@pytest.mark.parametrize(
    "fields",
    [
        {"system_status": MAV_STATE_EMERGENCY},
        {"tilt_rad": math.radians(80.0)},
        {"landed": True},
    ],
    ids=["emergency", "tilt", "landed-mid-mission"],
)
def test_what_the_vehicle_reports_of_a_crash_is_a_crash_before_anything_else(fields: dict) -> None:
    snap = with_vehicle(**fields, armed=False)  # a crashed PX4 also disarms; the crash names it
    snap = dataclasses.replace(snap, pos_world_m=np.array([1.0, 0.0, 0.0]))  # and it lies on the floor
    found = check_in_flight(snap, CFG)
    assert found is not None and found[0] is StopReason.CRASH, found
    assert StopReason.CRASH.exit_code is ExitCode.CRASH


def test_a_level_flight_and_a_landed_state_before_the_mission_are_no_crash() -> None:
    assert check_in_flight(with_vehicle(tilt_rad=math.radians(20.0), system_status=4), CFG) is None
    on_ground = dataclasses.replace(with_vehicle(landed=True), in_mission=False)
    assert check_in_flight(on_ground, CFG) is None  # take-off starts on the ground


def test_a_changed_link_source_is_a_link_fault_and_a_silent_link_outranks_it() -> None:
    snap = with_vehicle(source_changed=SourceChange(NOW - 0.1, BOUND, OTHER))
    found = check_in_flight(snap, CFG)
    assert found is not None and found[0] is StopReason.LINK_SOURCE_CHANGED
    snap.vehicle.t_last_msg_mono_s = NOW - 0.6
    found = check_in_flight(snap, CFG)
    assert found is not None and found[0] is StopReason.LINK_LOST


def test_the_link_is_quiet_before_odometry_riding_it_goes_stale() -> None:
    snap = healthy()
    assert not link_quiet(snap, CFG)
    snap.vehicle.t_last_msg_mono_s = NOW - CFG.stale_odometry_s * LINK_QUIET_FRACTION - 0.001
    assert link_quiet(snap, CFG) and LINK_QUIET_FRACTION < 1.0
    assert check_in_flight(snap, CFG) is None  # quiet is not yet lost


def test_sustained_vision_forward_failure_stops_a_brief_one_does_not() -> None:
    assert check_in_flight(healthy(vision_forward_failing_s=CFG.link_timeout_s - 0.05), CFG) is None
    found = check_in_flight(healthy(vision_forward_failing_s=CFG.link_timeout_s + 0.05), CFG)
    assert found is not None and found[0] is StopReason.VISION_FORWARD_FAILED


def test_a_frozen_position_is_bad_odometry() -> None:
    found = check_in_flight(healthy(frozen_position="odometry frozen"), CFG)
    assert found is not None and found[0] is StopReason.BAD_ODOMETRY


def feed(
    watch: FrozenPositionWatch, cmd_speed_m_s: float, pos_speed_m_s: float, duration_s: float = 0.5,
    rate_hz: float = 50.0, t0: float = 0.0,
) -> float:
    """Reports at ``rate_hz`` for ``duration_s``; returns the last report's time."""
    t = t0
    for k in range(int(duration_s * rate_hz) + 1):
        t = t0 + k / rate_hz
        watch.add(t, np.array([cmd_speed_m_s * t, 0.0, 1.5]), np.array([pos_speed_m_s * t, 0.0, 1.5]))
    return t


def test_a_position_that_stands_still_while_the_setpoint_moves_is_frozen() -> None:
    w = FrozenPositionWatch("odometry")
    t = feed(w, 1.0, 0.0)
    assert w.verdict(t) is not None


@pytest.mark.parametrize(("cmd", "pos"), [(1.0, 0.05), (0.0, 0.0), (0.2, 0.0)])
def test_a_moving_position_or_a_still_setpoint_is_not_frozen(cmd: float, pos: float) -> None:
    w = FrozenPositionWatch("odometry")
    t = feed(w, cmd, pos)
    assert w.verdict(t) is None


def test_the_frozen_watch_needs_a_full_window_and_forgets_on_nan() -> None:
    w = FrozenPositionWatch("odometry", window_s=0.3)
    t = feed(w, 1.0, 0.0, duration_s=0.2)
    assert w.verdict(t) is None
    t = feed(w, 1.0, 0.0, t0=t + 0.02)
    assert w.verdict(t) is not None
    w.add(t + 0.02, np.array([1.0, 0.0, 1.5]), np.full(3, math.nan))
    assert w.verdict(t + 0.02) is None


def test_repeated_timestamps_are_not_fresh_reports_and_a_silent_source_is_no_verdict() -> None:
    """A source read at 50 Hz that reports at 2 Hz: the same report read again is not evidence."""
    w = FrozenPositionWatch("PX4's position estimate")
    for k in range(50):  # 1 s of supervisor ticks, reports only at 0.0 and 0.5 s
        t_report = 0.0 if k < 25 else 0.5
        w.add(t_report, np.array([k / 50, 0.0, 1.5]), np.array([0.0, 0.0, 1.5]))
    assert w.verdict(0.98) is None  # two reports, not four
    w = FrozenPositionWatch("odometry")
    t = feed(w, 1.0, 0.0)
    assert w.verdict(t) is not None and w.verdict(t + 1.0) is None  # then nothing came


# --- pre-flight ---------------------------------------------------------------------------------


def frame(arr: np.ndarray, age_s: float = 0.01) -> DepthFrame:
    return DepthFrame(arr, NOW - age_s, 1)


def test_preflight_accepts_a_fresh_valid_depth_frame() -> None:
    assert check_depth_frame(frame(np.full((240, 424), 3000, np.uint16)), NOW, 0.3, PreprocessConfig()).ok


@pytest.mark.parametrize(
    ("arr", "age", "needle"),
    [
        (None, 0.0, "no depth frame"),
        (np.full((240, 424), 3000, np.uint16), 1.0, "old"),
        (np.full((240, 424), 3.0, np.float32), 0.0, "dtype"),
        (np.full((240,), 3000, np.uint16), 0.0, "shape"),
        (np.zeros((240, 424), np.uint16), 0.0, "valid pixels"),
    ],
)
def test_preflight_refuses_missing_stale_wrong_or_blind_depth(arr, age: float, needle: str) -> None:
    check = check_depth_frame(None if arr is None else frame(arr, age), NOW, 0.3, PreprocessConfig())
    assert not check.ok and check.name == "depth" and needle in check.detail


def test_preflight_odometry_refuses_nan_stale_and_bad_quaternions() -> None:
    good = OdometrySample(np.array([0.0, 0.0, 0.0]), quat_from_yaw(0.3), NOW - 0.01)
    assert check_odometry(good, NOW, 0.1).ok
    nan = dataclasses.replace(good, pos_world_m=np.array([np.nan, 0.0, 0.0]))
    assert "NaN" in check_odometry(nan, NOW, 0.1).detail
    stale = dataclasses.replace(good, t_arrival_mono_s=NOW - 0.5)
    assert not check_odometry(stale, NOW, 0.1).ok
    skew = dataclasses.replace(good, quat_world_body=np.array([2.0, 0.0, 0.0, 0.0]))
    assert "unit" in check_odometry(skew, NOW, 0.1).detail
    assert not check_odometry(None, NOW, 0.1).ok


def test_preflight_vehicle_needs_local_position_and_refuses_an_armed_vehicle() -> None:
    v = VehicleState(connected=True, local_position_ok=False)
    assert "local position" in check_vehicle_ready(v).detail
    v.local_position_ok = True
    assert check_vehicle_ready(v).ok
    v.armed = True
    assert "already armed" in check_vehicle_ready(v).detail


def test_preflight_refuses_at_once_a_second_autopilot_or_a_changed_source() -> None:
    for fields in ({"other_autopilots": (Candidate(2, 1, ("127.0.0.1", 40003)),)},
                   {"source_changed": SourceChange(NOW, BOUND, OTHER)}):
        v = VehicleState(connected=True, local_position_ok=True, binding=BOUND)
        for k, val in fields.items():
            setattr(v, k, val)
        c = check_vehicle_ready(v)
        assert not c.ok and not c.retry, c
    assert check_vehicle_ready(VehicleState(connected=True, local_position_ok=True, binding=BOUND)).ok


def test_preflight_path_start_must_be_inside_the_geofence() -> None:
    assert check_start_inside([0.0, 0.0, 1.5], CFG).ok
    assert not check_start_inside([0.0, 0.0, 20.0], CFG).ok
