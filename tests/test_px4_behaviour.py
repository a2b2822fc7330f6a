"""PX4 behaviour of the emulator, one test each, over real UDP with a raw pymavlink GCS.

MAVSDK hides some of these (it will not switch to offboard before it streams); the raw client
sends exactly what each test needs. Times come from the emulator's event log (monotonic clock).
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from sim_harness.px4 import EmulatorConfig, Px4Emulator, free_udp_port
from sim_harness.px4.client import RawGcs
from sim_harness.px4.mavlink_io import mavlink2 as m
from sim_harness.px4.modes import decode_custom_mode
from sim_harness.world import parse_world

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(60)]

ACCEPTED, DENIED, UNSUPPORTED = m.MAV_RESULT_ACCEPTED, m.MAV_RESULT_DENIED, m.MAV_RESULT_UNSUPPORTED


def fast(**kw: object) -> EmulatorConfig:
    return EmulatorConfig.idealised(**{"heartbeat_hz": 10.0, "land_disarm_s": 0.3, **kw})


def stream(gcs: RawGcs, ned: tuple[float, float, float], duration_s: float, vision: bool = False) -> float:
    """Send setpoints (and vision estimates) at 20 Hz for ``duration_s``; returns the last send time."""
    end = time.monotonic() + duration_s
    last = time.monotonic()
    while time.monotonic() < end:
        gcs.setpoint_ned(*ned)
        if vision:
            gcs.vision(0.0, 0.0, 0.0)
        last = time.monotonic()
        gcs.pump(0.05)
    return last


def take_off_offboard(gcs: RawGcs, emu: Px4Emulator, ned: tuple[float, float, float], vision: bool = False,
                      ) -> None:
    stream(gcs, ned, 0.2, vision)
    assert gcs.arm() == ACCEPTED
    assert gcs.set_mode("OFFBOARD") == ACCEPTED
    stream(gcs, ned, 1.5, vision)
    assert emu.true_pose().pos_world_m[2] > 0.5


def test_offboard_switch_refused_without_a_setpoint_stream_then_accepted_with_one() -> None:
    with Px4Emulator(None, fast(), api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        assert gcs.set_mode("OFFBOARD") == DENIED
        assert emu.mode == "HOLD"
        stream(gcs, (0.0, 0.0, -1.0), 0.3)
        assert gcs.set_mode("OFFBOARD") == ACCEPTED
        assert emu.mode == "OFFBOARD"


def test_offboard_switch_refused_when_the_stream_stopped_over_half_a_second_ago() -> None:
    with Px4Emulator(None, fast(), api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        stream(gcs, (0.0, 0.0, -1.0), 0.2)
        gcs.pump(0.7)
        assert gcs.set_mode("OFFBOARD") == DENIED
        assert emu.mode == "HOLD"


@pytest.mark.parametrize(("action", "mode"), [("hold", "HOLD"), ("land", "LAND")])
def test_setpoint_loss_triggers_the_failsafe_within_com_of_loss_t(action: str, mode: str) -> None:
    cfg = fast(offboard_loss_action=action)
    with Px4Emulator(None, cfg, api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        take_off_offboard(gcs, emu, (0.0, 0.0, -1.0))
        last_sent = stream(gcs, (0.0, 0.0, -1.0), 0.2)
        hb = gcs.wait("HEARTBEAT", 2.5, lambda h: decode_custom_mode(h.custom_mode) == mode)
        assert hb is not None, f"no {mode} heartbeat after setpoint loss"
        (t_failsafe, _, message), = [e for e in emu.events if e[1] == "failsafe"]
        assert "offboard" in message
        assert cfg.com_of_loss_t_s <= t_failsafe - last_sent <= cfg.com_of_loss_t_s + 0.2
        assert emu.mode == mode and emu.armed


def test_land_descends_touches_down_and_disarms_on_the_ground() -> None:
    cfg = fast(takeoff_alt_m=1.0)
    with Px4Emulator(None, cfg, api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        assert gcs.arm() == ACCEPTED
        assert gcs.command(m.MAV_CMD_NAV_TAKEOFF) == ACCEPTED
        assert emu.wait_for(lambda e: e.mode == "HOLD", 5.0)
        assert gcs.command(m.MAV_CMD_NAV_LAND) == ACCEPTED
        z0, t0 = emu.true_pose().pos_world_m[2], time.monotonic()
        gcs.pump(0.5)
        rate = (z0 - emu.true_pose().pos_world_m[2]) / (time.monotonic() - t0)
        assert 0.4 < rate < 0.8  # MPC_LAND_SPEED 0.7 m/s once the descent has settled
        hb = gcs.wait("HEARTBEAT", 4.0, lambda h: not h.base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED)
        assert hb is not None
        assert gcs.wait("EXTENDED_SYS_STATE", 1.0, lambda x: x.landed_state == m.MAV_LANDED_STATE_ON_GROUND)
        assert emu.true_pose().pos_world_m[2] == pytest.approx(0.0, abs=1e-9)
        assert not emu.armed


def test_disarm_in_the_air_is_refused_unless_forced() -> None:
    with Px4Emulator(None, fast(), api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        take_off_offboard(gcs, emu, (0.0, 0.0, -1.0))
        assert gcs.arm(False) == DENIED
        assert emu.armed
        assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, 21196.0) == ACCEPTED
        assert not emu.armed


def test_arming_refused_without_local_position_then_allowed_with_vision() -> None:
    with Px4Emulator(None, fast(vision_only=True), api_port=(port := free_udp_port())) as emu, \
            RawGcs(port) as gcs:
        status = gcs.wait("SYS_STATUS", 1.0)
        assert not status.onboard_control_sensors_health & m.MAV_SYS_STATUS_SENSOR_VISION_POSITION
        assert gcs.arm() == DENIED
        gcs.vision(0.0, 0.0, 0.0)
        assert gcs.arm() == ACCEPTED
        assert emu.armed


def test_vision_only_position_times_out_and_the_vehicle_lands() -> None:
    cfg = fast(vision_only=True)
    with Px4Emulator(None, cfg, api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        take_off_offboard(gcs, emu, (0.0, 0.0, -1.0), vision=True)
        status = gcs.wait("SYS_STATUS", 1.0)
        assert status.onboard_control_sensors_health & m.MAV_SYS_STATUS_SENSOR_VISION_POSITION
        end = time.monotonic() + 1.0
        while time.monotonic() < end:  # setpoints continue, vision stops
            gcs.setpoint_ned(0.0, 0.0, -1.0)
            gcs.pump(0.05)
        status = gcs.wait("SYS_STATUS", 1.0)
        assert not status.onboard_control_sensors_health & m.MAV_SYS_STATUS_SENSOR_VISION_POSITION
        assert gcs.wait("LOCAL_POSITION_NED", 0.5) is None  # an invalid estimate is not published
        (_, _, message), = [e for e in emu.events if e[1] == "failsafe"]
        assert "position" in message
        assert emu.mode == "LAND"


def test_collision_with_an_obstacle_crashes_and_is_reported() -> None:
    world = parse_world({
        "name": "wall", "path": {"waypoints": [[0, 0, 1], [10, 0, 1]]},
        "bounds": {"floor_z": 0.0, "ceiling_z": 5.0},
        "obstacles": [{"type": "box", "center": [2.0, 0.0, 1.0], "size": [0.2, 4.0, 4.0]}],
    })
    with Px4Emulator(world, fast(), api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        take_off_offboard(gcs, emu, (0.0, 0.0, -1.0))
        assert not emu.crashed
        text = None
        end = time.monotonic() + 5.0
        while time.monotonic() < end and text is None:
            gcs.setpoint_ned(4.0, 0.0, -1.0)  # through the wall at x = 2 m
            text = gcs.wait("STATUSTEXT", 0.05, lambda s: b"crash" in bytes(s.text, "latin1")
                            if isinstance(s.text, str) else b"crash" in s.text)
        assert text is not None and text.severity <= m.MAV_SEVERITY_CRITICAL
        assert emu.crashed and not emu.armed
        assert emu.true_pose().pos_world_m[0] < 2.0 - 0.1 - 0.3 + 0.2  # stopped at the wall's face
        assert gcs.wait("EXTENDED_SYS_STATE", 1.0, lambda x: x.landed_state == m.MAV_LANDED_STATE_ON_GROUND)
        assert gcs.arm() == DENIED


def test_landing_on_the_floor_of_a_world_is_not_a_collision() -> None:
    world = parse_world({"name": "room", "path": {"waypoints": [[0, 0, 1], [10, 0, 1]]},
                         "bounds": {"floor_z": 0.0, "ceiling_z": 5.0}})
    with Px4Emulator(world, fast(), api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        take_off_offboard(gcs, emu, (0.0, 0.0, -1.0))
        assert gcs.command(m.MAV_CMD_NAV_LAND) == ACCEPTED
        assert emu.wait_for(lambda e: not e.armed, 5.0)
        assert not emu.crashed


def test_nan_and_junk_command_parameters_are_refused_not_fatal() -> None:
    with Px4Emulator(None, fast(), api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, math.nan) == DENIED
        assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 7.0) == DENIED
        assert gcs.command(m.MAV_CMD_DO_SET_MODE, 1.0, math.nan, math.nan) == UNSUPPORTED
        assert gcs.command(m.MAV_CMD_DO_SET_MODE, 1.0, 99.0, 0.0) == UNSUPPORTED
        assert gcs.command(m.MAV_CMD_DO_SET_ROI_LOCATION, 1.0) == UNSUPPORTED
        assert not emu.armed
        assert gcs.arm() == ACCEPTED  # the emulator is still alive and answering


def test_request_message_and_message_interval() -> None:
    with Px4Emulator(None, fast(), api_port=(port := free_udp_port())) as _emu, RawGcs(port) as gcs:
        assert gcs.command(m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == ACCEPTED
        version = gcs.wait("AUTOPILOT_VERSION", 1.0)
        assert version is not None and version.capabilities & m.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        lpos = m.MAVLINK_MSG_ID_LOCAL_POSITION_NED
        assert gcs.command(m.MAV_CMD_SET_MESSAGE_INTERVAL, lpos, -1) == ACCEPTED
        gcs.pump(0.1)
        assert gcs.wait("LOCAL_POSITION_NED", 0.4) is None
        assert gcs.command(m.MAV_CMD_SET_MESSAGE_INTERVAL, lpos, 0) == ACCEPTED
        assert gcs.wait("LOCAL_POSITION_NED", 0.4) is not None


def test_local_position_is_ned_of_the_world_position() -> None:
    start = np.array([1.0, 2.0, 0.0])  # x fwd, y left, z up
    with Px4Emulator(None, fast(), api_port=(port := free_udp_port()), start_pos_world_m=start) as _e, \
            RawGcs(port) as gcs:
        lp = gcs.wait("LOCAL_POSITION_NED", 1.0)
        assert (lp.x, lp.y, lp.z) == pytest.approx((1.0, -2.0, 0.0))
