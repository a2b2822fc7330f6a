"""PX4 logic of the emulated vehicle with fake time (no sockets): modes, failsafes, landing."""

from __future__ import annotations

import numpy as np
import pytest

from sim_harness.px4 import EmulatorConfig
from sim_harness.px4.modes import (
    MODE_NAMES,
    ModeError,
    decode_custom_mode,
    decode_mode_params,
    encode_custom_mode,
)
from sim_harness.px4.vehicle import Px4Vehicle, Setpoint

DT = 0.01


def run(v: Px4Vehicle, t: float, duration_s: float, setpoint: np.ndarray | None = None) -> float:
    """Tick for ``duration_s`` from ``t``, streaming ``setpoint`` (world) every tick if given."""
    for _ in range(round(duration_s / DT)):
        t += DT
        if setpoint is not None:
            v.on_setpoint(Setpoint(setpoint, None, None, t))
        v.tick(t, DT)
    return t


def airborne(cfg: EmulatorConfig | None = None, z: float = 1.0) -> tuple[Px4Vehicle, float]:
    v = Px4Vehicle(cfg or EmulatorConfig(), np.zeros(3), 0.0, 0.0)
    sp = np.array([0.0, 0.0, z])
    v.on_setpoint(Setpoint(sp, None, None, 0.0))
    assert v.arm(0.0).accepted and v.set_mode(0.0, "OFFBOARD").accepted
    return v, run(v, 0.0, 3.0, sp)


def test_px4_custom_modes_round_trip_and_match_px4_values() -> None:
    assert encode_custom_mode("OFFBOARD") == 6 << 16
    assert encode_custom_mode("HOLD") == (4 << 16) | (3 << 24)
    assert encode_custom_mode("LAND") == (4 << 16) | (6 << 24)
    for mode in MODE_NAMES:
        assert decode_custom_mode(encode_custom_mode(mode)) == mode
    assert decode_mode_params(6.0, float("nan")) == "OFFBOARD"
    with pytest.raises(ModeError):
        decode_mode_params(float("nan"), 0.0)
    with pytest.raises(ModeError):
        encode_custom_mode("WARP")


def test_offboard_setpoint_is_reached_and_held() -> None:
    v, _ = airborne(z=1.5)
    assert np.linalg.norm(v.pos_world_m - [0.0, 0.0, 1.5]) < 0.02
    assert v.landed_state == "IN_AIR"


def test_offboard_loss_failsafe_fires_after_com_of_loss_t_not_before() -> None:
    v, t = airborne(EmulatorConfig(com_of_loss_t_s=1.0))
    t_last = t
    t = run(v, t, 0.95)
    assert v.mode == "OFFBOARD"
    run(v, t, 0.1)
    assert v.mode == "HOLD"
    (t_fs, _, _), = [e for e in v.events if e[1] == "failsafe"]
    assert 1.0 <= t_fs - t_last <= 1.0 + DT + 1e-9


def test_hold_keeps_the_position_where_it_was_entered() -> None:
    v, t = airborne(z=1.0)
    v.set_mode(t, "HOLD")
    run(v, t, 2.0)
    assert np.linalg.norm(v.pos_world_m - [0.0, 0.0, 1.0]) < 0.05


def test_land_descends_at_land_speed_and_disarms_after_com_disarm_land() -> None:
    v, t = airborne(EmulatorConfig(land_disarm_s=2.0), z=2.0)
    v.land(t)
    t = run(v, t, 1.0)
    z1 = v.pos_world_m[2]
    t = run(v, t, 1.0)
    assert z1 - v.pos_world_m[2] == pytest.approx(0.7, abs=0.02)
    t = run(v, t, 1.0)  # reaches the floor (2 m at 0.7 m/s)
    assert v.landed_state == "ON_GROUND" and v.armed
    run(v, t, 2.1)
    assert not v.armed and v.pos_world_m[2] == 0.0


def test_takeoff_climbs_to_the_takeoff_altitude_then_holds() -> None:
    v = Px4Vehicle(EmulatorConfig(takeoff_alt_m=1.2), np.zeros(3), 0.0, 0.0)
    v.arm(0.0)
    assert v.takeoff(0.0, None).accepted
    run(v, 0.0, 4.0)
    assert v.mode == "HOLD" and v.pos_world_m[2] == pytest.approx(1.2, abs=0.1)


def test_armed_without_takeoff_auto_disarms_after_com_disarm_prflt() -> None:
    v = Px4Vehicle(EmulatorConfig(preflight_disarm_s=10.0), np.zeros(3), 0.0, 0.0)
    v.arm(0.0)
    t = run(v, 0.0, 9.9)
    assert v.armed
    run(v, t, 0.2)
    assert not v.armed


def test_forced_disarm_in_the_air_falls_and_crashes_on_the_floor() -> None:
    v, t = airborne(z=2.0)
    assert not v.disarm(t).accepted
    assert v.disarm(t, force=True).accepted
    run(v, t, 1.0)
    assert v.crashed and v.pos_world_m[2] == 0.0


def test_velocity_only_setpoints_move_the_vehicle() -> None:
    v, t = airborne(z=1.0)
    for _ in range(200):
        t += DT
        v.on_setpoint(Setpoint(None, np.array([0.5, 0.0, 0.0]), None, t))
        v.tick(t, DT)
    assert v.vel_world_m_s[0] == pytest.approx(0.5, abs=0.05)
    assert v.pos_world_m[0] > 0.6


def test_yaw_turns_towards_the_setpoint_at_the_rate_limit() -> None:
    v, t = airborne(EmulatorConfig(max_yaw_rate_rad_s=1.0), z=1.0)
    for _ in range(50):
        t += DT
        v.on_setpoint(Setpoint(np.array([0.0, 0.0, 1.0]), None, 1.5, t))
        v.tick(t, DT)
    assert v.yaw_rad == pytest.approx(0.5, abs=0.02)


def test_a_crash_in_the_air_falls_from_where_it_hit_and_lies_on_the_floor() -> None:
    v, t = airborne(z=1.5)
    v.crash(t, "test")
    assert v.crashed and not v.armed and v.landed_state == "IN_AIR"
    assert v.pos_world_m[2] > 1.4  # not teleported to the floor
    t = run(v, t, 0.2)
    assert 0.0 < v.pos_world_m[2] < 1.4  # falling
    run(v, t, 1.0)
    assert v.pos_world_m[2] == 0.0 and v.landed_state == "ON_GROUND"
