"""The flight daemon: startup -> connect -> preflight -> wait for go -> take-off -> mission ->
stop ladder -> shutdown, read top to bottom in :meth:`FlightDaemon.run` and
:meth:`FlightDaemon._lifecycle`.

The daemon is built by composition: :meth:`FlightDaemon._build` makes the tasks
(:mod:`quadnav_onboard.daemon.loops`: depth ingest, depth preparation, odometry ingest, setpoint
streamer, supervisor; :mod:`~quadnav_onboard.daemon.planner`: the mission), each given its inputs,
and one :class:`~quadnav_onboard.daemon.state.FlightState` that owns the phase, the commanding
flags and the stop request. One ``asyncio.TaskGroup`` runs the data-flow tasks; the lifecycle runs
in the group's body and always ends in the stop ladder
(:class:`~quadnav_onboard.daemon.ladder.StopLadder`), which leaves the vehicle holding, landed,
or (pilot takeover, link loss) untouched. Each depth frame is prepared (preprocessed, depth lane
run) in a one-thread executor as it arrives, so the loop never stalls; at the step boundary only
the rest of the network (~0.1-0.6 ms) runs, on the loop (:mod:`quadnav_onboard.daemon.decide`).
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import math
import signal
import time
from collections.abc import Callable, Coroutine
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from quadnav_onboard import jit
from quadnav_onboard.daemon.config import FlightConfig
from quadnav_onboard.daemon.decide import Decider
from quadnav_onboard.daemon.ladder import StopLadder
from quadnav_onboard.daemon.loops import (
    DecisionClock,
    DepthIngest,
    DepthPreparer,
    OdometryIngest,
    SetpointStreamer,
    Supervisor,
    mode_stream,
    watch_vehicle,
)
from quadnav_onboard.daemon.mission import CurrentPose, RampTrajectory
from quadnav_onboard.daemon.notify import Notifier, NullNotifier
from quadnav_onboard.daemon.planner import PlannerTask
from quadnav_onboard.daemon.preflight import Preflight
from quadnav_onboard.daemon.recording import SafeRecorder
from quadnav_onboard.daemon.state import FlightState, Phase
from quadnav_onboard.daemon.stats import Latest, RunStats
from quadnav_onboard.daemon.stepper import MissionStepper, PendingStep
from quadnav_onboard.daemon.summary import FlightSummary
from quadnav_onboard.daemon.supervisor import PreflightCheck, PreflightError, StopReason
from quadnav_onboard.logs import get_logger
from quadnav_onboard.path import RoughPath
from quadnav_onboard.policy import Policy
from quadnav_onboard.record.flight import record_px4_time
from quadnav_onboard.sources.base import DepthSource, OdometrySample, OdometrySource
from quadnav_onboard.step import EpisodeLimits
from quadnav_onboard.vehicle import Px4Setup, VehicleError, VehicleErrorKind, VehicleLink

__all__ = ["FlightDaemon", "OdometrySpeed", "freeze_heap"]

log = get_logger("quadnav.daemon")


class _SensorOpenError(RuntimeError):
    """A depth or odometry source failed to open (before anything armed)."""


@dataclass(frozen=True)
class _Tasks:
    """One flight's parts, built from the daemon's inputs when it runs."""

    depth: DepthIngest
    odometry: OdometryIngest
    preparer: DepthPreparer
    streamer: SetpointStreamer
    supervisor: Supervisor
    preflight: Preflight
    planner: PlannerTask
    ladder: StopLadder


class FlightDaemon:
    """Fly one mission. Build with sources, a vehicle link and a policy; ``await run()``.

    ``cfg``, the sources and ``trigger`` may be replaced until :meth:`run`, which builds the
    flight's tasks again from them."""

    def __init__(
        self,
        cfg: FlightConfig,
        *,
        path: RoughPath,
        policy: Policy,
        depth: DepthSource,
        odometry: OdometrySource,
        vehicle: VehicleLink,
        recorder: Any = None,
        crash_probe: Callable[[], bool] | None = None,
        notifier: Notifier | None = None,
        trigger: Any = None,
        t_start_mono_s: float | None = None,
    ) -> None:
        self.cfg = cfg
        self.path = path
        self.policy = policy
        self.depth_source = depth
        self.odometry_source = odometry
        self.vehicle = vehicle
        self.recorder = SafeRecorder(recorder)
        self.crash_probe = crash_probe
        self.notifier: Notifier = notifier if notifier is not None else NullNotifier()
        self.trigger = trigger
        self.t_start_mono_s = time.monotonic() if t_start_mono_s is None else t_start_mono_s
        """When the daemon started (the process, from the command line): READY is timed from it."""
        self.prims = (cfg.primitives or policy.primitive_config()).build()
        self.preprocess_cfg = cfg.preprocess or policy.preprocess_config()
        self.decider = Decider(policy, self.preprocess_cfg, self.prims, cfg.shield)
        self.state = FlightState(self.recorder)
        """The phase, the commanding flags and the stop request: the only copy."""
        self.stats = RunStats()
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="dqn")
        self.tasks: _Tasks = self._build()
        """The flight's parts (built again by :meth:`run`, from the inputs then)."""
        self._kernels_at_arming: dict[str, int] | None = None
        self._ramp_end_world_m: np.ndarray | None = None
        self._signals = 0
        self._forced = False
        self._main_task: asyncio.Task[Any] | None = None
        self._hold_task: asyncio.Future[Any] | None = None

    # --- the stop API --------------------------------------------------------------------------

    def request_stop(self, reason: StopReason, detail: str, t_threshold_mono_s: float | None = None) -> bool:
        """Ask for the flight to stop for ``reason`` (the first request wins; True for it).
        ``detail`` is for people: nothing decides on it. ``t_threshold_mono_s``: when a stale input
        crossed its limit (the hold's reaction is timed from it)."""
        return self.state.request_stop(reason, detail, t_threshold_mono_s)

    # --- what a test, a benchmark or the operator's tools read ----------------------------------

    @property
    def phase(self) -> Phase:
        return self.state.phase

    @property
    def stop_reason(self) -> StopReason | None:
        return self.state.stop_reason

    @property
    def stop_detail(self) -> str:
        return "" if self.state.stop is None else self.state.stop.detail

    @property
    def in_mission(self) -> bool:
        return self.state.in_mission

    @property
    def flying(self) -> bool:
        return self.state.flying

    @property
    def steps(self) -> int:
        """Mission steps flown so far."""
        return self.tasks.planner.steps

    @property
    def pending_step(self) -> PendingStep | None:
        """The mission's step in progress (decided, not yet ended)."""
        return self.tasks.planner.pending

    @property
    def next_step_mono(self) -> float | None:
        """When the mission's next step boundary falls (monotonic s); None outside the mission."""
        return self.tasks.preparer.next_step_mono_s

    @property
    def latest_odom(self) -> Latest[OdometrySample]:
        """The newest odometry sample, in the ground frame."""
        return self.tasks.odometry.latest

    @property
    def deferred_stop(self) -> tuple[StopReason, str] | None:
        """A stop the supervisor found on a quiet link, waiting for the link's verdict."""
        return self.tasks.supervisor.deferred_stop

    # --- entry point ---------------------------------------------------------------------------

    async def run(self) -> FlightSummary:
        """Fly; never raises for flight problems: the outcome is in the returned summary."""
        self._main_task = asyncio.current_task()
        loop = asyncio.get_running_loop()
        installed = self._install_signals(loop)
        tasks = self.tasks = self._build()
        try:
            async with contextlib.AsyncExitStack() as stack:
                try:
                    await stack.enter_async_context(self.depth_source)
                    await stack.enter_async_context(self.odometry_source)
                except Exception as exc:  # nothing is armed yet: a refusal, not a bug
                    raise _SensorOpenError(f"{type(exc).__name__}: {exc}") from exc
                stack.push_async_callback(self.vehicle.close)
                async with asyncio.TaskGroup() as tg:
                    background = [
                        tg.create_task(tasks.depth.run(), name="depth"),
                        tg.create_task(tasks.preparer.run(), name="depth_prepare"),
                        tg.create_task(tasks.odometry.run(), name="odometry"),
                        tg.create_task(tasks.supervisor.run(), name="supervisor"),
                        tg.create_task(tasks.streamer.run(), name="setpoints"),
                    ]
                    try:
                        await self._lifecycle(tg, background)
                    finally:
                        for task in background:
                            task.cancel()
        except asyncio.CancelledError:
            if not self._forced:
                raise
            log.warning("forced_exit", reason=self.stop_reason.value if self.stop_reason else None)
            if self._hold_task is not None:
                with contextlib.suppress(Exception, asyncio.CancelledError):
                    await asyncio.wait_for(self._hold_task, 1.0)
        except _SensorOpenError as exc:
            log.error("sensor_open_failed", error=str(exc))
            self.request_stop(StopReason.PREFLIGHT_FAILED, f"a sensor cannot open: {exc}")
        except Exception as exc:  # a bug
            log.exception("daemon_error", error=str(exc))
            self.request_stop(StopReason.INTERNAL_ERROR, f"{type(exc).__name__}: {exc}")
        finally:
            for sig in installed:
                loop.remove_signal_handler(sig)
            self._executor.shutdown(wait=False, cancel_futures=True)
            gc.unfreeze()  # a process that goes on (tests, the benchmark) collects as before
            if self._kernels_at_arming is not None:
                compiled = jit.compiled_since(self._kernels_at_arming)
                self.stats.kernels_compiled_in_flight = compiled
                if compiled:
                    log.warning("kernels_compiled_in_flight", kernels=compiled)
        return self._shutdown()

    def _build(self) -> _Tasks:
        """The flight's tasks, each given what it reads and where its output goes."""
        cfg, state, rec, stats = self.cfg, self.state, self.recorder, self.stats
        stop = self.request_stop
        clock = DecisionClock()
        depth = DepthIngest(self.depth_source, rec, stats)
        odometry = OdometryIngest(self.odometry_source, cfg.odometry, self.vehicle, rec, stats)
        preparer = DepthPreparer(
            cfg.depth, depth, odometry, self.decider, self._executor, self.path, state, stats
        )
        streamer = SetpointStreamer(
            cfg.vehicle.setpoint_rate_hz, self.vehicle, odometry, state, clock, rec, stats
        )
        supervisor = Supervisor(
            cfg.safety,
            state=state,
            request_stop=stop,
            vehicle=self.vehicle,
            depth=depth,
            odometry=odometry,
            streamer=streamer,
            clock=clock,
            path=self.path,
            crash_probe=self.crash_probe,
            notifier=self.notifier,
            recorder=rec,
            stats=stats,
        )
        preflight = Preflight(
            cfg,
            path=self.path,
            policy=self.policy,
            prims=self.prims,
            preprocess_cfg=self.preprocess_cfg,
            decider=self.decider,
            vehicle=self.vehicle,
            depth=depth,
            odometry=odometry,
            supervisor=supervisor,
            recorder=rec,
            stats=stats,
        )
        limits = EpisodeLimits(cfg.mission.goal_radius_m, cfg.reward.max_deviation_m, cfg.mission.max_steps)
        planner = PlannerTask(
            MissionStepper(self.path, self.prims, self.decider, limits, cfg.reward),
            state=state,
            request_stop=stop,
            depth=depth,
            odometry=odometry,
            preparer=preparer,
            streamer=streamer,
            clock=clock,
            notifier=self.notifier,
            recorder=rec,
            stats=stats,
        )
        ladder = StopLadder(cfg, self.vehicle, rec, stats)
        return _Tasks(depth, odometry, preparer, streamer, supervisor, preflight, planner, ladder)

    def _install_signals(self, loop: asyncio.AbstractEventLoop) -> list[int]:
        installed = []
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                loop.add_signal_handler(sig, self.handle_signal, sig)
                installed.append(sig)
            except (RuntimeError, ValueError, NotImplementedError):  # not the main thread
                pass
        return installed

    def handle_signal(self, signum: int) -> None:
        """First SIGINT/SIGTERM: stop (hold, land, flush). Second: command hold and exit now."""
        self._signals += 1
        name = signal.Signals(signum).name
        if self._signals == 1:
            log.warning("signal", signal=name, action="stop: hold then land")
            self.request_stop(StopReason.OPERATOR_STOP, f"{name} received")
            return
        log.warning("signal", signal=name, action="forced exit after commanding hold")
        self._forced = True
        self.state.pause_streaming()
        if self.state.flying:
            self._hold_task = asyncio.ensure_future(self._quiet(self.vehicle.hold()))
        if self._main_task is not None:
            self._main_task.cancel()

    @staticmethod
    async def _quiet(coro: Coroutine[Any, Any, Any]) -> None:
        try:
            await coro
        except VehicleError as exc:
            log.error("vehicle_command_failed", error=str(exc))

    # --- lifecycle -----------------------------------------------------------------------------

    async def _lifecycle(self, tg: asyncio.TaskGroup, background: list[asyncio.Task[Any]]) -> None:
        tasks = self.tasks
        try:
            await self._connect(tg, background)
            self.state.enter(Phase.PREFLIGHT)
            await self._until_stopped(tasks.preflight.run())
            if self.stop_reason is not None:
                return
            freeze_heap()
            self.stats.ready_s = time.monotonic() - self.t_start_mono_s
            log.info("ready", ready_s=round(self.stats.ready_s, 3), warmup_s=self.stats.warmup_s)
            self.notifier.ready()
            self.notifier.status("preflight passed; waiting for go")
            await self._until_stopped(self._wait_for_go())
            if self.stop_reason is None:
                await self._until_stopped(self._takeoff())
            if self.stop_reason is None:
                assert self._ramp_end_world_m is not None
                await self._until_stopped(tasks.planner.run(self._ramp_end_world_m))
        except PreflightError as exc:
            self.request_stop(StopReason.PREFLIGHT_FAILED, str(exc))
        except VehicleError as exc:
            self.request_stop(StopReason.VEHICLE_ERROR, str(exc))
        except Exception as exc:
            log.exception("lifecycle_error", error=str(exc))
            self.request_stop(StopReason.INTERNAL_ERROR, f"{type(exc).__name__}: {exc}")
        finally:
            await self._stop_ladder()

    async def _until_stopped(self, coro: Coroutine[Any, Any, None]) -> None:
        """Run ``coro`` until it returns or a stop is requested (then cancel it)."""
        task = asyncio.ensure_future(coro)
        stop = asyncio.ensure_future(self.state.stopped.wait())
        try:
            await asyncio.wait({task, stop}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stop.cancel()
            if not task.done():
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        if task.done() and not task.cancelled():
            exc = task.exception()
            if exc is not None:
                raise exc

    async def _connect(self, tg: asyncio.TaskGroup, background: list[asyncio.Task[Any]]) -> None:
        """Connect to the one vehicle on the link. No autopilot, or more than one, is a refusal
        (nothing is armed yet)."""
        self.state.enter(Phase.CONNECT)
        try:
            await self.vehicle.connect()
        except VehicleError as exc:
            if exc.kind in (VehicleErrorKind.BINDING, VehicleErrorKind.CONNECT):
                raise PreflightError(PreflightCheck("vehicle", False, str(exc), retry=False)) from exc
            raise
        bound = self.vehicle.state.binding
        if bound is not None:
            self.recorder.event(time.monotonic(), "vehicle_bound", str(bound), system_id=bound.system_id)
        background.append(tg.create_task(watch_vehicle(self.vehicle), name="telemetry"))
        if isinstance(self.vehicle, Px4Setup):
            rate = self.cfg.vehicle.telemetry_rate_hz
            try:
                await self.vehicle.request_telemetry_rates(rate)
                log.info("telemetry_rates_requested", rate_hz=rate)
            except VehicleError as exc:  # preflight's rate check decides whether the stream will do
                log.warning("telemetry_rates_refused", rate_hz=rate, error=str(exc), kind=exc.kind.value)

    async def _wait_for_go(self) -> None:
        """Wait for the operator's go. For a pilot's switch to OFFBOARD, stream the vehicle's current
        position meanwhile (PX4 accepts OFFBOARD only with a live setpoint stream, and the vehicle
        then holds where it is)."""
        self.state.enter(Phase.WAIT_FOR_GO)
        if self.trigger is None or getattr(self.trigger, "mode", "auto") == "auto":
            return
        from quadnav_onboard.trigger import wait_for_go

        tasks = self.tasks
        latest = tasks.odometry.latest
        tasks.streamer.command(CurrentPose(lambda: latest.value))
        self.state.start_streaming()
        go = await wait_for_go(
            self.trigger, mode_stream=mode_stream(self.vehicle), heartbeat=self.notifier.watchdog
        )
        log.info("go", mode=go.mode, detail=getattr(go, "detail", ""))

    async def _takeoff(self) -> None:
        """Stream a setpoint at the current position, arm and switch to offboard (unless the pilot
        already did), then ramp up and over to the path start."""
        self.state.enter(Phase.TAKEOFF)
        tasks = self.tasks
        cfg = self.cfg.mission
        odom = tasks.odometry.latest.value
        assert odom is not None
        yaw0 = float(self.path.yaw_at(0.0))
        if not self.state.streaming and not self.vehicle.state.armed:  # still on the ground: measure it now
            check = tasks.preflight.set_ground()
            if not check.ok:
                raise PreflightError(check)
            odom = tasks.odometry.latest.value
            assert odom is not None
        ground = np.asarray(odom.pos_world_m, dtype=np.float64)
        if not self.state.streaming:
            tasks.streamer.command(
                RampTrajectory(ground[None].repeat(2, 0), cfg.takeoff_speed_m_s, yaw0, time.monotonic())
            )
            self.state.start_streaming()
            await asyncio.sleep(3.0 / self.cfg.vehicle.setpoint_rate_hz)
        # The go may come minutes after preflight: every input must still be healthy to fly. (A
        # pilot who armed and switched to OFFBOARD as the go has armed the vehicle on purpose.)
        pilot_armed = self.vehicle.state.armed
        await tasks.preflight.recheck_at_go(pilot_armed)
        self._kernels_at_arming = jit.signature_counts()  # nothing may compile from here on
        self.state.arming()
        if not self.vehicle.state.armed:
            await self.vehicle.arm()
            await self._await_state(lambda st: st.armed, "armed")
        if self.vehicle.state.mode != "OFFBOARD":
            await self._start_offboard()
            await self._await_state(lambda st: st.mode == "OFFBOARD", "in OFFBOARD")
        self.state.airborne()
        t_ramp = time.monotonic()
        ramp = RampTrajectory.takeoff(ground, self.path.start_m, cfg.takeoff_speed_m_s, yaw0, t_ramp)
        self._ramp_end_world_m = ramp.end_world_m  # the mission starts from its commanded end
        tasks.streamer.command(ramp)
        log.info("takeoff", ground_m=np.round(ground, 2).tolist(), start_m=self.path.start_m.tolist())
        deadline = time.monotonic() + cfg.takeoff_timeout_s
        speed = OdometrySpeed()
        while True:
            odom = tasks.odometry.latest.value
            assert odom is not None
            done = time.monotonic() >= ramp.t_start_mono_s + ramp.duration_s
            # PX4's land detector reports IN_AIR some time after the climb began (MAVSDK's landed
            # state lagged the emulator's by up to ~0.9 s): a mission started before it would read
            # "on the ground in the middle of the mission" as a crash.
            airborne = self.vehicle.state.landed is not True
            near = float(np.linalg.norm(odom.pos_world_m - self.path.start_m)) <= cfg.start_tolerance_m
            # The mission starts from a hover at the start, as a training episode starts at rest:
            # started while the climb still carries the vehicle up (or back down from the ramp's
            # overshoot), its first steps' rewards depend on when the checks above happen to pass.
            settled = speed.slow_for(odom, cfg.start_settled_speed_m_s) >= cfg.start_settled_for_s
            if done and airborne and near and settled:
                return
            if time.monotonic() > deadline:
                self.request_stop(
                    StopReason.TAKEOFF_TIMEOUT, f"path start not reached in {cfg.takeoff_timeout_s} s"
                )
                return
            await asyncio.sleep(0.05)

    async def _start_offboard(self) -> None:
        """Switch to OFFBOARD, retried (``vehicle.offboard_start_attempts``) while the setpoint
        stream runs: PX4 SITL refused one start with NO_SETPOINT_SET after 64 setpoints."""
        v = self.cfg.vehicle
        for attempt in range(1, v.offboard_start_attempts + 1):
            await self._fresh_setpoint()
            try:
                await self.vehicle.start_offboard()
                if attempt > 1:
                    self.stats.offboard_start_attempts = attempt
                return
            except VehicleError as exc:
                retry = exc.kind in (VehicleErrorKind.REFUSED, VehicleErrorKind.TIMEOUT)
                last = attempt == v.offboard_start_attempts
                log.warning("offboard_start_refused", attempt=attempt, of=v.offboard_start_attempts,
                            result=exc.result, kind=exc.kind.value, retry=retry and not last)
                self.recorder.event(time.monotonic(), "offboard_start_refused", str(exc), attempt=attempt)
                self.stats.offboard_start_attempts = attempt
                if not retry or last or not self.state.streaming:
                    raise
                await asyncio.sleep(v.offboard_retry_s)

    async def _fresh_setpoint(self) -> None:
        """Have the streamer send a setpoint now (bounded by two periods). MAVSDK refuses a start
        locally with NO_SETPOINT_SET when a heartbeat not in OFFBOARD arrived after its newest
        setpoint (its offboard plugin then forgets the setpoint): starting right after one narrows
        that window to the time between the two calls."""
        sent = self.stats.setpoints
        self.tasks.streamer.wake()
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(2.0 / self.cfg.vehicle.setpoint_rate_hz):
                while self.stats.setpoints == sent:
                    await asyncio.sleep(0.001)

    async def _await_state(self, pred: Callable[[Any], bool], what: str) -> None:
        """Wait until telemetry confirms a command took effect (bounded by command_timeout_s)."""
        try:
            async with asyncio.timeout(self.cfg.vehicle.command_timeout_s):
                while not pred(self.vehicle.state):
                    await asyncio.sleep(0.02)
        except TimeoutError:
            limit = self.cfg.vehicle.command_timeout_s
            raise VehicleError(f"telemetry did not confirm the vehicle {what} within {limit:g} s") from None

    # --- stop ladder and shutdown --------------------------------------------------------------

    async def _stop_ladder(self) -> None:
        """Every flight ends here: nothing streams or supervises any more, the step in progress is
        ended, and a vehicle that was armed gets the ladder's answer to the stop."""
        if self.state.stop is None:
            self.request_stop(StopReason.INTERNAL_ERROR, "lifecycle ended without a stop reason")
        stop = self.state.stop
        assert stop is not None
        tasks = self.tasks
        self.state.stopping()
        self.notifier.status(f"stopping: {stop.reason.value}")
        tasks.planner.close(stop.reason)
        tasks.streamer.command(None)
        if self.state.flying:
            await tasks.ladder.respond(stop)

    def _shutdown(self) -> FlightSummary:
        """The flight's summary, written into the record as it closes."""
        reason = self.stop_reason or StopReason.INTERNAL_ERROR
        planner = self.tasks.planner
        odom = self.tasks.odometry.latest.value
        pos = np.asarray(odom.pos_world_m) if odom is not None else np.full(3, np.nan)
        t0, t1 = planner.t_start_mono_s, planner.t_end_mono_s
        started = math.isfinite(t0)
        summary = FlightSummary.build(
            reason=reason,
            detail=self.stop_detail,
            steps=self.steps,
            navigation_distance_m=float(self.path.progress_m(pos))
            if started and np.all(np.isfinite(pos))
            else 0.0,
            flight_time_s=(t1 - t0) if started else 0.0,
            crashed=reason is StopReason.CRASH,
            total_reward=planner.total_reward,
            stats=self.stats,
            model_sha256=self.policy.checkpoint.sha256,
        )
        record_px4_time(self.recorder, self.vehicle.state)
        self.recorder.close(reason.value, summary.to_dict())
        return summary


class OdometrySpeed:
    """The vehicle's speed (m/s) from the odometry's positions: the displacement between two
    samples at least 20 ms apart over their arrival times (inf until there are two). The same
    estimate whatever the source (some give no velocity)."""

    def __init__(self) -> None:
        self._prev: OdometrySample | None = None
        self.speed_m_s = math.inf
        self._slow_since_s: float | None = None

    def slow_for(self, odom: OdometrySample, limit_m_s: float) -> float:
        """Update with ``odom``; how long (s, arrival time) every estimate has been at most
        ``limit_m_s`` (0 while the newest is above it). A vehicle swinging about a point reads
        slow at each turn: it is settled only when it stays slow."""
        speed = self.update(odom)
        if speed > limit_m_s:
            self._slow_since_s = None
            return 0.0
        if self._slow_since_s is None:
            self._slow_since_s = odom.t_arrival_mono_s
        return odom.t_arrival_mono_s - self._slow_since_s

    def update(self, odom: OdometrySample) -> float:
        prev = self._prev
        if prev is None:
            self._prev = odom
            return self.speed_m_s
        dt = odom.t_arrival_mono_s - prev.t_arrival_mono_s
        if dt >= 0.02:
            moved = np.asarray(odom.pos_world_m, dtype=np.float64) - np.asarray(prev.pos_world_m)
            self.speed_m_s = float(np.linalg.norm(moved)) / dt
            self._prev = odom
        return self.speed_m_s


def freeze_heap() -> None:
    """Collect once, then move every object alive now (the model, torch, numpy, MAVSDK, the
    sources) into the collector's permanent generation (:func:`gc.freeze`).

    A full collection walks every object of the heap: in this process that took 89-208 ms
    (``benchmarks/bench_daemon.py --full-gc-mid-flight --no-gc-freeze``, its JSON's
    ``gc_pauses_main_run``; docs/daemon.md), long enough to delay a
    decision or a setpoint by several periods. After the freeze a full collection walks only what
    the flight itself allocated. Run once, after preflight and before READY, when the long-lived
    objects exist and nothing flies yet."""
    gc.collect()
    gc.freeze()
    log.info("heap_frozen", objects=gc.get_freeze_count())
