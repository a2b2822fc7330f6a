"""What real PX4 (v1.16 SITL) does that the emulator now does too, and how the daemon copes.

Pure parts with fake time (the emulator's vehicle logic, the ground frame, the parameter rules,
the odometry-rate sizing); end to end: the real daemon, real MAVSDK and real UDP against the
emulator configured as PX4 SITL behaved (ground offset at boot, 30 Hz odometry with jitter, a
one-off OFFBOARD refusal, landed-but-armed then auto-disarm, SITL parameter defaults).
"""

from __future__ import annotations

import asyncio
import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from quadnav_onboard.config import PrimitiveConfig, parse_config
from quadnav_onboard.daemon.app import FlightDaemon
from quadnav_onboard.daemon.config import (
    FlightConfig,
    MissionConfig,
    OdometrySourceConfig,
    SafetyConfig,
)
from quadnav_onboard.daemon.dryrun import DryRun
from quadnav_onboard.daemon.ground import measure_ground
from quadnav_onboard.daemon.px4_params import Severity, judge_parameters, parameter_rules
from quadnav_onboard.daemon.supervisor import (
    OdometryRate,
    check_odometry_rate,
    in_flight_stale_odometry_s,
    measure_odometry_rate,
)
from quadnav_onboard.policy import Policy
from quadnav_onboard.sources.base import OdometrySample
from quadnav_onboard.sources.px4_odometry import Px4OdometrySource
from sim_harness.px4 import EmulatorConfig, Px4Emulator
from sim_harness.px4 import telemetry as tm
from sim_harness.px4.bridge import SitlBridge
from sim_harness.px4.mavlink_io import mavlink2 as m
from sim_harness.px4.vehicle import Px4Vehicle, Setpoint

SITL_PARAMS = {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 0.0, "COM_RC_IN_MODE": 1.0, "COM_DISARM_LAND": 2.0,
               "EKF2_EV_CTRL": 0.0, "EKF2_HGT_REF": 1.0}
"""PX4 v1.16 SITL's defaults of the parameters preflight reads (measured over MAVLink)."""


# --- the emulator's vehicle logic (fake time) ------------------------------------------------------


def _offboard_airborne(cfg: EmulatorConfig) -> tuple[Px4Vehicle, float]:
    v = Px4Vehicle(cfg, np.zeros(3), 0.0, 0.0)
    t, dt = 0.0, 0.01
    assert v.arm(t).accepted
    v.on_companion_heartbeat(t)
    while t < 3.0:  # climb to 2 m in OFFBOARD, setpoints streaming
        v.on_setpoint(Setpoint(np.array([0.0, 0.0, 2.0]), None, None, t))
        if v.mode != "OFFBOARD":
            assert v.set_mode(t, "OFFBOARD").accepted
        v.on_companion_heartbeat(t)
        t += dt
        v.tick(t, dt)
    return v, t


def test_offboard_loss_follows_px4s_sequence_announce_hold_land_disarm() -> None:
    """Setpoints stop: after COM_OF_LOSS_T "Failsafe activated" and HOLD; after COM_FAIL_ACT_T
    LAND; after touchdown the auto-disarm; the companion's silence is announced after
    COM_OBC_LOSS_T; all within 30 s, as PX4 SITL did."""
    cfg = EmulatorConfig()
    v, t_lost = _offboard_airborne(cfg)
    t, dt = t_lost, 0.01
    seen: dict[str, float] = {}
    while t < t_lost + 30.0 and v.armed:
        t += dt
        v.tick(t, dt)
        for _, text in v.outbox:
            seen.setdefault(text, t - t_lost)
        v.outbox.clear()
        seen.setdefault(f"mode {v.mode}", t - t_lost)
    assert seen["Failsafe activated"] == pytest.approx(cfg.com_of_loss_t_s, abs=0.05)
    assert seen["mode HOLD"] == pytest.approx(cfg.com_of_loss_t_s, abs=0.05)
    assert seen["mode LAND"] == pytest.approx(cfg.com_of_loss_t_s + cfg.failsafe_delay_s, abs=0.05)
    assert seen["Connection to mission computer lost"] == pytest.approx(cfg.companion_loss_s, abs=0.05)
    assert not v.armed and v.landed_state == "ON_GROUND"
    assert t - t_lost < 30.0


