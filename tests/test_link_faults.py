"""End to end: the wrong vehicle or a dead one. The real daemon, real MAVSDK and real UDP against
emulated PX4s (sim_harness.px4.Px4Emulator), flown by sim_harness.px4.link_rig: depth is a
constant free view and odometry the emulator's true pose (a mocap), both in this process.
"""

from __future__ import annotations

import time

import pytest

from quadnav_onboard.daemon.testing import constant_action_checkpoint
from quadnav_onboard.policy import Policy
from sim_harness.px4 import EmulatorConfig, Px4Emulator, free_udp_port
from sim_harness.px4.link_rig import LinkFlight, modes_entered

pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.timeout(120)]

FAST = EmulatorConfig(heartbeat_hz=10.0)
FORWARD = 4


@pytest.fixture(scope="module")
def policy(tmp_path_factory: pytest.TempPathFactory) -> Policy:
    return Policy(constant_action_checkpoint(str(tmp_path_factory.mktemp("m") / "fwd.pt"), FORWARD))


async def test_two_autopilots_with_one_system_id_on_the_port_refuse_the_start(policy: Policy) -> None:
    port = free_udp_port()
    with Px4Emulator(None, FAST, api_port=port) as a, Px4Emulator(None, FAST, api_port=port) as b:
        flight = LinkFlight(policy, a, port)
        s = await flight.run()
        assert s.stop_reason == "preflight_failed" and s.exit_code == 2, s
        for emu in (a, b):
            assert str(emu.local_ports[0]) in s.detail  # both candidates named
            assert not emu.armed and "COMMAND_LONG" not in emu.seen_message_types
        assert flight.vehicle.calls == []


async def test_no_autopilot_on_the_link_is_a_refusal(policy: Policy) -> None:
    port = free_udp_port()
    flight = LinkFlight(policy, Px4Emulator(None, FAST, api_port=free_udp_port()), port)  # never started
    flight.vehicle.connect_timeout_s = 1.0
    s = await flight.run()
    assert s.stop_reason == "preflight_failed" and s.exit_code == 2, s
    assert flight.vehicle.calls == []


async def test_the_vehicles_source_changing_in_flight_stops_and_only_the_bound_vehicle_is_commanded(
    policy: Policy,
) -> None:
    port = free_udp_port()
    with Px4Emulator(None, FAST, api_port=port) as emu:
        second: list[Px4Emulator] = []
        flight = LinkFlight(policy, emu, port)
        try:
            s = await flight.run(lambda f: second.append(Px4Emulator(None, FAST, api_port=port).start()))
            assert s.stop_reason == "link_source_changed" and s.exit_code == 3, s
            assert str(second[0].local_ports[0]) in s.detail
            assert modes_entered(emu)[-2:] == ["HOLD", "LAND"]  # the bound vehicle was brought down
            seen = second[0].seen_message_types
            assert not second[0].armed
            assert "COMMAND_LONG" not in seen and "SET_POSITION_TARGET_LOCAL_NED" not in seen
        finally:
            for other in second:
                other.stop()


@pytest.mark.parametrize("odometry_dies_too", [False, True])
async def test_killing_the_vehicle_mid_flight_is_link_lost_released_without_commands(
    policy: Policy, odometry_dies_too: bool
) -> None:
    """Odometry riding the link (or a mocap that dies with the vehicle) goes stale before the link
    times out; the stop is still link_lost, and nothing is sent into the dead link."""
    port = free_udp_port()
    with Px4Emulator(None, FAST, api_port=port) as emu:
        flight = LinkFlight(policy, emu, port)

        def kill(f: LinkFlight) -> None:
            f.emu.stop()
            if odometry_dies_too:
                f.odometry.paused = True

        s = await flight.run(kill)
        t_done = time.monotonic()
        assert s.stop_reason == "link_lost" and s.exit_code == 3, s
        assert flight.t_fault is not None
        assert flight.vehicle.commands_after(flight.t_fault) == []  # no hold, no land
        assert t_done - flight.t_fault < 5.0  # released at once, no land timeout waited out (15 s)


async def test_a_crash_reported_by_the_vehicle_is_a_crash_not_an_altitude_stop(policy: Policy) -> None:
    """No crash probe (as on a real vehicle): the emulator's crash is seen in its telemetry."""
    port = free_udp_port()
    with Px4Emulator(None, FAST, api_port=port) as emu:
        flight = LinkFlight(policy, emu, port)
        assert flight.daemon.crash_probe is None
        s = await flight.run(lambda f: f.emu.faults.crash_now())
        assert s.stop_reason == "crash" and s.exit_code == 4 and s.crashed, s


@pytest.mark.parametrize("px4_odometry", [False, True], ids=["mocap", "px4-odometry"])
async def test_a_frozen_position_estimate_stops_the_flight_as_bad_odometry(
    policy: Policy, px4_odometry: bool
) -> None:
    """The emulator's freeze_position: PX4's reported position stops moving (fresh timestamps)
    while the setpoint moves on; with mocap the daemon's own odometry still moves."""
    port = free_udp_port()
    with Px4Emulator(None, FAST, api_port=port) as emu:
        flight = LinkFlight(policy, emu, port, px4_odometry=px4_odometry)
        s = await flight.run(lambda f: f.emu.faults.freeze_position(0.0, 1.0))
        assert s.stop_reason == "bad_odometry" and s.exit_code == 3, s
        assert "frozen" in s.detail
        assert modes_entered(emu)[-2:] == ["HOLD", "LAND"]

