"""The end of a flight: per-step reward bookkeeping, the response ladder, and the summary.

Mixed into :class:`quadnav_onboard.daemon.app.FlightDaemon`. The ladder: stop streaming; hold;
land (if configured); disarm (if configured). Pilot takeover and link loss release the vehicle
instead (no command at all), so the daemon never fights a pilot or PX4's own failsafe; a link
that is silent when the ladder starts, or falls silent during it, releases it too (nothing is sent
into a dead link, and no land timeout is waited out).
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from quadnav_onboard.daemon.loops import Loops
from quadnav_onboard.daemon.mission import step_inputs
from quadnav_onboard.daemon.summary import FlightSummary
from quadnav_onboard.daemon.supervisor import Response, StopReason, response_for
from quadnav_onboard.logs import get_logger
from quadnav_onboard.record.flight import record_px4_time
from quadnav_onboard.reward import reward
from quadnav_onboard.vehicle import VehicleError

__all__ = ["StopLadder"]

log = get_logger("quadnav.daemon")


class StopLadder(Loops):
    """Reward per step, the response ladder and the flight summary (needs path, prims, policy)."""

    path: Any
    prims: Any
    policy: Any
    flying: bool
    total_reward: float
    steps: int
    t_mission_start_mono_s: float
    t_mission_end_mono_s: float

    def _finish_step(
        self, p: dict[str, Any], pos: np.ndarray, d_now_m: float, collided: bool = False
    ) -> None:
        """Reward of one executed step, exactly as in training, and its record."""
        dev = float(self.path.deviation_m(pos))
        deviated = dev > self.cfg.reward.max_deviation_m
        r = float(reward(p["inputs"].distance_m, d_now_m, deviated, collided, self.cfg.reward))
        self.total_reward += r
        self.steps = p["step"] + 1
        self.pending_step = None
        self.recorder.step(
            p["t"],
            step=p["step"],
            action=p["action"],
            q_values=p["q"],
            rel_pos_body_m=p["inputs"].rel_pos_body_m,
            moving_setpoint_world_m=p["inputs"].setpoint_world_m,
            pos_world_m=p["pos"],
            reward=r,
            reward_terms={
                "d_prev_m": p["inputs"].distance_m,
                "d_now_m": d_now_m,
                "deviated": deviated,
                "collided": collided,
            },
            progress_m=float(self.path.progress_m(pos)),
            deviation_m=dev,
            latency_ms=self.decision_latency_last_s * 1e3,
            shield_allowed=p.get("allowed"),
            shield_clearance_m=p.get("clearance_m"),
            primitive=p.get("prim"),
        )

    # --- stop ----------------------------------------------------------------------------------

    async def _respond(self) -> None:
        """The response ladder: stop streaming; hold; land (if configured); disarm (if configured)."""
        if self.stop_reason is None:
            self.request_stop(StopReason.INTERNAL_ERROR, "lifecycle ended without a stop reason")
        reason = self.stop_reason
        assert reason is not None
        self.phase = "stop"
        self.notifier.status(f"stopping: {reason.value}")
        self.t_mission_end_mono_s = time.monotonic()
        self.streaming = False
        self.supervising = False
        self.trajectory = None
        self._close_partial_step(reason)
        if not self.flying:
            return
        if response_for(reason) is Response.RELEASE:
            self._release(reason, "not commanding: pilot/PX4 in charge")
            return
        if not self._link_alive():
            self._release(reason, "the vehicle's link is silent: no commands into a dead link")
            return
        if not self.vehicle.state.armed:
            self._release(reason, "the vehicle is disarmed: nothing to hold or land")
            return
        await self.command_hold()
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
            while st.armed and time.monotonic() - t0 < wait_s and self._link_alive():
                await asyncio.sleep(0.05)
        waited = round(time.monotonic() - t0, 2)
        if not st.armed:
            log.info("disarmed", by="PX4 (auto-disarm after landing)", waited_s=waited)
            self.stats.landing = {"landed": True, "disarm": "auto", "waited_s": waited}
            return
        if not self._link_alive():
            self.stats.landing = {"landed": True, "disarm": "still_armed", "waited_s": waited}
            log.error("landed_armed", detail="the link fell silent before the disarm")
            return
        await self._ladder_step("disarm", self.vehicle.disarm)
        deadline = time.monotonic() + self.cfg.vehicle.command_timeout_s
        while st.armed and time.monotonic() < deadline and self._link_alive():
            await asyncio.sleep(0.02)
        outcome = "commanded" if not st.armed else "still_armed"
        if st.armed:
            log.error("landed_armed", detail="disarm not confirmed by telemetry")
        self.stats.landing = {"landed": True, "disarm": outcome, "waited_s": waited}

    def _auto_disarm_wait_s(self) -> float:
        """How long to wait for PX4's auto-disarm: COM_DISARM_LAND (read in preflight) + 1 s,
        at most ``safety.auto_disarm_wait_s``; 0 when PX4's auto-disarm is off."""
        limit = self.cfg.safety.auto_disarm_wait_s
        value = self.stats.px4_parameters.get("values", {}).get("COM_DISARM_LAND")  # type: ignore[union-attr]
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
            if not self._link_alive():
                log.error("land_unconfirmed", detail="the vehicle's link fell silent while landing")
                self.recorder.event(time.monotonic(), "release", "link silent while landing")
                return False
            await asyncio.sleep(0.05)
        log.error("land_timeout", timeout_s=self.cfg.safety.land_timeout_s)
        return False

    def _link_alive(self) -> bool:
        """Something was heard from the vehicle within ``safety.link_timeout_s``."""
        age = time.monotonic() - self.vehicle.state.t_last_msg_mono_s
        return age <= self.cfg.safety.link_timeout_s

    async def _hold_for(self, duration_s: float) -> bool:
        """Wait ``duration_s`` in the hold; False as soon as the link falls silent."""
        deadline = time.monotonic() + duration_s
        while (left := deadline - time.monotonic()) > 0:
            if not self._link_alive():
                return False
            await asyncio.sleep(min(0.05, left))
        return self._link_alive()

    def _release(self, reason: StopReason, why: str) -> None:
        log.warning("stop_release", reason=reason.value, detail=why)
        self.recorder.event(
            time.monotonic(), "release", f"stopped commanding the vehicle: {why}", reason=reason.value
        )

    def _close_partial_step(self, reason: StopReason) -> None:
        p = self.pending_step
        odom = self.latest_odom.value
        if p is None or odom is None:
            return
        pos = np.asarray(odom.pos_world_m, dtype=np.float64)
        d_now = step_inputs(self.path, p["step"] + 1, self.prims.duration_s, pos).distance_m
        self._finish_step(p, pos, d_now, collided=reason is StopReason.CRASH)

    def _finish(self) -> FlightSummary:
        reason = self.stop_reason or StopReason.INTERNAL_ERROR
        odom = self.latest_odom.value
        pos = np.asarray(odom.pos_world_m) if odom is not None else np.full(3, np.nan)
        started = math.isfinite(self.t_mission_start_mono_s)
        summary = FlightSummary.build(
            reason=reason,
            detail=self.stop_detail,
            steps=self.steps,
            navigation_distance_m=float(self.path.progress_m(pos))
            if started and np.all(np.isfinite(pos))
            else 0.0,
            flight_time_s=(self.t_mission_end_mono_s - self.t_mission_start_mono_s) if started else 0.0,
            crashed=reason is StopReason.CRASH,
            total_reward=self.total_reward,
            stats=self.stats,
            model_sha256=self.policy.checkpoint.sha256,
        )
        record_px4_time(self.recorder, self.vehicle.state)
        self.recorder.close(reason.value, summary.to_dict())
        return summary