def test_the_idealised_failsafe_holds_at_once_and_stays() -> None:
    """``offboard_loss_action: hold`` (the old behaviour) switches to HOLD and never lands."""
    v, t_lost = _offboard_airborne(EmulatorConfig.idealised())
    t = t_lost
    while t < t_lost + 10.0:
        t += 0.01
        v.tick(t, 0.01)
    assert v.mode == "HOLD" and v.armed


def test_a_one_off_offboard_refusal_with_a_live_stream() -> None:
    """``offboard_refusals: 1``: the first switch is refused although setpoints stream; the next
    one is accepted."""
    v = Px4Vehicle(EmulatorConfig(offboard_refusals=1), np.zeros(3), 0.0, 0.0)
    assert v.arm(0.0).accepted
    v.on_setpoint(Setpoint(np.zeros(3), None, None, 0.1))
    assert not v.set_mode(0.1, "OFFBOARD").accepted
    v.on_setpoint(Setpoint(np.zeros(3), None, None, 0.2))
    assert v.set_mode(0.2, "OFFBOARD").accepted


def test_the_estimators_origin_is_not_the_ground() -> None:
    """With a ground offset PX4's local height of the vehicle on the ground is the offset, and a
    setpoint's local height maps back to the world (what a GPS-height PX4 reports)."""
    emu = Px4Emulator(None, EmulatorConfig(ground_offset_m=0.3))
    lp = tm.local_position_ned(emu.snapshot(emu._t0))
    assert -lp.z == pytest.approx(0.3)
    assert EmulatorConfig(vision_only=True).ground_offset_m is None
    assert Px4Emulator(None, EmulatorConfig(vision_only=True)).ground_offset_m == 0.0


def test_the_drawn_ground_offset_lies_in_sitls_measured_range() -> None:
    """Unset, the offset is drawn (seeded) within -0.38..+0.33 m, as over 11 SITL starts."""
    drawn = [Px4Emulator(None, EmulatorConfig(seed=s)).ground_offset_m for s in range(20)]
    assert all(-0.38 <= d <= 0.33 for d in drawn) and len(set(drawn)) > 10


def test_fast_telemetry_is_a_jittered_grid() -> None:
    """At 30 Hz with jitter 0.5 the gaps reach ~49 ms, never more, and the mean rate stays 30 Hz."""
    emu = Px4Emulator(None, EmulatorConfig(seed=1))
    due, now = [], 0.0
    for _ in range(600):
        now = emu._next_due("ODOMETRY", 1 / 30, now)
        due.append(now)
    gaps = np.diff(due)
    assert gaps.max() <= 1 / 30 * 1.5 + 1e-9 and gaps.max() > 0.045
    assert (len(due) - 1) / (due[-1] - due[0]) == pytest.approx(30.0, rel=0.01)


def test_sitl_parameter_defaults_are_reported() -> None:
    """The emulator's parameters are PX4 SITL's defaults (what preflight reads)."""
    emu = Px4Emulator(None, EmulatorConfig())
    values = {n: emu.commands.params[n][0] for n in SITL_PARAMS}
    assert values == SITL_PARAMS


def test_integer_parameters_go_bytewise_as_px4_sends_them() -> None:
    """An INT32 parameter's bytes travel in PARAM_VALUE's float field (what MAVSDK decodes for
    PX4); a PARAM_SET of one is decoded the same way."""
    import struct

    from sim_harness.px4.commands import _from_wire, _wire_value

    wire = _wire_value(5.0, m.MAV_PARAM_TYPE_INT32)
    assert struct.unpack("<i", struct.pack("<f", wire))[0] == 5
    assert _from_wire(wire, m.MAV_PARAM_TYPE_INT32) == 5.0
    assert _wire_value(1.5, m.MAV_PARAM_TYPE_REAL32) == 1.5


# --- the daemon's pure parts -----------------------------------------------------------------------


