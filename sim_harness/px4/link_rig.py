"""One flight of the real daemon against an emulated PX4, for link and fault tests and benchmarks.

The real :class:`~quadnav_onboard.daemon.app.FlightDaemon`, the real MAVSDK vehicle link and real
UDP to a :class:`~sim_harness.px4.Px4Emulator` started by the caller; depth is a constant free
view and odometry the emulator's true pose (a mocap), or PX4's own ODOMETRY, both in this process:
the link and the vehicle are the subject, not the camera. A fault is injected once the mission
has made its first step, and every moment that matters is stamped (``time.monotonic()``).

    with Px4Emulator(None, EmulatorConfig(heartbeat_hz=10.0), api_port=port) as emu:
        flight = LinkFlight(policy, emu, port)
        summary = await flight.run(lambda f: f.emu.faults.crash_now())
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from quadnav_onboard.config import PrimitiveConfig, parse_config
from quadnav_onboard.daemon.app import FlightDaemon
from quadnav_onboard.daemon.config import FlightConfig, MissionConfig, SafetyConfig, VehicleConfig
from quadnav_onboard.daemon.summary import FlightSummary
from quadnav_onboard.daemon.supervisor import StopReason
from quadnav_onboard.daemon.testing import FakeDepthSource, FakeOdometrySource
from quadnav_onboard.path import RoughPath
from quadnav_onboard.policy import Policy
from quadnav_onboard.sources.px4_odometry import Px4OdometrySource
from quadnav_onboard.vehicle import MavsdkVehicle
from sim_harness.px4.emulator import Px4Emulator

__all__ = ["PATH", "LinkFlight", "SpyVehicle", "flight_config", "modes_entered"]

PATH = RoughPath(np.array([[0.0, 0.0, 1.5], [3.0, 0.0, 1.5]]), 1.0)
"""A 3 m free path at 1.5 m (the emulator's floor is z = 0)."""


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


def flight_config(port: int) -> FlightConfig:
    """0.5 s steps of 0.5 m primitives, a fast take-off, a short hold before landing."""
    return FlightConfig(
        mission=MissionConfig(takeoff_speed_m_s=2.0, max_steps=30),
        primitives=parse_config(PrimitiveConfig, {"scale_m": 0.5, "duration_s": 0.5}),
        safety=SafetyConfig(hold_before_land_s=0.3, land_timeout_s=15.0),
        vehicle=VehicleConfig(url=f"udpin://127.0.0.1:{port}", connect_timeout_s=10.0, command_timeout_s=3.0),
    )


class LinkFlight:
    """One daemon against the emulator ``emu`` (already started, sending to ``port``)."""

    def __init__(self, policy: Policy, emu: Px4Emulator, port: int, px4_odometry: bool = False) -> None:
        self.emu = emu
        self.vehicle = SpyVehicle(f"udpin://127.0.0.1:{port}")
        self.odometry: Any = (
            Px4OdometrySource(self.vehicle)
            if px4_odometry
            else FakeOdometrySource(lambda: emu.true_pose().pos_world_m, rate_hz=100.0)
        )
        self.daemon = FlightDaemon(
            flight_config(port),
            path=PATH,
            policy=policy,
            depth=FakeDepthSource(fps=30.0),
            odometry=self.odometry,
            vehicle=self.vehicle,
        )
        self.t_start: float | None = None
        """When ``daemon.run()`` was called (monotonic s)."""
        self.t_fault: float | None = None
        """When the fault was injected (monotonic s)."""
        self.t_stop: float | None = None
        """When the daemon decided to stop (monotonic s)."""
        self.t_end: float | None = None
        """When ``daemon.run()`` returned (monotonic s)."""
        request_stop = self.daemon.request_stop

        def stamped(reason: StopReason, detail: str, t_threshold_mono_s: float | None = None) -> bool:
            first = request_stop(reason, detail, t_threshold_mono_s)
            if first:
                self.t_stop = time.monotonic()
            return first

        self.daemon.request_stop = stamped  # type: ignore[method-assign]

    async def run(
        self, fault: Callable[[LinkFlight], None] | None = None, timeout_s: float = 60.0
    ) -> FlightSummary:
        """Fly; ``fault(self)`` is called once the mission made its first step."""

        async def inject() -> None:
            while not (self.daemon.in_mission and self.daemon.steps >= 1):
                await asyncio.sleep(0.005)
            self.t_fault = time.monotonic()
            fault(self)  # type: ignore[misc]

        task = asyncio.ensure_future(inject()) if fault else None
        self.t_start = time.monotonic()
        try:
            return await asyncio.wait_for(self.daemon.run(), timeout_s)
        finally:
            self.t_end = time.monotonic()
            if task is not None:
                task.cancel()


def modes_entered(emu: Px4Emulator) -> list[str]:
    """Modes the emulated PX4 entered, in order (from its event log: "A -> B")."""
    return [msg.split(" -> ")[1] for _, kind, msg in emu.events if kind == "mode"]
