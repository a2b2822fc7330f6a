"""End to end: the real MAVSDK (native binding, asyncio API) flies the emulated PX4 over real UDP.

No mocks between: MAVSDK listens on an OS-chosen loopback port, the emulator sends to it, and the
vehicle moves only through the setpoints MAVSDK streams.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator

import numpy as np
import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk, System
from mavsdk.asyncio.plugins.action import ActionAsync, ActionError
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
from mavsdk.asyncio.plugins.telemetry import LandedState, TelemetryAsync

from quadnav_onboard.frames import frd_to_flu
from sim_harness.px4 import EmulatorConfig, Px4Emulator, free_udp_port

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(60)]

FAST = EmulatorConfig.idealised(heartbeat_hz=10.0, land_disarm_s=0.3)  # the ground at z = 0


@contextlib.asynccontextmanager
async def connected(emu: Px4Emulator) -> AsyncIterator[System]:
    """MAVSDK (as a companion computer) connected to ``emu``."""
    config = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
    async with Mavsdk(config) as sdk:
        await sdk.add_any_connection(f"udpin://127.0.0.1:{emu.api_port}")
        drone = await sdk.first_autopilot(timeout_s=5.0)
        assert drone is not None, "MAVSDK found no autopilot"
        yield drone


async def wait_health_local_position(tel: TelemetryAsync, ok: bool, timeout_s: float = 5.0) -> None:
    async with asyncio.timeout(timeout_s):
        async for health in tel.subscribe_health():
            if health.is_local_position_ok == ok:
                return


async def test_mavsdk_connects_arms_flies_offboard_lands_and_disarms() -> None:
    """The whole flight through MAVSDK: the quad reaches the setpoint within 0.1 m, lands, disarms."""
    target_ned = np.array([1.5, -0.5, -1.2])  # 1.5 m forward, 0.5 m left, 1.2 m up
    with Px4Emulator(None, FAST, api_port=free_udp_port()) as emu:
        async with connected(emu) as drone:
            tel, action, offboard = TelemetryAsync(drone), ActionAsync(drone), OffboardAsync(drone)
            await wait_health_local_position(tel, ok=True)
            await action.arm()
            assert emu.armed
            await offboard.set_position_ned(PositionNedYaw(*target_ned, 0.0))
            await offboard.start()
            assert emu.mode == "OFFBOARD"
            target_world = frd_to_flu(target_ned)
            async with asyncio.timeout(8.0):
                while np.linalg.norm(emu.true_pose().pos_world_m - target_world) > 0.1:
                    await offboard.set_position_ned(PositionNedYaw(*target_ned, 0.0))
                    await asyncio.sleep(0.05)
            reported = await tel.position_velocity_ned()
            assert abs(reported.position.north_m - target_ned[0]) < 0.1
            assert abs(reported.position.east_m - target_ned[1]) < 0.1
            assert abs(reported.position.down_m - target_ned[2]) < 0.1
            assert await tel.in_air()
            await offboard.stop()
            assert emu.mode == "HOLD"
            await action.land()
            async with asyncio.timeout(6.0):
                async for armed in tel.subscribe_armed():
                    if not armed:
                        break
            async with asyncio.timeout(2.0):
                async for landed in tel.subscribe_landed_state():
                    if landed == LandedState.ON_GROUND:
                        break
        assert not emu.armed
        assert emu.true_pose().pos_world_m[2] == pytest.approx(0.0, abs=1e-6)
        kinds = [kind for _, kind, _ in emu.events]
        assert kinds.index("touchdown") < kinds.index("disarmed")


async def test_mavsdk_takeoff_climbs_to_takeoff_altitude_and_holds() -> None:
    """Action.takeoff (NAV_TAKEOFF with NaN altitude) climbs to MIS_TAKEOFF_ALT and then holds."""
    cfg = EmulatorConfig.idealised(heartbeat_hz=10.0, takeoff_alt_m=1.0)
    with Px4Emulator(None, cfg, api_port=free_udp_port()) as emu:
        async with connected(emu) as drone:
            tel, action = TelemetryAsync(drone), ActionAsync(drone)
            await wait_health_local_position(tel, ok=True)
            await action.arm()
            await action.takeoff()
            assert await asyncio.to_thread(emu.wait_for, lambda e: e.mode == "HOLD", 6.0)
            assert emu.true_pose().pos_world_m[2] == pytest.approx(1.0, abs=0.1)
            await asyncio.sleep(0.5)
            assert emu.true_pose().pos_world_m[2] == pytest.approx(1.0, abs=0.1)


async def test_mavsdk_sees_arming_refused_without_local_position() -> None:
    """Vision-only with no vision data: health says no local position and arming is denied."""
    cfg = EmulatorConfig(heartbeat_hz=10.0, vision_only=True)
    with Px4Emulator(None, cfg, api_port=free_udp_port()) as emu:
        async with connected(emu) as drone:
            tel, action = TelemetryAsync(drone), ActionAsync(drone)
            await asyncio.sleep(0.5)  # a few SYS_STATUS
            assert not (await tel.health()).is_local_position_ok
            with pytest.raises(ActionError):
                await action.arm()
        assert not emu.armed
        assert any(kind == "arm" and "local position" in msg for _, kind, msg in emu.events)