def test_the_ground_frame_puts_z_zero_on_the_ground_and_setpoints_back_into_px4s_frame() -> None:
    """PX4's own estimate (-0.38 m on the ground): the daemon sees z = 0 there, and a setpoint 2 m
    above the ground goes to PX4 as 1.62 m of its frame."""
    g = measure_ground(np.array([1.0, 2.0, -0.38]), None)
    s = g.to_world(OdometrySample(np.array([1.0, 2.0, -0.38]), np.array([1.0, 0, 0, 0]), 0.0))
    assert s.pos_world_m.tolist() == pytest.approx([1.0, 2.0, 0.0])
    assert g.to_px4(np.array([1.0, 2.0, 2.0])).tolist() == pytest.approx([1.0, 2.0, 1.62])


def test_mocap_flown_against_a_px4_on_gps_sends_setpoints_in_px4s_frame() -> None:
    """Mocap says 0.05 m, PX4 says 0.30 m: the ground is the mocap's 0.05, a setpoint goes to
    PX4 shifted by PX4's offset from the ground frame."""
    g = measure_ground(np.array([0.0, 0.0, 0.05]), np.array([0.1, 0.0, 0.30]))
    assert g.ground_z_m == pytest.approx(0.05)
    assert g.to_px4(np.array([0.0, 0.0, 2.0])).tolist() == pytest.approx([0.1, 0.0, 2.30])


def test_a_configured_ground_ignores_the_vehicles_height() -> None:
    """``ground_reference: configured``: the ground is ``ground_z_m``, wherever the vehicle is."""
    g = measure_ground(np.array([0.0, 0.0, 0.2]), None, configured_z_m=-0.1)
    assert g.ground_z_m == -0.1 and g.source == "configured"


def test_the_stale_limit_is_sized_from_the_measured_rate() -> None:
    """30 Hz with 49 ms gaps keeps the 0.1 s limit; 10 Hz raises it to 3 periods; 50 Hz keeps it;
    never above 1 s."""
    cfg = SafetyConfig()
    assert in_flight_stale_odometry_s(cfg, OdometryRate(30.0, 0.049, 30)) == pytest.approx(0.1)
    assert in_flight_stale_odometry_s(cfg, OdometryRate(10.0, 0.12, 10)) == pytest.approx(0.3)
    assert in_flight_stale_odometry_s(cfg, OdometryRate(50.0, 0.03, 50)) == pytest.approx(0.1)
    assert in_flight_stale_odometry_s(cfg, OdometryRate(1.0, 2.0, 3)) == 1.0
    assert in_flight_stale_odometry_s(cfg, None) == cfg.stale_odometry_s


def test_preflight_measures_the_odometry_rate_and_refuses_a_slow_stream() -> None:
    """31 samples over a second: ~30 Hz; below min_odometry_rate_hz the check fails (retry)."""
    arrivals = [k / 30 for k in range(31)]
    rate = measure_odometry_rate(arrivals, 1.0)
    assert rate is not None and rate.rate_hz == pytest.approx(30.0) and rate.n == 31
    assert check_odometry_rate(rate, 20.0).ok
    slow = check_odometry_rate(rate, 40.0)
    assert not slow.ok and slow.retry
    assert not check_odometry_rate(measure_odometry_rate([0.5], 1.0), 20.0).ok


def test_sitl_defaults_pass_on_px4_odometry_with_advice() -> None:
    """PX4's own estimate: SITL's defaults are no refusal; RC input mode and the EV parameters are
    advice."""
    cfg = FlightConfig(odometry=OdometrySourceConfig(kind="px4"))
    found = judge_parameters(parameter_rules(cfg), SITL_PARAMS)
    assert not [f for f in found if f.severity is Severity.REQUIRED]
    assert {f.name for f in found} == {"COM_RC_IN_MODE", "EKF2_EV_CTRL", "EKF2_HGT_REF"}


