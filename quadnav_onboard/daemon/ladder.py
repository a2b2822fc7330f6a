"""The stop ladder: stop streaming; hold; land (if configured); disarm (if configured).

Pilot takeover and link loss release the vehicle instead (no command at all), so the daemon never
fights a pilot or PX4's own failsafe; a link that is silent when the ladder starts, or falls silent
during it, releases it too (nothing is sent into a dead link, and no land timeout is waited out).
Its input is the flight's :class:`~quadnav_onboard.daemon.state.StopRequest`; its output is the
commands sent and the ``landing`` figures in ``stats``.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from typing import Any

from quadnav_onboard.daemon.config import FlightConfig
from quadnav_onboard.daemon.recording import SafeRecorder
from quadnav_onboard.daemon.state import StopRequest
from quadnav_onboard.daemon.stats import RunStats
from quadnav_onboard.daemon.supervisor import Response, StopReason, response_for
from quadnav_onboard.logs import get_logger
from quadnav_onboard.vehicle import VehicleError, VehicleLink

__all__ = ["StopLadder"]

log = get_logger("quadnav.daemon")


class StopLadder:
    """Answers one stop request for a vehicle that was armed (the caller decides that)."""

    def __init__(
        self, cfg: FlightConfig, vehicle: VehicleLink, recorder: SafeRecorder, stats: RunStats
    ) -> None:
        self.cfg = cfg
        self.vehicle = vehicle
        self.recorder = recorder
        self.stats = stats
        self.stop_reason: StopReason | None = None

    async def respond(self, stop: StopRequest) -> None:
        """Hold, land, disarm or release, as ``stop``'s reason and the config ask."""
        reason = stop.reason
        self.stop_reason = reason
        if response_for(reason) is Response.RELEASE:
            self._release(reason, "not commanding: pilot/PX4 in charge")
            return
        if not self.link_alive():
            self._release(reason, "the vehicle's link is silent: no commands into a dead link")
            return
        if not self.vehicle.state.armed:
            self._release(reason, "the vehicle is disarmed: nothing to hold or land")
            return
        await self.command_hold(stop.t_threshold_mono_s)
        land = (
            self.cfg.mission.land_at_goal
            if reason is StopReason.GOAL_REACHED
            else self.cfg.safety.land_on_abort
        )
        if not land:
            return
        if not await self._hold_for(self.cfg.safety.hold_before_land_s):
            self._release(reason, "the vehicle's link fell silent during the hold: land not sent")
            return
        if not self.vehicle.state.armed:
            self._release(reason, "the vehicle disarmed during the hold: nothing to land")
            return
        if self.vehicle.state.mode not in ("HOLD", "OFFBOARD") and self.vehicle.state.armed:
            log.warning("land_skipped", mode=self.vehicle.state.mode, detail="pilot took over during hold")
            return
        await self._ladder_step("land", self.vehicle.land)
        landed = await self._wait_landed()
        at_once = self.cfg.safety.disarm_on_abort and reason is not StopReason.GOAL_REACHED
        await self._after_landing(landed, at_once)

    async def command_hold(self, t_threshold_mono_s: float | None) -> None:
        """Hold now (first rung); records the reaction time to a stale-input threshold."""
        t = time.monotonic()
        if t_threshold_mono_s is not None:
            self.stats.hold_reaction_s = t - t_threshold_mono_s
        log.warning("ladder", step="hold", reason=self.stop_reason.value if self.stop_reason else None)
        self.recorder.event(t, "ladder", "hold")
        try:
            await self.vehicle.hold()
        except VehicleError as exc:
            log.error("ladder_failed", step="hold", error=str(exc))
            self.recorder.event(time.monotonic(), "ladder_failed", f"hold: {exc}")

    async def _after_landing(self, landed: bool, at_once: bool) -> None:
        """Landed but still armed: wait (bounded) for PX4's auto-disarm (COM_DISARM_LAND), else
        disarm; or disarm at once (``safety.after_landing: disarm``, ``disarm_on_abort``). The
        outcome goes into the summary's ``landing``."""
        s = self.cfg.safety
        st = self.vehicle.state
        t0 = time.monotonic()
        if not landed:
            self.stats.landing = {"landed": False, "disarm": "still_armed" if st.armed else "auto"}
            return
        if st.armed and not at_once and s.after_landing == "wait_for_auto_disarm":
            wait_s = self._auto_disarm_wait_s()
            while st.armed and time.monotonic() - t0 < wait_s and self.link_alive():
                await asyncio.sleep(0.05)
        waited = round(time.monotonic() - t0, 2)
        if not st.armed:
            log.info("disarmed", by="PX4 (auto-disarm after landing)", waited_s=waited)
            self.stats.landing = {"landed": True, "disarm": "auto", "waited_s": waited}
            return
        if not self.link_alive():
            self.stats.landing = {"landed": True, "disarm": "still_armed", "waited_s": waited}
            log.error("landed_armed", detail="the link fell silent before the disarm")
            return
        await self._ladder_step("disarm", self.vehicle.disarm)
        deadline = time.monotonic() + self.cfg.vehicle.command_timeout_s
        while st.armed and time.monotonic() < deadline and self.link_alive():
            await asyncio.sleep(0.02)
        outcome = "commanded" if not st.armed else "still_armed"
        if st.armed:
            log.error("landed_armed", detail="disarm not confirmed by telemetry")
        self.stats.landing = {"landed": True, "disarm": outcome, "waited_s": waited}

    def _auto_disarm_wait_s(self) -> float:
        """How long to wait for PX4's auto-disarm: COM_DISARM_LAND (read in preflight) + 1 s,
        at most ``safety.auto_disarm_wait_s``; 0 when PX4's auto-disarm is off."""
        limit = self.cfg.safety.auto_disarm_wait_s
        values = self.stats.px4_parameters.get("values")
        value = values.get("COM_DISARM_LAND") if isinstance(values, dict) else None
        if value is None or not math.isfinite(value):
            return limit
        return 0.0 if value <= 0 else min(limit, float(value) + 1.0)

    async def _ladder_step(self, name: str, fn: Callable[[], Any]) -> None:
        t = time.monotonic()
        log.warning("ladder", step=name, reason=self.stop_reason.value if self.stop_reason else None)
        self.recorder.event(t, "ladder", name)
        try:
            await fn()
        except VehicleError as exc:
            log.error("ladder_failed", step=name, error=str(exc))
            self.recorder.event(time.monotonic(), "ladder_failed", f"{name}: {exc}")

    async def _wait_landed(self) -> bool:
        """Wait for touchdown (bounded by ``land_timeout_s``); True once on the ground."""
        deadline = time.monotonic() + self.cfg.safety.land_timeout_s
        while time.monotonic() < deadline:
            st = self.vehicle.state
            if not st.armed or st.landed:
                log.info("landed", armed=st.armed)
                self.recorder.event(time.monotonic(), "landed", "on the ground", armed=st.armed)
                return True
            if not self.link_alive():
                log.error("land_unconfirmed", detail="the vehicle's link fell silent while landing")
                self.recorder.event(time.monotonic(), "release", "link silent while landing")
                return False
            await asyncio.sleep(0.05)
        log.error("land_timeout", timeout_s=self.cfg.safety.land_timeout_s)
        return False

    def link_alive(self) -> bool:
        """Something was heard from the vehicle within ``safety.link_timeout_s``."""
        age = time.monotonic() - self.vehicle.state.t_last_msg_mono_s
        return age <= self.cfg.safety.link_timeout_s

    async def _hold_for(self, duration_s: float) -> bool:
        """Wait ``duration_s`` in the hold; False as soon as the link falls silent."""
        deadline = time.monotonic() + duration_s
        while (left := deadline - time.monotonic()) > 0:
            if not self.link_alive():
                return False
            await asyncio.sleep(min(0.05, left))
        return self.link_alive()

    def _release(self, reason: StopReason, why: str) -> None:
        log.warning("stop_release", reason=reason.value, detail=why)
        self.recorder.event(
            time.monotonic(), "release", f"stopped commanding the vehicle: {why}", reason=reason.value
        )
