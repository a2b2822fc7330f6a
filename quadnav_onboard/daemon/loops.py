"""The daemon's concurrent tasks, each an object with its inputs given when it is built and its
outputs as attributes: depth ingest, depth preparation, odometry ingest, setpoint streamer,
supervisor (and the vehicle's telemetry, a plain coroutine).

Sensors publish into :class:`~quadnav_onboard.daemon.stats.Latest` holders (latest value wins,
nothing queues up). A task whose source fails logs it and ends; the data it fed goes stale and the
supervisor stops the flight, so one broken sensor never tears down the task group (and with it the
stop ladder). Every task reads the flight's phase from the one
:class:`~quadnav_onboard.daemon.state.FlightState`, and asks for a stop only through the
``request_stop`` it was given.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections import deque
from collections.abc import AsyncIterator, Callable
from concurrent.futures import Executor
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from quadnav_onboard.daemon.config import DepthSourceConfig, OdometrySourceConfig, SafetyConfig
from quadnav_onboard.daemon.decide import Decider, DecisionPath, Motion, PreparedFrame
from quadnav_onboard.daemon.ground import GroundFrame
from quadnav_onboard.daemon.notify import Notifier
from quadnav_onboard.daemon.recording import SafeRecorder
from quadnav_onboard.daemon.state import FlightState
from quadnav_onboard.daemon.stats import Latest, RunStats
from quadnav_onboard.daemon.supervisor import (
    FlightSnapshot,
    FrozenPositionWatch,
    StopReason,
    check_in_flight,
    link_quiet,
)
from quadnav_onboard.logs import get_logger
from quadnav_onboard.path import RoughPath
from quadnav_onboard.preprocess import DepthFrameError, validate_depth_mm
from quadnav_onboard.sources.base import DepthFrame, DepthSource, OdometrySample, OdometrySource
from quadnav_onboard.vehicle import VehicleError, VehicleLink

__all__ = [
    "DecisionClock",
    "DepthIngest",
    "DepthPreparer",
    "OdometryIngest",
    "SetpointStreamer",
    "StopRequester",
    "Supervisor",
    "Trajectory",
    "mode_stream",
    "watch_vehicle",
]

log = get_logger("quadnav.daemon")


class StopRequester(Protocol):
    """The one way a task asks for a stop (``FlightState.request_stop``, as the daemon exposes it)."""

    def __call__(
        self, reason: StopReason, detail: str, t_threshold_mono_s: float | None = None
    ) -> bool: ...


class Trajectory(Protocol):
    """What the streamer samples: a primitive, a ramp or the current pose (:mod:`.mission`)."""

    def sample(self, t_mono_s: float) -> tuple[np.ndarray, np.ndarray, float]: ...


@dataclass
class DecisionClock:
    """The mission's decision timing, read by the supervisor (a decision that hangs) and the
    streamer (decision latency). Written by the mission task only."""

    t_start_mono_s: float | None = None
    """When the decision in progress started (monotonic s); None when none runs."""
    last_s: float = 0.0
    """How long the last decision's DQN work took (s), from the step boundary."""


# --- sensors -------------------------------------------------------------------------------------


class DepthIngest:
    """Newest depth frame wins (:attr:`latest`); a cheap dtype/shape check flags an unusable frame
    at once (:attr:`error`)."""

    def __init__(self, source: DepthSource, recorder: SafeRecorder, stats: RunStats) -> None:
        self.source = source
        self.recorder = recorder
        self.stats = stats
        self.latest: Latest[DepthFrame] = Latest()
        self.error: str | None = None
        """Why the newest frame is unusable (a message), else None: the supervisor stops on it."""

    async def run(self) -> None:
        try:
            async for frame in self.source.frames():
                arr = frame.depth_mm
                if arr.dtype != np.uint16 or arr.ndim != 2 or min(arr.shape) < 32:
                    self.error = f"depth frame of dtype {arr.dtype} and shape {arr.shape} (need uint16 HxW)"
                else:
                    self.error = None
                self.latest.set(frame)
                self.stats.depth_frames += 1
                self.recorder.depth(frame.t_capture_mono_s, arr)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.error("depth_source_failed", error=f"{type(exc).__name__}: {exc}")
            self.recorder.event(time.monotonic(), "source_failed", f"depth: {exc}")