def test_forwarded_mocap_requires_the_vision_parameters() -> None:
    """Mocap forwarded to EKF2 on SITL's defaults: EKF2_EV_CTRL and EKF2_HGT_REF are required; a
    parameter PX4 did not answer is a finding too."""
    cfg = FlightConfig(odometry=OdometrySourceConfig(kind="mocap", forward_to_px4=True))
    found = judge_parameters(parameter_rules(cfg), {**SITL_PARAMS, "COM_OF_LOSS_T": None})
    required = {f.name for f in found if f.severity is Severity.REQUIRED}
    assert required == {"EKF2_EV_CTRL", "EKF2_HGT_REF", "COM_OF_LOSS_T"}


# --- the bridge (a SITL's reported state as the sim's truth) ---------------------------------------


def _msg(msg: Any, sysid: int = 1, comp: int = 1) -> Any:
    mav = m.MAVLink(None, srcSystem=sysid, srcComponent=comp)
    return mav.decode(bytearray(msg.pack(mav)))


def test_the_bridge_anchors_the_ground_and_follows_px4s_position() -> None:
    """Disarmed on the ground at PX4 height -0.3 m: the world floor. Armed and 2 m up in PX4's
    frame: 2.3 m above the floor, x/y as PX4's north/east turned into x forward / y left."""
    b = SitlBridge(0.0)
    assert b.on_message(_msg(m.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3)), 0.0) is False
    assert b.on_message(_msg(m.MAVLink_local_position_ned_message(0, 1.0, 2.0, 0.3, 0, 0, 0)), 0.1)
    assert b.pose is not None and b.pose.pos_world_m.tolist() == pytest.approx([1.0, -2.0, 0.0])
    b.on_message(_msg(m.MAVLink_heartbeat_message(2, 12, m.MAV_MODE_FLAG_SAFETY_ARMED, 0, 4, 3)), 0.2)
    b.on_message(_msg(m.MAVLink_extended_sys_state_message(0, 2)), 0.2)
    b.on_message(_msg(m.MAVLink_local_position_ned_message(0, 1.0, 2.0, -2.0, 0, 0, 0)), 0.3)
    assert b.pose.pos_world_m.tolist() == pytest.approx([1.0, -2.0, 2.3]) and b.armed


def test_the_bridge_takes_one_autopilot_and_latches_a_crash() -> None:
    """Another system's messages are ignored; a sweep through an obstacle is a crash."""
    b = SitlBridge(0.0, collide=lambda prev, new: new[0] > 5.0)
    b.on_message(_msg(m.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3)), 0.0)
    assert not b.on_message(_msg(m.MAVLink_local_position_ned_message(0, 9, 0, 0, 0, 0, 0), sysid=2), 0.1)
    b.on_message(_msg(m.MAVLink_local_position_ned_message(0, 4.0, 0, 0, 0, 0, 0)), 0.1)
    assert not b.crashed
    b.on_message(_msg(m.MAVLink_local_position_ned_message(0, 6.0, 0, 0, 0, 0, 0)), 0.2)
    assert b.crashed


# --- end to end ------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory, straight_world: Callable[[Path, float], Path]) -> Path:
    return straight_world(tmp_path_factory.mktemp("w"), 3.0)


def _config(**safety: Any) -> FlightConfig:
    prims = parse_config(PrimitiveConfig, {"scale_m": 0.5, "duration_s": 0.5})
    return FlightConfig(
        mission=MissionConfig(takeoff_speed_m_s=2.0, max_steps=30),
        primitives=prims,
        safety=SafetyConfig(**{"hold_before_land_s": 0.3, "land_timeout_s": 15.0, **safety}),
        odometry=OdometrySourceConfig(kind="px4"),
    )


async def _fly(world: Path, model: Path, cfg: FlightConfig, **emulator: Any) -> tuple[Any, DryRun, list]:
    with DryRun(cfg, world, emulator={"heartbeat_hz": 10.0, **emulator}) as sim:
        parts = sim.parts()
        parts["odometry"] = Px4OdometrySource(parts["vehicle"])  # PX4's own estimate, as on SITL
        daemon = FlightDaemon(sim.cfg, policy=Policy.from_path(model), **parts)
        heights: list[tuple[float, float]] = []
        """(true height above the floor, the daemon's odometry height) pairs during the flight."""

        async def watch() -> None:
            while True:
                odom = daemon.latest_odom.value
                if odom is not None:
                    true_z = float(sim.emulator.true_pose().pos_world_m[2])
                    heights.append((true_z, float(odom.pos_world_m[2])))
                await asyncio.sleep(0.05)

        task = asyncio.ensure_future(watch())
        summary = await asyncio.wait_for(daemon.run(), 90)
        task.cancel()
        return summary, sim, heights


