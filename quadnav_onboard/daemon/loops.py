"""The daemon's concurrent tasks: sensor ingest, depth preparation, telemetry watch, setpoint
streamer, supervisor.

Sensors publish into :class:`~quadnav_onboard.daemon.stats.Latest` holders (latest value wins,
nothing queues up). A task whose source fails logs it and ends; the data it fed goes stale and the
supervisor stops the flight, so one broken sensor never tears down the task group (and with it the
response ladder).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections import deque
from collections.abc import AsyncIterator
from typing import Any

import numpy as np

from quadnav_onboard.daemon.config import FlightConfig
from quadnav_onboard.daemon.decide import DecisionPath, PreparedFrame
from quadnav_onboard.daemon.ground import GroundFrame
from quadnav_onboard.daemon.stats import LatencyStats, Latest
from quadnav_onboard.daemon.summary import NullNotifier
from quadnav_onboard.daemon.supervisor import (
    FlightSnapshot,
    FrozenPositionWatch,
    StopReason,
    check_in_flight,
    link_quiet,
)
from quadnav_onboard.logs import get_logger
from quadnav_onboard.preprocess import DepthFrameError, validate_depth_mm
from quadnav_onboard.sources.base import DepthFrame, OdometrySample
from quadnav_onboard.vehicle import VehicleError, VehicleLink

__all__ = ["Loops", "RunStats"]

log = get_logger("quadnav.daemon")


class RunStats:
    """Bounded timing figures of one flight (seconds in, ms out)."""

    def __init__(self) -> None:
        self.decision_latency = LatencyStats()
        """Decision start (newest frame taken) -> first setpoint of the new primitive sent."""
        self.inference = LatencyStats()
        """The step's DQN work from the step boundary: the head, plus any wait for, or run of, the
        newest frame's preparation."""
        self.frame_age = LatencyStats()
        """Age of the depth frame a decision used, at the step boundary (sensor latency, not
        decision latency)."""
        self.decision_paths: dict[DecisionPath, int] = {"prepared": 0, "waited": 0, "full": 0}
        """How each decision got its prepared frame (see ``decide.DecisionPath``)."""
        self.setpoint_interval = LatencyStats()
        """Time between consecutive setpoints sent."""
        self.hold_reaction_s: float | None = None
        """Stale-input threshold crossing -> hold command issued (None if no such stop)."""
        self.depth_frames = 0
        self.depth_frames_prepared = 0
        """Frames preprocessed and run through the depth lane (on arrival or at a step)."""
        self.depth_frames_checked = 0
        """Frames only checked, too early before a step boundary to be used (``prepare_within_s``)."""
        self.odometry_samples = 0
        self.setpoints = 0
        self.vision_forwards = 0
        """Vision estimates forwarded to PX4."""
        self.vision_forward_failures = 0
        """Vision forwards that failed (the link refused or could not send them)."""
        self.warmup_s: float | None = None
        """Preflight's test decisions: compiling (or loading from cache) every kernel and the
        network's first call, before anything arms."""
        self.ready_s: float | None = None
        """Daemon start -> READY (preflight passed)."""
        self.kernels_compiled_in_flight: dict[str, list[str]] = {}
        """Kernels that compiled a new signature after arming, and those signatures (none expected)."""
        self.stops_deferred_for_link = 0
        """Stops found while the link was quiet, held until the link's verdict."""
        self.ground: dict[str, object] = {}
        """The ground frame flown (``GroundFrame.describe``)."""
        self.odometry: dict[str, float | None] = {}
        """The odometry stream measured in preflight and the stale limit sized from it."""
        self.px4_parameters: dict[str, object] = {}
        """PX4's parameters read in preflight: {"values": {name: value}, "required": [...],
        "advice": [...]} (the findings, as text)."""
        self.offboard_start_attempts = 1
        """Tries the switch to OFFBOARD took (more than 1: PX4 refused the first)."""
        self.landing: dict[str, object] = {}
        """How the flight ended on the ground after the ladder's land: {"landed": bool, "disarm":
        "auto" | "commanded" | "still_armed", "waited_s": s}; empty when it did not land."""

    def count_decision(self, path: DecisionPath, frame_age_s: float) -> None:
        self.decision_paths[path] += 1
        self.frame_age.add(frame_age_s)


