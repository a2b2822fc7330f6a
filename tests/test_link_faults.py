"""End to end: the wrong vehicle or a dead one. The real daemon, real MAVSDK and real UDP against
emulated PX4s (sim_harness.px4.Px4Emulator); depth is a constant free view and odometry the
emulator's true pose (a mocap), both in this process: the link is the subject here.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from quadnav_onboard.config import PrimitiveConfig, parse_config
from quadnav_onboard.daemon.app import FlightDaemon
from quadnav_onboard.daemon.config import FlightConfig, MissionConfig, SafetyConfig, VehicleConfig
from quadnav_onboard.daemon.summary import FlightSummary
from quadnav_onboard.daemon.testing import FakeDepthSource, FakeOdometrySource, constant_action_checkpoint
from quadnav_onboard.path import RoughPath
from quadnav_onboard.policy import Policy
from quadnav_onboard.sources.px4_odometry import Px4OdometrySource
from quadnav_onboard.vehicle import MavsdkVehicle
from sim_harness.px4 import EmulatorConfig, Px4Emulator, free_udp_port

pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.timeout(120)]

PATH = RoughPath(np.array([[0.0, 0.0, 1.5], [3.0, 0.0, 1.5]]), 1.0)
FAST = EmulatorConfig(heartbeat_hz=10.0)
FORWARD = 4


@pytest.fixture(scope="module")
def policy(tmp_path_factory: pytest.TempPathFactory) -> Policy:
    return Policy(constant_action_checkpoint(str(tmp_path_factory.mktemp("m") / "fwd.pt"), FORWARD))


class SpyVehicle(MavsdkVehicle):
    """The real MAVSDK vehicle, noting every command it is asked to send (with the time)."""

    def __init__(self, url: str) -> None:
        super().__init__(url, connect_timeout_s=10.0, command_timeout_s=3.0)
        self.calls: list[tuple[float, str]] = []

    async def _command(self, name: str, coro_fn: Any) -> None:
        self.calls.append((time.monotonic(), name))
        await super()._command(name, coro_fn)

    def commands_after(self, t_mono_s: float) -> list[str]:
        return [name for t, name in self.calls if t >= t_mono_s]


def config(port: int) -> FlightConfig:
    return FlightConfig(
        mission=MissionConfig(takeoff_speed_m_s=2.0, max_steps=30),
        primitives=parse_config(PrimitiveConfig, {"scale_m": 0.5, "duration_s": 0.5}),
        safety=SafetyConfig(hold_before_land_s=0.3, land_timeout_s=15.0),
        vehicle=VehicleConfig(url=f"udpin://127.0.0.1:{port}", connect_timeout_s=10.0, command_timeout_s=3.0),
    )


class Flight:
    """One daemon against the emulator ``emu`` (already started on ``port``)."""

    def __init__(self, policy: Policy, emu: Px4Emulator, port: int, px4_odometry: bool = False) -> None:
        self.emu = emu
        self.vehicle = SpyVehicle(f"udpin://127.0.0.1:{port}")
        self.odometry: Any = (
            Px4OdometrySource(self.vehicle)
            if px4_odometry
            else FakeOdometrySource(lambda: emu.true_pose().pos_world_m, rate_hz=100.0)
        )
        self.daemon = FlightDaemon(
            config(port),
            path=PATH,
            policy=policy,
            depth=FakeDepthSource(fps=30.0),
            odometry=self.odometry,
            vehicle=self.vehicle,
        )
        self.t_fault: float | None = None

    async def run(self, fault: Callable[[Flight], None] | None = None) -> FlightSummary:
        async def inject() -> None:
            while not (self.daemon.in_mission and self.daemon.steps >= 1):
                await asyncio.sleep(0.02)
            self.t_fault = time.monotonic()
            fault(self)  # type: ignore[misc]

        task = asyncio.ensure_future(inject()) if fault else None
        try:
            return await asyncio.wait_for(self.daemon.run(), 60)
        finally:
            if task is not None:
                task.cancel()


def modes_entered(emu: Px4Emulator) -> list[str]:
    return [msg.split(" -> ")[1] for _, kind, msg in emu.events if kind == "mode"]


async def test_two_autopilots_with_one_system_id_on_the_port_refuse_the_start(policy: Policy) -> None:
    port = free_udp_port()
    with Px4Emulator(None, FAST, api_port=port) as a, Px4Emulator(None, FAST, api_port=port) as b:
        flight = Flight(policy, a, port)
        s = await flight.run()
        assert s.stop_reason == "preflight_failed" and s.exit_code == 2, s
        for emu in (a, b):
            assert str(emu.local_ports[0]) in s.detail  # both candidates named
            assert not emu.armed and "COMMAND_LONG" not in emu.seen_message_types
        assert flight.vehicle.calls == []


async def test_the_vehicles_source_changing_in_flight_stops_and_only_the_bound_vehicle_is_commanded(
    policy: Policy,
) -> None:
    port = free_udp_port()
    with Px4Emulator(None, FAST, api_port=port) as emu:
        second: list[Px4Emulator] = []
        flight = Flight(policy, emu, port)
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
        flight = Flight(policy, emu, port)

        def kill(f: Flight) -> None:
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
        flight = Flight(policy, emu, port)
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
        flight = Flight(policy, emu, port, px4_odometry=px4_odometry)
        s = await flight.run(lambda f: f.emu.faults.freeze_position(0.0, 1.0))
        assert s.stop_reason == "bad_odometry" and s.exit_code == 3, s
        assert "frozen" in s.detail
        assert modes_entered(emu)[-2:] == ["HOLD", "LAND"]