@pytest.mark.e2e
@pytest.mark.slow
async def test_a_sitl_like_px4_is_flown_relative_to_the_ground(world: Path, forward_model: Path) -> None:
    """Against the emulator behaving as SITL did (the ground at +0.35 m of PX4's frame, 30 Hz
    odometry with jitter, the first OFFBOARD start refused, auto-disarm 2 s after touchdown): the
    daemon asks for 50 Hz odometry and gets it, flies the path's height above the ground, retries
    OFFBOARD once, waits for PX4's own disarm, and compiles nothing after arming."""
    s, sim, heights = await _fly(world, forward_model, _config(), ground_offset_m=0.35, offboard_refusals=1)
    assert s.stop_reason == "goal_reached" and s.exit_code == 0, s
    st = s.startup
    assert st["ground"]["ground_z_m"] == pytest.approx(0.35, abs=0.02) and st["ground"]["source"] == "takeoff"
    assert st["offboard_start_attempts"] == 2
    assert st["odometry"]["measured_hz"] > 40  # asked for 50 Hz; the emulator's default is 30
    sized = max(0.1, 2e-3 * st["odometry"]["max_gap_ms"])  # the 0.1 s limit, or twice the worst gap
    assert st["odometry"]["stale_limit_s"] == pytest.approx(sized, abs=2e-3)
    assert st["px4_parameters"]["required"] == [] and st["kernels_compiled_in_flight"] == {}
    read = st["px4_parameters"]["values"]  # over MAVSDK's param plugin, integers bytewise
    assert {k: read[k] for k in SITL_PARAMS} == SITL_PARAMS
    pairs = np.array(heights)
    flying = pairs[pairs[:, 0] > 0.5]  # PX4's frame is 0.35 m off the floor; the daemon's is not
    assert len(flying) > 10 and float(np.median(np.abs(flying[:, 0] - flying[:, 1]))) < 0.05
    assert s.landing == {"landed": True, "disarm": "auto", "waited_s": s.landing["waited_s"]}
    assert 1.0 < s.landing["waited_s"] < 3.5 and not sim.emulator.armed


@pytest.mark.e2e
@pytest.mark.slow
async def test_landed_but_armed_past_the_wait_is_disarmed_by_the_daemon(
    world: Path, forward_model: Path
) -> None:
    """PX4's auto-disarm later than ``auto_disarm_wait_s``: the daemon disarms and says so."""
    s, sim, _ = await _fly(world, forward_model, _config(auto_disarm_wait_s=0.5), land_disarm_s=20.0)
    assert s.stop_reason == "goal_reached"
    assert s.landing["disarm"] == "commanded" and s.landing["waited_s"] >= 0.5
    assert not sim.emulator.armed
    disarms = [msg for _, kind, msg in sim.emulator.events if kind == "disarmed"]
    assert disarms == ["Disarmed by external command"]


@pytest.mark.e2e
@pytest.mark.slow
async def test_forwarded_mocap_on_sitls_defaults_is_refused_naming_the_parameters(
    world: Path, forward_model: Path
) -> None:
    """Mocap forwarded to an EKF2 that does not fuse vision (SITL's defaults): refused before
    arming, the refusal naming EKF2_EV_CTRL and EKF2_HGT_REF."""
    cfg = dataclasses.replace(_config(), odometry=OdometrySourceConfig(kind="mocap", forward_to_px4=True))
    with DryRun(cfg, world, emulator={"heartbeat_hz": 10.0}) as sim:
        daemon = FlightDaemon(sim.cfg, policy=Policy.from_path(forward_model), **sim.parts())
        s = await asyncio.wait_for(daemon.run(), 60)
        assert not sim.emulator.armed
    assert s.stop_reason == "preflight_failed" and s.exit_code == 2
    named = {f.split("=")[0] for f in s.startup["px4_parameters"]["required"]}
    assert named == {"EKF2_EV_CTRL", "EKF2_HGT_REF"}
    assert "EKF2_EV_CTRL=0" in s.detail and "EKF2_HGT_REF=1" in s.detail  # the operator's list