class Loops:
    """State shared by the tasks, and the tasks themselves (mixed into FlightDaemon)."""

    def __init__(self, cfg: FlightConfig, *, vehicle: VehicleLink, recorder: Any, notifier: Any) -> None:
        self.cfg = cfg
        self.vehicle = vehicle
        self.recorder = recorder
        self.notifier = notifier if notifier is not None else NullNotifier()
        self.latest_depth: Latest[DepthFrame] = Latest()
        self.latest_odom: Latest[OdometrySample] = Latest()
        """The newest odometry sample, in the ground frame (:attr:`ground_frame`)."""
        self.latest_odom_raw: OdometrySample | None = None
        """The newest odometry sample in the source's own frame."""
        self.odom_arrivals: deque[float] = deque(maxlen=512)
        """Arrival times (monotonic s) of the newest odometry samples (the preflight rate check)."""
        self.ground_frame = GroundFrame()
        """The daemon's world frame (z = 0: the ground) against the odometry's and PX4's."""
        self.safety = cfg.safety
        """The in-flight limits: ``cfg.safety`` with the stale-odometry limit sized in preflight."""
        self.stop_event = asyncio.Event()
        self.new_trajectory = asyncio.Event()
        self.stop_reason: StopReason | None = None
        self.stop_detail = ""
        self.t_stop_threshold_mono_s: float | None = None
        self.phase = "startup"
        self.trajectory: Any = None
        self.streaming = False
        self.supervising = False
        self.in_mission = False
        self.t_decision_start: float | None = None
        self.last_inference_s = 0.0
        self.decision_t: float | None = None
        self.decision_latency_last_s = math.nan
        self.pending_step: dict[str, Any] | None = None
        self.depth_error: str | None = None
        self._preparing: asyncio.Future[PreparedFrame] | None = None
        self.next_step_mono: float | None = None
        """When the mission's next step boundary falls (monotonic s); None outside the mission."""
        self.stats = RunStats()
        self.last_setpoint_world_m: np.ndarray | None = None
        """The newest setpoint sent (world, m), shape (3,)."""
        self.t_forward_failing_since: float | None = None
        """When the current run of failed vision forwards began (monotonic s); None when the
        last forward went out."""
        self._forward_streak = 0
        self.frozen_watches = (
            FrozenPositionWatch("odometry"),
            FrozenPositionWatch("PX4's position estimate"),
        )
        self.deferred_stop: tuple[StopReason, str] | None = None
        """A stop found while the link was quiet, waiting for the link's verdict."""

    # --- stop requests -------------------------------------------------------------------------

    def request_stop(self, reason: StopReason, detail: str, t_threshold_mono_s: float | None = None) -> bool:
        """Record the first stop reason and wake the lifecycle; later requests are logged only."""
        if self.stop_reason is not None:
            log.info("stop_ignored", reason=reason.value, detail=detail, stopping_for=self.stop_reason.value)
            return False
        self.stop_reason, self.stop_detail = reason, detail
        self.t_stop_threshold_mono_s = t_threshold_mono_s
        self.streaming = False  # stop commanding at once; the ladder takes over
        log.warning(
            "stop", reason=reason.value, detail=detail, phase=self.phase, exit_code=int(reason.exit_code)
        )
        self.recorder.event(time.monotonic(), "stop", detail, reason=reason.value, phase=self.phase)
        self.stop_event.set()
        return True

    async def command_hold(self) -> None:
        """Hold now (first rung of the ladder); records the reaction time to a stale-input threshold."""
        t = time.monotonic()
        if self.t_stop_threshold_mono_s is not None:
            self.stats.hold_reaction_s = t - self.t_stop_threshold_mono_s
        log.warning("ladder", step="hold", reason=self.stop_reason.value if self.stop_reason else None)
        self.recorder.event(t, "ladder", "hold")
        try:
            await self.vehicle.hold()
        except VehicleError as exc:
            log.error("ladder_failed", step="hold", error=str(exc))
            self.recorder.event(time.monotonic(), "ladder_failed", f"hold: {exc}")

    # --- sensors -------------------------------------------------------------------------------

    async def ingest_depth(self) -> None:
        """Newest depth frame wins; a cheap dtype/shape check flags unusable frames at once."""
        try:
            async for frame in self.depth_source.frames():  # type: ignore[attr-defined]
                arr = frame.depth_mm
                if arr.dtype != np.uint16 or arr.ndim != 2 or min(arr.shape) < 32:
                    self.depth_error = (
                        f"depth frame of dtype {arr.dtype} and shape {arr.shape} (need uint16 HxW)"
                    )
                else:
                    self.depth_error = None
                self.latest_depth.set(frame)
                self.stats.depth_frames += 1
                self.recorder.depth(frame.t_capture_mono_s, arr)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.error("depth_source_failed", error=f"{type(exc).__name__}: {exc}")
            self.recorder.event(time.monotonic(), "source_failed", f"depth: {exc}")

    async def prepare_depth(self) -> None:
        """Once flying, prepare each new depth frame in the DQN executor as it arrives.

        Latest wins: frames that arrive while one is being prepared are skipped, except the newest,
        which is prepared next. In the mission, with ``depth.prepare_within_s`` set, a frame that
        arrives earlier than that before the next step boundary is only checked, not prepared: the
        step uses the newest frame, and a later one will replace it. A frame that is rejected
        (checked or prepared) is flagged as ``depth_error`` (while it is still the newest), so the
        supervisor stops the flight for bad depth.
        """
        seq = 0
        window = self.cfg.depth.preparation_window_s()
        while True:
            frame = await self.latest_depth.wait_newer(seq)
            seq = self.latest_depth.seq
            if not self.flying or self.stop_reason is not None:  # type: ignore[attr-defined]
                continue
            due = self.next_step_mono
            try:
                if window is not None and due is not None and time.monotonic() < due - window:
                    await self._check(frame)
                else:
                    await self._prepare(frame)
            except DepthFrameError as exc:
                if self.latest_depth.value is frame:
                    self.depth_error = str(exc)
            except Exception as exc:  # a bug: the step prepares its frame itself
                log.error("depth_prepare_failed", error=f"{type(exc).__name__}: {exc}")

    def _check(self, frame: DepthFrame) -> asyncio.Future[None]:
        """Only the checks of ``frame`` (raises ``DepthFrameError`` as preparing it would), in the
        DQN executor, off the loop."""
        self.stats.depth_frames_checked += 1
        loop = asyncio.get_running_loop()
        return loop.run_in_executor(
            self._executor,  # type: ignore[attr-defined]
            validate_depth_mm,
            frame.depth_mm,
            self.decider.preprocess,  # type: ignore[attr-defined]
        )

    def _prepare(self, frame: DepthFrame) -> asyncio.Future[PreparedFrame]:
        """Preparation of ``frame`` in the DQN executor, against a snapshot of the history now."""
        decider = self.decider  # type: ignore[attr-defined]
        self.stats.depth_frames_prepared += 1
        loop = asyncio.get_running_loop()
        fut = loop.run_in_executor(
            self._executor,  # type: ignore[attr-defined]
            decider.prepare,
            frame,
            decider.snapshot(),
            self.motion_now(),  # type: ignore[attr-defined]
            decider.memory,
        )
        self._preparing = fut
        return fut

    async def prepared_for(self, frame: DepthFrame) -> tuple[PreparedFrame, DecisionPath]:
        """At the step boundary: ``frame`` prepared against the current history, and how it came.

        Ready: no wait. Being prepared: wait for it (the executor has one thread; anything else
        would queue behind it). Otherwise prepare it now. Raises ``DepthFrameError``.
        """
        decider = self.decider  # type: ignore[attr-defined]
        prepared = decider.current(frame)
        if prepared is not None:
            return prepared, "prepared"
        if self._preparing is not None and not self._preparing.done():
            await asyncio.wait({self._preparing})  # never cancels it; its task reads the outcome
            prepared = decider.current(frame)
            if prepared is not None:
                return prepared, "waited"
        return await self._prepare(frame), "full"

    async def ingest_odometry(self) -> None:
        """Newest pose wins; optionally forwarded to PX4 as a vision estimate (rate limited)."""
        fwd = self.cfg.odometry.forward_to_px4 and self.cfg.odometry.kind == "mocap"
        min_dt = 1.0 / self.cfg.odometry.forward_rate_hz
        t_fwd = -math.inf
        try:
            async for raw in self.odometry_source.samples():  # type: ignore[attr-defined]
                self.latest_odom_raw = raw
                self.odom_arrivals.append(raw.t_arrival_mono_s)
                s = self.ground_frame.to_world(raw)
                self.latest_odom.set(s)
                self.stats.odometry_samples += 1
                self.recorder.odometry(s.t_arrival_mono_s, s.pos_world_m, s.quat_world_body, s.vel_world_m_s)
                if fwd and s.t_arrival_mono_s - t_fwd >= min_dt and self.vehicle.state.connected:
                    t_fwd = s.t_arrival_mono_s
                    await self._forward_vision(raw)  # PX4 fuses the mocap frame itself
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.error("odometry_source_failed", error=f"{type(exc).__name__}: {exc}")
            self.recorder.event(time.monotonic(), "source_failed", f"odometry: {exc}")

    async def _forward_vision(self, s: OdometrySample) -> None:
        """Forward one pose to PX4's estimator. A failure is counted and logged (the first of a run
        and the recovery); it never ends the ingest. The supervisor stops the flight only when
        every forward has failed for longer than ``link_timeout_s``."""
        try:
            await self.vehicle.send_vision_position(s.pos_world_m, s.quat_world_body, s.t_arrival_mono_s)
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # VehicleError; anything else a link raises is counted the same
            self.stats.vision_forward_failures += 1
            self._forward_streak += 1
            if self.t_forward_failing_since is None:
                self.t_forward_failing_since = s.t_arrival_mono_s
                kind = exc.kind.value if isinstance(exc, VehicleError) else type(exc).__name__
                log.error("vision_forward_failed", error=str(exc), kind=kind)
                self.recorder.event(time.monotonic(), "vision_forward_failed", str(exc), kind=kind)
            return
        self.stats.vision_forwards += 1
        if self.t_forward_failing_since is not None:
            log.warning(
                "vision_forward_recovered",
                failed=self._forward_streak,
                after_s=round(s.t_arrival_mono_s - self.t_forward_failing_since, 3),
            )
            self.t_forward_failing_since = None
            self._forward_streak = 0

    async def watch_vehicle(self) -> None:
        try:
            await self.vehicle.run_telemetry()
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.error("telemetry_failed", error=f"{type(exc).__name__}: {exc}")

    async def mode_stream(self) -> AsyncIterator[str]:
        """Flight-mode names as they change (for the offboard-switch trigger)."""
        last = None
        while True:
            mode = self.vehicle.state.mode
            if mode != last:
                last = mode
                yield mode
            await asyncio.sleep(0.05)

    # --- setpoints -----------------------------------------------------------------------------

    async def stream_setpoints(self) -> None:
        """Sample the active trajectory at the configured rate (absolute schedule) and send it.

        A new primitive wakes the streamer at once, so its first setpoint leaves without waiting
        for the next tick. Nothing is sent while ``streaming`` is False.
        """
        period = 1.0 / self.cfg.vehicle.setpoint_rate_hz
        next_t = time.monotonic()
        last_sent: float | None = None
        last_traj: Any = None
        while True:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(max(0.0, next_t - time.monotonic())):
                    await self.new_trajectory.wait()
            self.new_trajectory.clear()
            now = time.monotonic()
            if now >= next_t:
                next_t += period
                if next_t < now:
                    next_t = now + period
            traj = self.trajectory
            if traj is None or not self.streaming:
                last_sent = None
                continue
            pos, vel, yaw = traj.sample(now)
            try:
                await self.vehicle.set_setpoint(self.ground_frame.to_px4(pos), vel, yaw)
            except VehicleError as exc:
                log.error("setpoint_failed", error=str(exc))
                continue
            t_sent = time.monotonic()
            self.last_setpoint_world_m = pos
            self.stats.setpoints += 1
            if last_sent is not None:
                self.stats.setpoint_interval.add(t_sent - last_sent)
            last_sent = t_sent
            if traj is not last_traj and self.decision_t is not None and self.in_mission:
                self.decision_latency_last_s = t_sent - self.decision_t
                self.stats.decision_latency.add(self.decision_latency_last_s)
                self.stats.inference.add(self.last_inference_s)
            last_traj = traj
            self.recorder.setpoint(t_sent, pos, vel, yaw)

    # --- supervisor ----------------------------------------------------------------------------

    def snapshot(self, now: float) -> FlightSnapshot:
        depth, odom = self.latest_depth.value, self.latest_odom.value
        pos = np.asarray(odom.pos_world_m, dtype=np.float64) if odom is not None else np.full(3, np.nan)
        dev = float(self.path.deviation_m(pos)) if np.all(np.isfinite(pos)) else math.inf  # type: ignore[attr-defined]
        running = self.t_decision_start
        probe = self.crash_probe  # type: ignore[attr-defined]
        return FlightSnapshot(
            t_mono_s=now,
            vehicle=self.vehicle.state,
            t_depth_mono_s=depth.t_capture_mono_s if depth is not None else -math.inf,
            t_odom_mono_s=odom.t_arrival_mono_s if odom is not None else -math.inf,
            pos_world_m=pos,
            deviation_m=dev,
            in_mission=self.in_mission,
            inference_s=(now - running) if running is not None else self.last_inference_s,
            crashed=bool(probe()) if probe is not None else False,
            depth_error=self.depth_error,
            frozen_position=self._frozen_verdict(now, odom),
            vision_forward_failing_s=(
                0.0 if self.t_forward_failing_since is None else now - self.t_forward_failing_since
            ),
        )

    def _frozen_verdict(self, now: float, odom: OdometrySample | None) -> str | None:
        """Feed the frozen-position watches (the daemon's odometry, PX4's estimate) with their
        fresh reports while the mission streams setpoints; the first verdict, if any."""
        cmd = self.last_setpoint_world_m
        if not (self.in_mission and self.streaming) or cmd is None or odom is None:
            for w in self.frozen_watches:
                w.reset()
            return None
        odom_w, px4_w = self.frozen_watches
        odom_w.add(odom.t_arrival_mono_s, cmd, odom.pos_world_m)
        st = self.vehicle.state
        px4_w.add(st.t_position_mono_s, cmd, st.pos_world_m)
        return odom_w.verdict(now) or px4_w.verdict(now)

    async def supervise(self) -> None:
        """In-flight checks at ``safety.check_rate_hz``; also feeds the systemd watchdog."""
        period = 1.0 / self.cfg.safety.check_rate_hz
        interval = getattr(self.notifier, "watchdog_interval_s", lambda: None)()
        wd_period_s = min(1.0, interval) if interval else 1.0
        t_vehicle_rec = t_watchdog = -math.inf
        while True:
            await asyncio.sleep(period)
            now = time.monotonic()
            if now - t_watchdog >= wd_period_s:  # from this loop: a hung loop stops the pings
                t_watchdog = now
                self.notifier.watchdog()
            st = self.vehicle.state
            if now - t_vehicle_rec >= 0.2:
                t_vehicle_rec = now
                self.recorder.vehicle(now, st.armed, st.mode, {"local_position_ok": st.local_position_ok})
            if not self.supervising or self.stop_reason is not None:
                continue
            snap = self.snapshot(now)
            found = check_in_flight(snap, self.safety)
            if self._defer_for_link(found, snap):
                continue
            if found is None:
                continue
            reason, detail = found
            threshold = None
            if reason is StopReason.STALE_DEPTH:
                threshold = snap.t_depth_mono_s + self.cfg.safety.stale_depth_s
            elif reason is StopReason.STALE_ODOMETRY:
                threshold = snap.t_odom_mono_s + self.safety.stale_odometry_s
            self.request_stop(reason, detail, threshold)

    def _defer_for_link(self, found: tuple[StopReason, str] | None, snap: FlightSnapshot) -> bool:
        """True while a stop found on a quiet link waits for the link's verdict.

        Odometry and telemetry may ride the vehicle's link: when it dies, stale odometry is seen
        before the link timeout, and commanding hold and land into a dead link only fails. So a
        stop found while nothing is heard from the vehicle (``link_quiet``) pauses the setpoints
        and waits: the link silent past ``link_timeout_s`` is ``link_lost`` (release, no
        commands); the link back means the stop found then (or, if none, streaming resumes).
        A crash is never held back."""
        if found is not None and found[0] not in (StopReason.CRASH, StopReason.LINK_LOST) and link_quiet(
            snap, self.safety
        ):
            if self.deferred_stop is None:
                self.deferred_stop = found
                self.stats.stops_deferred_for_link += 1
                self.streaming = False
                self.recorder.event(snap.t_mono_s, "stop_deferred", found[1], reason=found[0].value)
                log.warning(
                    "stop_deferred",
                    reason=found[0].value,
                    detail=found[1],
                    link_age_s=round(snap.t_mono_s - snap.vehicle.t_last_msg_mono_s, 3),
                    why="the vehicle's link is quiet: waiting for link_lost or the link back",
                )
            return True
        if self.deferred_stop is not None:
            self.deferred_stop = None
            if found is None and self.trajectory is not None:
                log.warning("stop_deferral_cleared", detail="link back, nothing to stop for: streaming again")
                self.streaming = True
        return False