class OdometryIngest:
    """Newest pose wins, in the ground frame (:attr:`latest`); optionally forwarded to PX4 as a
    vision estimate (rate limited)."""

    def __init__(
        self,
        source: OdometrySource,
        cfg: OdometrySourceConfig,
        vehicle: VehicleLink,
        recorder: SafeRecorder,
        stats: RunStats,
    ) -> None:
        self.source = source
        self.cfg = cfg
        self.vehicle = vehicle
        self.recorder = recorder
        self.stats = stats
        self.latest: Latest[OdometrySample] = Latest()
        """The newest odometry sample, in the ground frame (:attr:`ground_frame`)."""
        self.latest_raw: OdometrySample | None = None
        """The newest odometry sample in the source's own frame."""
        self.arrivals: deque[float] = deque(maxlen=512)
        """Arrival times (monotonic s) of the newest samples (the preflight rate check)."""
        self.ground_frame = GroundFrame()
        """The daemon's world frame (z = 0: the ground) against the odometry's and PX4's."""
        self.t_forward_failing_since: float | None = None
        """When the current run of failed vision forwards began (monotonic s); None when the
        last forward went out."""
        self._forward_streak = 0

    def set_ground(self, frame: GroundFrame) -> None:
        """Fly in ``frame`` from now on; the newest sample is published again in it."""
        self.ground_frame = frame
        if self.latest_raw is not None:
            self.latest.set(frame.to_world(self.latest_raw))

    async def run(self) -> None:
        fwd = self.cfg.forward_to_px4 and self.cfg.kind == "mocap"
        min_dt = 1.0 / self.cfg.forward_rate_hz
        t_fwd = -math.inf
        try:
            async for raw in self.source.samples():
                self.latest_raw = raw
                self.arrivals.append(raw.t_arrival_mono_s)
                s = self.ground_frame.to_world(raw)
                self.latest.set(s)
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


class DepthPreparer:
    """Once flying, prepares each new depth frame in the DQN executor as it arrives; at the step
    boundary, :meth:`prepared_for` hands the mission its frame prepared.

    Latest wins: frames that arrive while one is being prepared are skipped, except the newest,
    which is prepared next. In the mission, with ``depth.prepare_within_s`` set, a frame that
    arrives earlier than that before the next step boundary is only checked, not prepared: the
    step uses the newest frame, and a later one will replace it. A frame that is rejected
    (checked or prepared) is flagged as the depth ingest's ``error`` (while it is still the
    newest), so the supervisor stops the flight for bad depth.

    Inputs from the mission: :attr:`next_step_mono_s` and :attr:`next_start`."""

    def __init__(
        self,
        cfg: DepthSourceConfig,
        depth: DepthIngest,
        odometry: OdometryIngest,
        decider: Decider,
        executor: Executor,
        path: RoughPath,
        state: FlightState,
        stats: RunStats,
    ) -> None:
        self.window_s = cfg.preparation_window_s()
        self.depth = depth
        self.odometry = odometry
        self.decider = decider
        self.executor = executor
        self.path = path
        self.state = state
        self.stats = stats
        self.next_step_mono_s: float | None = None
        """When the mission's next step boundary falls (monotonic s); None outside the mission."""
        self.next_start: tuple[np.ndarray, np.ndarray] | None = None
        """Commanded start (world m) and velocity (m/s) of the next primitive, once in the mission."""
        self._preparing: asyncio.Future[PreparedFrame] | None = None

    def motion_now(self) -> Motion | None:
        """The vehicle's motion now and the commanded start of its next primitive, for a frame
        prepared between step boundaries (None before the mission: the boundary computes it)."""
        odom, start = self.odometry.latest.value, self.next_start
        if odom is None or start is None:
            return None
        yaw = float(self.path.heading_at(np.asarray(odom.pos_world_m, dtype=np.float64)))
        return Motion.of(odom, start[0], start[1], yaw)

    async def run(self) -> None:
        seq = 0
        latest = self.depth.latest
        while True:
            frame = await latest.wait_newer(seq)
            seq = latest.seq
            if not self.state.flying or self.state.stop is not None:
                continue
            due = self.next_step_mono_s
            try:
                if self.window_s is not None and due is not None and time.monotonic() < due - self.window_s:
                    await self._check(frame)
                else:
                    await self._prepare(frame)
            except DepthFrameError as exc:
                if latest.value is frame:
                    self.depth.error = str(exc)
            except Exception as exc:  # a bug: the step prepares its frame itself
                log.error("depth_prepare_failed", error=f"{type(exc).__name__}: {exc}")

    def _check(self, frame: DepthFrame) -> asyncio.Future[None]:
        """Only the checks of ``frame`` (raises ``DepthFrameError`` as preparing it would), in the
        DQN executor, off the loop."""
        self.stats.depth_frames_checked += 1
        loop = asyncio.get_running_loop()
        return loop.run_in_executor(self.executor, validate_depth_mm, frame.depth_mm, self.decider.preprocess)

    def _prepare(self, frame: DepthFrame) -> asyncio.Future[PreparedFrame]:
        """Preparation of ``frame`` in the DQN executor, against a snapshot of the history now."""
        decider = self.decider
        self.stats.depth_frames_prepared += 1
        loop = asyncio.get_running_loop()
        fut = loop.run_in_executor(
            self.executor, decider.prepare, frame, decider.snapshot(), self.motion_now(), decider.memory
        )
        self._preparing = fut
        return fut

    async def prepared_for(self, frame: DepthFrame) -> tuple[PreparedFrame, DecisionPath]:
        """At the step boundary: ``frame`` prepared against the current history, and how it came.

        Ready: no wait. Being prepared: wait for it (the executor has one thread; anything else
        would queue behind it). Otherwise prepare it now. Raises ``DepthFrameError``.
        """
        decider = self.decider
        prepared = decider.current(frame)
        if prepared is not None:
            return prepared, "prepared"
        if self._preparing is not None and not self._preparing.done():
            await asyncio.wait({self._preparing})  # never cancels it; its task reads the outcome
            prepared = decider.current(frame)
            if prepared is not None:
                return prepared, "waited"
        return await self._prepare(frame), "full"


