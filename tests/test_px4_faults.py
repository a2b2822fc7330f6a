"""Fault injection (from tests and from a scenario file) and the ``quadnav-sim serve`` process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from quadnav_onboard.config import ConfigError
from sim_harness.px4 import EmulatorConfig, Px4Emulator, free_udp_port
from sim_harness.px4.client import RawGcs
from sim_harness.px4.mavlink_io import mavlink2 as m
from sim_harness.px4.scenario import apply_scenario, load_scenario

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(60)]

FAST = EmulatorConfig(heartbeat_hz=10.0)


def test_drop_link_silences_the_vehicle_for_the_window_then_it_returns() -> None:
    with Px4Emulator(None, FAST, api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        assert gcs.wait("HEARTBEAT", 1.0) is not None
        emu.faults.drop_link(0.0, 0.6)
        gcs.pump(0.05)  # what was already in flight
        assert gcs.wait("HEARTBEAT", 0.4) is None
        assert gcs.wait("HEARTBEAT", 1.0) is not None


def test_dropped_link_means_lost_commands_too() -> None:
    with Px4Emulator(None, FAST, api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        gcs.wait("HEARTBEAT", 1.0)
        emu.faults.drop_link(0.0, 1.0)
        assert gcs.arm(timeout_s=0.3) is None
        assert not emu.armed


def test_delay_link_delays_the_answer_by_both_ways() -> None:
    with Px4Emulator(None, FAST, api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        gcs.wait("HEARTBEAT", 1.0)
        emu.faults.delay_link(0.0, 5.0, delay_s=0.2)
        t0 = time.monotonic()
        assert gcs.arm(timeout_s=2.0) == m.MAV_RESULT_ACCEPTED
        assert time.monotonic() - t0 >= 0.4 - 0.02  # 0.2 s up + 0.2 s down


def test_freeze_position_holds_the_reported_position_while_the_vehicle_moves() -> None:
    with Px4Emulator(None, FAST, api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        for _ in range(4):
            gcs.setpoint_ned(0.0, 0.0, -1.0)
            gcs.pump(0.05)
        assert gcs.arm() == m.MAV_RESULT_ACCEPTED
        assert gcs.set_mode("OFFBOARD") == m.MAV_RESULT_ACCEPTED
        emu.faults.freeze_position(0.0, 0.8)
        gcs.setpoint_ned(0.0, 0.0, -1.0)
        gcs.pump(0.1)  # what the emulator sent before the freeze, still in the socket's buffer
        reported = []
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            gcs.setpoint_ned(0.0, 0.0, -1.0)
            lp = gcs.wait("LOCAL_POSITION_NED", 0.05)
            if lp is not None:
                reported.append(lp.z)
        assert len(reported) > 5 and len(set(reported)) == 1
        assert emu.true_pose().pos_world_m[2] > 0.1  # it climbed meanwhile
        gcs.setpoint_ned(0.0, 0.0, -1.0)
        gcs.pump(0.4)
        lp = gcs.wait("LOCAL_POSITION_NED", 0.2)
        assert lp.z < reported[0] - 0.1


def test_deny_mode_refuses_the_switch_until_allowed() -> None:
    with Px4Emulator(None, FAST, api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        emu.faults.deny_mode("LAND")
        assert gcs.command(m.MAV_CMD_NAV_LAND) == m.MAV_RESULT_DENIED
        assert gcs.set_mode("LAND") == m.MAV_RESULT_DENIED
        emu.faults.allow_mode("LAND")
        assert gcs.set_mode("LAND") == m.MAV_RESULT_ACCEPTED
        assert emu.mode == "LAND"


def test_crash_now_crashes_and_reports_it() -> None:
    with Px4Emulator(None, FAST, api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        assert gcs.arm() == m.MAV_RESULT_ACCEPTED
        emu.faults.crash_now()
        text = gcs.wait("STATUSTEXT", 1.0, lambda s: "crash" in str(s.text))
        assert text is not None
        assert emu.crashed and not emu.armed


def test_a_crash_in_flight_shows_in_the_attitude_and_the_vehicle_falls() -> None:
    """What a real vehicle reports of a crash: tipped over, disarmed, an emergency, on the floor."""
    from quadnav_onboard.frames import quat_to_rotmat

    with Px4Emulator(None, FAST, api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        for _ in range(4):
            gcs.setpoint_ned(0.0, 0.0, -1.5)
            gcs.pump(0.05)
        assert gcs.arm() == m.MAV_RESULT_ACCEPTED
        assert gcs.set_mode("OFFBOARD") == m.MAV_RESULT_ACCEPTED
        end = time.monotonic() + 1.5
        while time.monotonic() < end:
            gcs.setpoint_ned(0.0, 0.0, -1.5)
            gcs.pump(0.05)
        assert emu.true_pose().pos_world_m[2] > 1.0
        emu.faults.crash_now()
        att = gcs.wait("ATTITUDE_QUATERNION", 1.0, lambda a: abs(a.q1) < 0.9)
        assert att is not None
        tilt = np.degrees(np.arccos(quat_to_rotmat([att.q1, att.q2, att.q3, att.q4])[2, 2]))
        assert tilt > 80.0
        hb = gcs.wait("HEARTBEAT", 1.0, lambda h: h.system_status == m.MAV_STATE_EMERGENCY)
        assert hb is not None and not hb.base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED
        assert emu.wait_for(lambda e: e.true_pose().pos_world_m[2] == 0.0, 2.0)
        assert emu.wait_for(lambda e: e.landed_state == "ON_GROUND", 1.0)


def test_a_scenario_file_schedules_faults(tmp_path: Path) -> None:
    path = tmp_path / "faults.yaml"
    path.write_text("faults:\n  - {kind: deny_mode, mode: HOLD}\n  - {kind: crash, at_s: 0.3}\n")
    with Px4Emulator(None, FAST, api_port=(port := free_udp_port())) as emu, RawGcs(port) as gcs:
        apply_scenario(emu.faults, load_scenario(path))
        assert gcs.set_mode("HOLD") == m.MAV_RESULT_DENIED
        assert not emu.crashed
        assert emu.wait_for(lambda e: e.crashed, 2.0)
        assert emu.faults.mode_denied("HOLD")


@pytest.mark.parametrize(("text", "where"), [
    ("faults:\n  - {kind: explode}\n", "faults.0.kind"),
    ("faults:\n  - {kind: drop_link, at_s: -1}\n", "faults.0.at_s"),
    ("faults:\n  - {kind: deny_mode, mode: WARP}\n", "faults.0.mode"),
    ("faults:\n  - {kind: crash, when: 3}\n", "faults.0.when"),
])
def test_bad_scenario_files_name_the_file_and_key(tmp_path: Path, text: str, where: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    assert str(path) in str(err.value) and where in str(err.value)


def _serve(*args: str) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "sim_harness.cli", "serve", *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def test_serve_runs_the_emulator_until_sigint() -> None:
    port = free_udp_port()
    with RawGcs(port) as gcs:
        proc = _serve("--world", "env01", "--api-port", str(port), "--gcs-port", "0", "--heartbeat-hz", "10")
        try:
            hb = gcs.wait("HEARTBEAT", 20.0)
            assert hb is not None and hb.autopilot == m.MAV_AUTOPILOT_PX4
            assert gcs.arm() == m.MAV_RESULT_ACCEPTED
        finally:
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert f"udpin://0.0.0.0:{port}" in out and "stopped" in out


@pytest.mark.parametrize("args", [
    ["--world", "env42"], ["--world", "env01", "--api-port", "70000"],
    ["--world", "env01", "--heartbeat-hz", "0"],
])
def test_serve_rejects_bad_arguments_without_a_traceback(args: list[str]) -> None:
    proc = _serve(*args)
    _out, err = proc.communicate(timeout=30)
    assert proc.returncode == 2
    assert "quadnav-sim serve:" in err and "Traceback" not in err
