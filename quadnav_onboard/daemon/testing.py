"""Fakes for testing the daemon without a vehicle or sensors (shipped like structlog.testing).

:class:`FakeVehicle` implements :class:`~quadnav_onboard.vehicle.VehicleLink` with a tiny
PX4-like mode machine and first-order position tracking; :class:`FakeDepthSource` and
:class:`FakeOdometrySource` implement the source protocols and can be paused or fed bad data.
These are for unit tests of the daemon's logic; end-to-end tests use the real MAVSDK against the
sim harness's PX4 emulator.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import AsyncIterator, Callable

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.checkpoint import Checkpoint, save_checkpoint
from quadnav_onboard.frames import quat_from_yaw
from quadnav_onboard.network import DQN, NetworkConfig
from quadnav_onboard.sources.base import DepthFrame, OdometrySample
from quadnav_onboard.vehicle import VehicleError, VehicleState

__all__ = ["FakeDepthSource", "FakeOdometrySource", "FakeVehicle", "constant_action_checkpoint"]


def constant_action_checkpoint(path: str, action: int = 4, config: NetworkConfig | None = None) -> Checkpoint:
    """Write (and return the path of) a checkpoint whose greedy action is always ``action``.

    Action 4 of the default set is straight ahead (1, 0, 0). All weights but the output bias are
    random, so the network still runs its full forward pass.
    """
    import torch

    from quadnav_onboard.checkpoint import load_checkpoint

    torch.manual_seed(0)
    model = DQN(config or NetworkConfig())
    with torch.no_grad():
        model.out.weight.zero_()
        model.out.bias.zero_()
        model.out.bias[action] = 1.0
    save_checkpoint(path, model, meta={"kind": "constant-action test model"})
    return load_checkpoint(path)


class FakeVehicle:
    """A PX4-like vehicle in memory: arm, offboard (needs a prior setpoint), hold, land, disarm."""

    def __init__(self, start_pos_world_m: NDArray[np.float64] | None = None, rate_hz: float = 50.0) -> None:
        self.state = VehicleState()
        self.pos_world_m = np.zeros(3) if start_pos_world_m is None else np.asarray(start_pos_world_m, float)
        self.target_world_m = self.pos_world_m.copy()
        self.rate_hz = rate_hz
        self.link_up = True
        self.deny_offboard = False
        self.commands: list[tuple[float, str]] = []
        self.setpoints: list[tuple[float, NDArray[np.float64]]] = []
        self._got_setpoint = False

    def _log(self, name: str) -> None:
        self.commands.append((time.monotonic(), name))

    async def connect(self) -> None:
        self.state.connected = True
        self.state.local_position_ok = True
        self.state.armable = True
        self.state.landed = True
        self.state.mode = "HOLD"
        self.state.t_last_msg_mono_s = time.monotonic()

    async def run_telemetry(self) -> None:
        dt = 1.0 / self.rate_hz
        while True:
            await asyncio.sleep(dt)
            self._physics(dt)
            if self.link_up:
                self.state.t_last_msg_mono_s = time.monotonic()
                self.state.pos_world_m = self.pos_world_m.copy()

    def _physics(self, dt: float) -> None:
        st = self.state
        if not st.armed:
            return
        if st.mode == "LAND":
            self.target_world_m = np.array([*self.pos_world_m[:2], 0.0])
        step = self.target_world_m - self.pos_world_m
        self.pos_world_m = self.pos_world_m + step * min(1.0, 8.0 * dt)
        st.landed = self.pos_world_m[2] < 0.05
        if st.mode == "LAND" and st.landed:
            st.armed = False

    def set_mode(self, mode: str) -> None:
        """What a pilot's switch (or a PX4 failsafe) does."""
        self.state.mode = mode
        if mode == "HOLD":
            self.target_world_m = self.pos_world_m.copy()

    async def arm(self) -> None:
        self._log("arm")
        self.state.armed = True

    async def disarm(self) -> None:
        self._log("disarm")
        self.state.armed = False

    async def start_offboard(self) -> None:
        self._log("offboard_start")
        if not self._got_setpoint or self.deny_offboard:
            raise VehicleError("offboard_start: refused: no setpoint" if not self._got_setpoint else "denied")
        self.state.mode = "OFFBOARD"

    async def stop_offboard(self) -> None:
        self._log("offboard_stop")
        self.set_mode("HOLD")

    async def hold(self) -> None:
        self._log("hold")
        self.set_mode("HOLD")

    async def land(self) -> None:
        self._log("land")
        self.state.mode = "LAND"

    async def set_setpoint(
        self, pos_world_m: NDArray[np.float64], vel_world_m_s: NDArray[np.float64], yaw_rad: float
    ) -> None:
        if not self.link_up:
            return
        self._got_setpoint = True
        self.setpoints.append((time.monotonic(), np.asarray(pos_world_m, float).copy()))
        if self.state.mode == "OFFBOARD":
            self.target_world_m = np.asarray(pos_world_m, float).copy()

    async def send_vision_position(
        self, pos_world_m: NDArray, quat_world_body: NDArray, t_mono_s: float
    ) -> None:
        self._log("vision")

    async def close(self) -> None:
        self.state.connected = False


class FakeDepthSource:
    """Frames of constant depth at ``fps``; ``paused`` stops the feed, ``make`` overrides a frame."""

    def __init__(self, fps: float = 30.0, shape: tuple[int, int] = (240, 424), depth_mm: int = 8000) -> None:
        self.fps = fps
        self.shape = shape
        self.depth_mm = depth_mm
        self.paused = False
        self.make: Callable[[int], np.ndarray] | None = None

    async def __aenter__(self) -> FakeDepthSource:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def frames(self) -> AsyncIterator[DepthFrame]:
        seq = 0
        while True:
            await asyncio.sleep(1.0 / self.fps)
            if self.paused:
                continue
            arr = self.make(seq) if self.make else np.full(self.shape, self.depth_mm, np.uint16)
            seq += 1
            yield DepthFrame(arr, time.monotonic(), seq)


class FakeOdometrySource:
    """Pose of ``pose_fn()`` at ``rate_hz``; ``paused`` stops it; ``nan`` makes positions NaN."""

    def __init__(self, pose_fn: Callable[[], NDArray[np.float64]], rate_hz: float = 120.0) -> None:
        self.pose_fn = pose_fn
        self.rate_hz = rate_hz
        self.paused = False
        self.nan = False

    async def __aenter__(self) -> FakeOdometrySource:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def samples(self) -> AsyncIterator[OdometrySample]:
        while True:
            await asyncio.sleep(1.0 / self.rate_hz)
            if self.paused:
                continue
            pos = np.full(3, math.nan) if self.nan else np.asarray(self.pose_fn(), float).copy()
            yield OdometrySample(pos, quat_from_yaw(0.0), time.monotonic())