@pytest.mark.e2e
@pytest.mark.slow
def test_the_bridge_part_writes_what_a_px4_reports_into_the_truth(
    tmp_path: Path, straight_world: Callable[[Path, float], Path]
) -> None:
    """The vehicle side with a bridge instead of the emulator: a PX4 (here the emulator, on its
    GCS-like port, the ground at +0.3 m of its frame) streams to the bridge's port; the truth the
    camera renders from is the vehicle's world position, on the floor."""
    from sim_harness.px4 import free_udp_port
    from sim_harness.vehicle_side import VehicleSide

    w = straight_world(tmp_path, 3.0)
    with pytest.raises(ValueError):
        VehicleSide(w, bridge={"port": 1}, parts=("vehicle", "camera"))
    port = free_udp_port()
    with Px4Emulator(None, EmulatorConfig(ground_offset_m=0.3, heartbeat_hz=10.0), api_port=port,
                     start_pos_world_m=np.array([1.0, -0.5, 0.0])) as emu, \
            VehicleSide(w, bridge={"port": port, "wait_s": 20.0}, parts=("bridge",)) as side:
        assert side.parts["bridge"].info["ground_up_m"] == pytest.approx(0.3, abs=1e-6)
        assert side.truth is not None
        truth = side.truth.read()
        assert truth.pos_world_m.tolist() == pytest.approx(emu.true_pose().pos_world_m.tolist(), abs=1e-6)
        assert not truth.crashed and not truth.armed


@pytest.mark.e2e
@pytest.mark.slow
def test_the_one_command_sitl_mode_flies_a_px4_through_the_sim_world(tmp_path: Path) -> None:
    """``quadnav-onboard --dry-run --px4-sitl PORT --config config/px4-sitl.yaml``, with the
    emulator standing in for a user's SITL (its API link to the daemon, its GCS link to the
    bridge, the ground at -0.3 m of its frame): the daemon reaches the goal 6 m on, PX4 disarms
    after the landing, nothing compiles after arming."""
    import json
    import subprocess
    import sys

    import yaml

    from sim_harness.px4 import free_udp_port

    repo = Path(__file__).resolve().parents[1]
    cfg = yaml.safe_load((repo / "config" / "px4-sitl.yaml").read_text())
    api, gcs = free_udp_port(), free_udp_port()
    cfg["vehicle"]["url"] = f"udpin://127.0.0.1:{api}"
    cfg["mission"]["waypoints_m"] = [[0.0, 0.0, 2.0], [6.0, 0.0, 2.0]]
    cfg["record"]["enabled"] = False
    path = tmp_path / "px4-sitl.yaml"
    path.write_text(yaml.safe_dump(cfg))
    with Px4Emulator(None, EmulatorConfig(ground_offset_m=-0.3), api_port=api, gcs_port=gcs) as emu:
        done = subprocess.run(
            [sys.executable, "-m", "quadnav_onboard.cli", "--dry-run", "--px4-sitl", str(gcs), "--config",
             str(path), "--json", "--log-format", "json"],
            cwd=repo, capture_output=True, text=True, timeout=240,
        )
        assert emu.wait_for(lambda e: not e.armed, 5.0)
    assert done.returncode == 0, done.stderr[-3000:]
    s = json.loads(done.stdout.strip().splitlines()[-1])
    assert s["stop_reason"] == "goal_reached" and s["navigation_distance_m"] > 5.0 and not s["crashed"]
    assert s["startup"]["ground"]["ground_z_m"] == pytest.approx(-0.3, abs=0.02)
    assert s["landing"]["disarm"] == "auto" and s["startup"]["kernels_compiled_in_flight"] == {}
    assert s["depth_frames"]["received"] > 100  # rendered from the bridged state, no frame folder