# --- the vehicle ---------------------------------------------------------------------------------


async def watch_vehicle(vehicle: VehicleLink) -> None:
    """Run the link's telemetry; a failure is logged (the supervisor sees the link go quiet)."""
    try:
        await vehicle.run_telemetry()
    except asyncio.CancelledError:
        raise
    except Exception as exc:
        log.error("telemetry_failed", error=f"{type(exc).__name__}: {exc}")


async def mode_stream(vehicle: VehicleLink) -> AsyncIterator[str]:
    """Flight-mode names as they change (for the offboard-switch trigger)."""
    last = None
    while True:
        mode = vehicle.state.mode
        if mode != last:
            last = mode
            yield mode
        await asyncio.sleep(0.05)


class SetpointStreamer:
    """Samples the commanded trajectory at ``rate_hz`` (absolute schedule) and sends it, in PX4's
    frame, while the flight state says ``streaming``.

    A new trajectory (:meth:`command`) wakes the streamer at once, so its first setpoint leaves
    without waiting for the next tick; for a planner decision the time from the decision's start
    to that first setpoint is the decision latency. Outputs: :attr:`last_setpoint_world_m`,
    :attr:`decision_latency_last_s` and the setpoint figures in ``stats``."""

    def __init__(
        self,
        rate_hz: float,
        vehicle: VehicleLink,
        odometry: OdometryIngest,
        state: FlightState,
        clock: DecisionClock,
        recorder: SafeRecorder,
        stats: RunStats,
    ) -> None:
        self.period_s = 1.0 / rate_hz
        self.vehicle = vehicle
        self.odometry = odometry
        self.state = state
        self.clock = clock
        self.recorder = recorder
        self.stats = stats
        self.trajectory: Trajectory | None = None
        """What is streamed (None: nothing)."""
        self.last_setpoint_world_m: np.ndarray | None = None
        """The newest setpoint sent (world, m), shape (3,)."""
        self.decision_latency_last_s = math.nan
        """The last decision's latency (s): its start -> its primitive's first setpoint sent."""
        self._t_decision_mono_s: float | None = None
        self._wake = asyncio.Event()

    def command(self, trajectory: Trajectory | None, t_decision_mono_s: float | None = None) -> None:
        """Stream ``trajectory`` from now (None: nothing); ``t_decision_mono_s``: when the planner
        decision that chose it started (its latency is measured)."""
        self.trajectory = trajectory
        if t_decision_mono_s is not None:
            self._t_decision_mono_s = t_decision_mono_s
        self._wake.set()

    def wake(self) -> None:
        """Send a setpoint now (the next tick's schedule is kept)."""
        self._wake.set()

    async def run(self) -> None:
        period = self.period_s
        next_t = time.monotonic()
        last_sent: float | None = None
        last_traj: Any = None
        while True:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(max(0.0, next_t - time.monotonic())):
                    await self._wake.wait()
            self._wake.clear()
            now = time.monotonic()
            if now >= next_t:
                next_t += period
                if next_t < now:
                    next_t = now + period
            traj = self.trajectory
            if traj is None or not self.state.streaming:
                last_sent = None
                continue
            pos, vel, yaw = traj.sample(now)
            try:
                await self.vehicle.set_setpoint(self.odometry.ground_frame.to_px4(pos), vel, yaw)
            except VehicleError as exc:
                log.error("setpoint_failed", error=str(exc))
                continue
            t_sent = time.monotonic()
            self.last_setpoint_world_m = pos
            self.stats.setpoints += 1
            if last_sent is not None:
                self.stats.setpoint_interval.add(t_sent - last_sent)
            last_sent = t_sent
            if traj is not last_traj and self._t_decision_mono_s is not None and self.state.in_mission:
                self.decision_latency_last_s = t_sent - self._t_decision_mono_s
                self.stats.decision_latency.add(self.decision_latency_last_s)
                self.stats.inference.add(self.clock.last_s)
            last_traj = traj
            self.recorder.setpoint(t_sent, pos, vel, yaw)


# --- supervisor ----------------------------------------------------------------------------------


class Supervisor:
    """In-flight checks at ``safety.check_rate_hz`` once the flight state says ``supervising``;
    also feeds the systemd watchdog and records the vehicle's state. Its output is a stop request.

    :attr:`safety` is ``cfg.safety`` until preflight replaces it with the stale-odometry limit
    sized from the measured stream."""

    def __init__(
        self,
        safety: SafetyConfig,
        *,
        state: FlightState,
        request_stop: StopRequester,
        vehicle: VehicleLink,
        depth: DepthIngest,
        odometry: OdometryIngest,
        streamer: SetpointStreamer,
        clock: DecisionClock,
        path: RoughPath,
        crash_probe: Callable[[], bool] | None,
        notifier: Notifier,
        recorder: SafeRecorder,
        stats: RunStats,
    ) -> None:
        self.safety = safety
        self.state = state
        self.request_stop = request_stop
        self.vehicle = vehicle
        self.depth = depth
        self.odometry = odometry
        self.streamer = streamer
        self.clock = clock
        self.path = path
        self.crash_probe = crash_probe
        self.notifier = notifier
        self.recorder = recorder
        self.stats = stats
        self.frozen_watches = (
            FrozenPositionWatch("odometry"),
            FrozenPositionWatch("PX4's position estimate"),
        )
        self.deferred_stop: tuple[StopReason, str] | None = None
        """A stop found while the link was quiet, waiting for the link's verdict."""

    async def run(self) -> None:
        period = 1.0 / self.safety.check_rate_hz
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
            if not self.state.supervising or self.state.stop is not None:
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
                threshold = snap.t_depth_mono_s + self.safety.stale_depth_s
            elif reason is StopReason.STALE_ODOMETRY:
                threshold = snap.t_odom_mono_s + self.safety.stale_odometry_s
            self.request_stop(reason, detail, threshold)

    def snapshot(self, now: float) -> FlightSnapshot:
        depth, odom = self.depth.latest.value, self.odometry.latest.value
        pos = np.asarray(odom.pos_world_m, dtype=np.float64) if odom is not None else np.full(3, np.nan)
        dev = float(self.path.deviation_m(pos)) if np.all(np.isfinite(pos)) else math.inf
        running = self.clock.t_start_mono_s
        probe = self.crash_probe
        failing = self.odometry.t_forward_failing_since
        return FlightSnapshot(
            t_mono_s=now,
            vehicle=self.vehicle.state,
            t_depth_mono_s=depth.t_capture_mono_s if depth is not None else -math.inf,
            t_odom_mono_s=odom.t_arrival_mono_s if odom is not None else -math.inf,
            pos_world_m=pos,
            deviation_m=dev,
            in_mission=self.state.in_mission,
            inference_s=(now - running) if running is not None else self.clock.last_s,
            crashed=bool(probe()) if probe is not None else False,
            depth_error=self.depth.error,
            frozen_position=self._frozen_verdict(now, odom),
            vision_forward_failing_s=0.0 if failing is None else now - failing,
        )

    def _frozen_verdict(self, now: float, odom: OdometrySample | None) -> str | None:
        """Feed the frozen-position watches (the daemon's odometry, PX4's estimate) with their
        fresh reports while the mission streams setpoints; the first verdict, if any."""
        cmd = self.streamer.last_setpoint_world_m
        if not (self.state.in_mission and self.state.streaming) or cmd is None or odom is None:
            for w in self.frozen_watches:
                w.reset()
            return None
        odom_w, px4_w = self.frozen_watches
        odom_w.add(odom.t_arrival_mono_s, cmd, odom.pos_world_m)
        st = self.vehicle.state
        px4_w.add(st.t_position_mono_s, cmd, st.pos_world_m)
        return odom_w.verdict(now) or px4_w.verdict(now)

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
                self.state.pause_streaming()
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
            if found is None and self.streamer.trajectory is not None:
                log.warning("stop_deferral_cleared", detail="link back, nothing to stop for: streaming again")
                self.state.start_streaming()
        return False
