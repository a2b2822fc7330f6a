"""The flight daemon: startup -> preflight -> wait for go -> take-off -> mission -> stop -> shutdown.

One ``asyncio.TaskGroup`` holds the data-flow tasks (see :mod:`quadnav_onboard.daemon.loops`):
depth ingest and odometry ingest (latest value wins), vehicle telemetry, the 20 Hz setpoint
streamer and the supervisor. The lifecycle runs in the group's body and always ends in
:meth:`FlightDaemon._respond`, which leaves the vehicle holding, landed, or (pilot takeover, link
loss) untouched. Each depth frame is prepared (preprocessed, depth lane run) in a one-thread
executor as it arrives, so the loop never stalls; at the step boundary only the rest of the network
(~0.1-0.6 ms) runs, on the loop (:mod:`quadnav_onboard.daemon.decide`).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import gc
import math
import signal
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from quadnav_onboard import jit
from quadnav_onboard.daemon.config import FlightConfig
from quadnav_onboard.daemon.decide import Decider, Motion
from quadnav_onboard.daemon.ground import measure_ground
from quadnav_onboard.daemon.ladder import StopLadder
from quadnav_onboard.daemon.mission import (
    ActivePrimitive,
    CurrentPose,
    RampTrajectory,
    goal_reached,
    step_inputs,
)
from quadnav_onboard.daemon.px4_params import Severity, judge_parameters, parameter_rules
from quadnav_onboard.daemon.summary import FlightSummary, SafeRecorder
from quadnav_onboard.daemon.supervisor import (
    PreflightCheck,
    PreflightError,
    StopReason,
    check_depth_frame,
    check_odometry,
    check_odometry_rate,
    check_start_inside,
    check_vehicle_ready,
    in_flight_stale_odometry_s,
    measure_odometry_rate,
)
from quadnav_onboard.logs import get_logger
from quadnav_onboard.path import RoughPath
from quadnav_onboard.policy import Policy
from quadnav_onboard.preprocess import DepthFrameError
from quadnav_onboard.sources.base import DepthFrame, DepthSource, OdometrySource
from quadnav_onboard.vehicle import Px4Setup, VehicleError, VehicleErrorKind, VehicleLink

__all__ = ["FlightDaemon"]

log = get_logger("quadnav.daemon")

GO_RECHECK_S = 1.5
"""At the go, how long (s) a failed input check that time may fix has to pass again before the
flight is refused (the odometry rate is measured over the last second)."""


class _SensorOpenError(RuntimeError):
    """A depth or odometry source failed to open (before anything armed)."""


class FlightDaemon(StopLadder):
    """Fly one mission. Build with sources, a vehicle link and a policy; ``await run()``."""

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
        notifier: Any = None,
        trigger: Any = None,
        t_start_mono_s: float | None = None,
    ) -> None:
        super().__init__(cfg, vehicle=vehicle, recorder=SafeRecorder(recorder), notifier=notifier)
        self.t_start_mono_s = time.monotonic() if t_start_mono_s is None else t_start_mono_s
        """When the daemon started (the process, from the command line): READY is timed from it."""
        self._kernels_at_arming: dict[str, int] | None = None
        self.path = path
        self.policy = policy
        self.depth_source = depth
        self.odometry_source = odometry
        self.crash_probe = crash_probe
        self.trigger = trigger
        self.prims = (cfg.primitives or policy.primitive_config()).build()
        self.preprocess_cfg = cfg.preprocess or policy.preprocess_config()
        self.decider = Decider(policy, self.preprocess_cfg, self.prims, cfg.shield)
        self.next_start: tuple[np.ndarray, np.ndarray] | None = None
        """Commanded start (world m) and velocity (m/s) of the next primitive, once in the mission."""
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="dqn")
        self.flying = False
        self.total_reward = 0.0
        self.steps = 0
        self.t_mission_start_mono_s = math.nan
        self.t_mission_end_mono_s = math.nan
        self._signals = 0
        self._forced = False
        self._main_task: asyncio.Task[Any] | None = None
        self._hold_task: asyncio.Task[Any] | None = None
        self._background: list[asyncio.Task[Any]] = []

    # --- entry point ---------------------------------------------------------------------------

    async def run(self) -> FlightSummary:
        """Fly; never raises for flight problems: the outcome is in the returned summary."""
        self._main_task = asyncio.current_task()
        loop = asyncio.get_running_loop()
        installed = self._install_signals(loop)
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
                        tg.create_task(self.ingest_depth(), name="depth"),
                        tg.create_task(self.prepare_depth(), name="depth_prepare"),
                        tg.create_task(self.ingest_odometry(), name="odometry"),
                        tg.create_task(self.supervise(), name="supervisor"),
                        tg.create_task(self.stream_setpoints(), name="setpoints"),
                    ]
                    self._background = background
                    try:
                        await self._lifecycle(tg)
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
        return self._finish()

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
        self.streaming = False
        if self.flying:
            self._hold_task = asyncio.ensure_future(self._quiet(self.vehicle.hold()))
        if self._main_task is not None:
            self._main_task.cancel()

    @staticmethod
    async def _quiet(coro: Any) -> None:
        try:
            await coro
        except VehicleError as exc:
            log.error("vehicle_command_failed", error=str(exc))

    # --- lifecycle -----------------------------------------------------------------------------

    async def _lifecycle(self, tg: asyncio.TaskGroup) -> None:
        try:
            await self._connect(tg)
            await self._until_stopped(self._preflight())
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
                await self._until_stopped(self._mission())
        except PreflightError as exc:
            self.request_stop(StopReason.PREFLIGHT_FAILED, str(exc))
        except VehicleError as exc:
            self.request_stop(StopReason.VEHICLE_ERROR, str(exc))
        except Exception as exc:
            log.exception("lifecycle_error", error=str(exc))
            self.request_stop(StopReason.INTERNAL_ERROR, f"{type(exc).__name__}: {exc}")
        finally:
            await self._respond()

    async def _until_stopped(self, coro: Any) -> None:
        """Run ``coro`` until it returns or a stop is requested (then cancel it)."""
        task = asyncio.ensure_future(coro)
        stop = asyncio.ensure_future(self.stop_event.wait())
        try:
            await asyncio.wait({task, stop}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stop.cancel()
            if not task.done():
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        if task.done() and not task.cancelled() and task.exception() is not None:
            raise task.exception()  # type: ignore[misc]

    async def _connect(self, tg: asyncio.TaskGroup) -> None:
        """Connect to the one vehicle on the link. No autopilot, or more than one, is a refusal
        (nothing is armed yet)."""
        self.phase = "connect"
        try:
            await self.vehicle.connect()
        except VehicleError as exc:
            if exc.kind in (VehicleErrorKind.BINDING, VehicleErrorKind.CONNECT):
                raise PreflightError(PreflightCheck("vehicle", False, str(exc), retry=False)) from exc
            raise
        bound = self.vehicle.state.binding
        if bound is not None:
            self.recorder.event(time.monotonic(), "vehicle_bound", str(bound), system_id=bound.system_id)
        self._background.append(tg.create_task(self.watch_vehicle(), name="telemetry"))
        if isinstance(self.vehicle, Px4Setup):
            rate = self.cfg.vehicle.telemetry_rate_hz
            try:
                await self.vehicle.request_telemetry_rates(rate)
                log.info("telemetry_rates_requested", rate_hz=rate)
            except VehicleError as exc:  # preflight's rate check decides whether the stream will do
                log.warning("telemetry_rates_refused", rate_hz=rate, error=str(exc), kind=exc.kind.value)

    async def _preflight(self) -> None:
        """Every check must pass before anything arms; the first failure names itself."""
        self.phase = "preflight"
        cfg = self.cfg
        model_check = self._check_model()
        log.info("preflight_check", check=model_check.name, ok=model_check.ok, detail=model_check.detail)
        if not model_check.ok:
            raise PreflightError(model_check)
        param_check = await self._check_parameters()
        log.info("preflight_check", check=param_check.name, ok=param_check.ok, detail=param_check.detail)
        if not param_check.ok:
            raise PreflightError(param_check)
        deadline = time.monotonic() + cfg.vehicle.health_timeout_s
        while True:
            now = time.monotonic()
            checks = self._input_checks(now)
            failed = [c for c in checks if not c.ok]
            if not failed:
                for c in checks:
                    log.info("preflight_check", check=c.name, ok=True, detail=c.detail)
                self._size_stale_odometry(now)
                ground = self._set_ground()
                if not ground.ok:
                    raise PreflightError(ground)
                log.info("preflight_check", check=ground.name, ok=True, detail=ground.detail)
                self.recorder.event(now, "preflight", "all checks passed")
                return
            hard = [c for c in failed if not c.retry]
            if hard or now > deadline:
                raise PreflightError((hard or failed)[0])
            await asyncio.sleep(0.05)

    def _input_checks(self, now: float, allow_armed: bool = False) -> list[PreflightCheck]:
        """Depth, odometry, vehicle health and path: run before READY and again right before arming."""
        cfg = self.cfg
        return [
            check_depth_frame(self.latest_depth.value, now, cfg.safety.stale_depth_s, self.preprocess_cfg),
            check_odometry(self.latest_odom.value, now, cfg.safety.stale_odometry_s),
            check_odometry_rate(
                measure_odometry_rate(self.odom_arrivals, now), cfg.safety.min_odometry_rate_hz
            ),
            check_vehicle_ready(self.vehicle.state, allow_armed),
            check_start_inside(self.path.start_m, cfg.safety),
        ]

    async def _check_parameters(self) -> PreflightCheck:
        """PX4's parameters over MAVLink: a wrong required one refuses the flight with the list to
        set; advice is logged as a warning (:mod:`quadnav_onboard.daemon.px4_params`)."""
        if not self.cfg.vehicle.check_parameters:
            return PreflightCheck("px4_parameters", True, "not checked (vehicle.check_parameters: false)")
        if not isinstance(self.vehicle, Px4Setup):
            return PreflightCheck("px4_parameters", True, "not checked: the link reads no parameters")
        rules = parameter_rules(self.cfg)
        values = await self.vehicle.read_parameters({r.name: r.kind for r in rules})
        findings = judge_parameters(rules, values)
        required = [f for f in findings if f.severity is Severity.REQUIRED]
        advice = [f for f in findings if f.severity is Severity.ADVICE]
        self.stats.px4_parameters = {"values": dict(values), "advice": [str(f) for f in advice],
                                     "required": [str(f) for f in required]}
        for f in advice:
            log.warning("px4_parameter_advice", name=f.name, value=f.value, want=f.want)
        if required:
            listed = "; ".join(str(f) for f in required)
            return PreflightCheck("px4_parameters", False, f"set on PX4: {listed}", retry=False)
        return PreflightCheck("px4_parameters", True, f"{len(rules)} read, {len(advice)} advice")

    def _size_stale_odometry(self, now: float) -> None:
        """Size the in-flight stale-odometry limit from the stream measured now."""
        rate = measure_odometry_rate(self.odom_arrivals, now)
        limit = in_flight_stale_odometry_s(self.cfg.safety, rate)
        self.safety = dataclasses.replace(self.cfg.safety, stale_odometry_s=limit)
        self.stats.odometry = {
            "requested_hz": self.cfg.vehicle.telemetry_rate_hz if self.cfg.odometry.kind == "px4" else None,
            "measured_hz": None if rate is None else round(rate.rate_hz, 1),
            "max_gap_ms": None if rate is None else round(rate.max_gap_s * 1e3, 1),
            "stale_limit_s": round(limit, 3),
        }
        log.info("stale_odometry_limit", **self.stats.odometry)

    def _set_ground(self) -> PreflightCheck:
        """Measure the ground frame now, the vehicle standing on the ground (refused when PX4
        reports it in the air)."""
        raw = self.latest_odom_raw
        if raw is None:
            return PreflightCheck("ground", False, "no odometry sample to measure the ground from")
        if self.vehicle.state.landed is False:
            return PreflightCheck(
                "ground", False, "PX4 reports the vehicle in the air: no ground to measure", retry=False
            )
        s = self.cfg.safety
        px4 = None if self.cfg.odometry.kind == "px4" else np.asarray(self.vehicle.state.pos_world_m)
        if px4 is not None and not np.all(np.isfinite(px4)):
            px4 = np.asarray(raw.pos_world_m)  # no estimate from PX4 yet: assume its frame is the odometry's
        frame = measure_ground(
            raw.pos_world_m, px4, configured_z_m=s.ground_z_m if s.ground_reference == "configured" else None
        )
        self.ground_frame = frame
        self.latest_odom.set(frame.to_world(raw))
        self.stats.ground = frame.describe()
        self.recorder.event(time.monotonic(), "ground_reference", str(frame.describe()))
        return PreflightCheck(
            "ground", True, f"{frame.source}: ground at z {frame.ground_z_m:+.2f} m of the odometry frame, "
            f"PX4's frame {np.round(frame.px4_minus_world_m, 2).tolist()} m from the daemon's",
        )

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
                if not retry or last or not self.streaming:
                    raise
                await asyncio.sleep(v.offboard_retry_s)

    async def _fresh_setpoint(self) -> None:
        """Have the streamer send a setpoint now (bounded by two periods). MAVSDK refuses a start
        locally with NO_SETPOINT_SET when a heartbeat not in OFFBOARD arrived after its newest
        setpoint (its offboard plugin then forgets the setpoint): starting right after one narrows
        that window to the time between the two calls."""
        sent = self.stats.setpoints
        self.new_trajectory.set()
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(2.0 / self.cfg.vehicle.setpoint_rate_hz):
                while self.stats.setpoints == sent:
                    await asyncio.sleep(0.001)

    def _check_model(self) -> PreflightCheck:
        pol = self.policy
        if pol.n_actions != self.prims.n_actions:
            return PreflightCheck(
                "model",
                False,
                f"model has {pol.n_actions} outputs, the action set has {self.prims.n_actions}",
            )
        prim_speed = self.prims.scale_m / self.prims.duration_s
        if not math.isclose(self.path.speed_m_s, prim_speed, rel_tol=0.05):
            # trained (and evaluated at any scale) with the moving setpoint one primitive ahead per
            # step: another ratio feeds the network relative positions it never saw
            return PreflightCheck(
                "model",
                False,
                f"mission.speed_m_s {self.path.speed_m_s:g} does not match the primitives "
                f"({self.prims.scale_m:g} m per {self.prims.duration_s:g} s = {prim_speed:g} m/s): "
                "the model was trained with the moving setpoint advancing one primitive per step",
            )
        try:
            t0 = time.monotonic()
            q = self._test_decision()
            self.stats.warmup_s = time.monotonic() - t0
        except Exception as exc:
            return PreflightCheck("model", False, f"test inference failed: {exc}")
        if q.shape != (self.prims.n_actions,) or not np.all(np.isfinite(q)):
            return PreflightCheck(
                "model", False, f"test inference gave Q-values of shape {q.shape} / non-finite"
            )
        sha = pol.checkpoint.sha256[:12]
        sh = self.decider.shield
        shield = (
            f"shield on (clearance {sh.clearance_m} m, memory {sh.memory_steps} decisions)"
            if sh.enabled
            else "shield off"
        )
        kernels = jit.signature_counts()
        return PreflightCheck(
            "model",
            True,
            f"{pol.n_actions} actions of {self.prims.scale_m} m, sha256 {sha}, {shield}; warm-up "
            f"{self.stats.warmup_s:.2f} s ({len(kernels)} kernels, {sum(kernels.values())} signatures "
            "compiled or loaded from cache)",
        )

    def _test_decision(self) -> np.ndarray:
        """One whole decision (preprocess, depth lane, shield, head) on a scratch decider and a
        synthetic frame: checks the model, and compiles what compiles on first use (the shield's
        numba code took ~250 ms on its first call, which in flight stalled the loop into a
        stale-depth stop)."""
        scratch = Decider(self.policy, self.preprocess_cfg, self.prims, self.cfg.shield)
        frame = DepthFrame(np.full((240, 424), 5000, np.uint16), time.monotonic())
        start = np.asarray(self.path.start_m, dtype=np.float64)
        motion = Motion(start, np.zeros(3), start, np.zeros(3), float(self.path.yaw_at(0.0)))
        q = np.zeros(self.prims.n_actions)
        for path in ("full", "prepared"):  # both ways a step takes its frame
            prepared = scratch.prepare(frame, scratch.snapshot())
            q = scratch.decide(prepared, np.zeros(3), path, motion).q
        return q

    async def _wait_for_go(self) -> None:
        """Wait for the operator's go. For a pilot's switch to OFFBOARD, stream the vehicle's current
        position meanwhile (PX4 accepts OFFBOARD only with a live setpoint stream, and the vehicle
        then holds where it is)."""
        self.phase = "wait_for_go"
        if self.trigger is None or getattr(self.trigger, "mode", "auto") == "auto":
            return
        from quadnav_onboard.trigger import wait_for_go

        self.trajectory = CurrentPose(lambda: self.latest_odom.value)
        self.streaming = True
        go = await wait_for_go(self.trigger, mode_stream=self.mode_stream(), heartbeat=self.notifier.watchdog)
        log.info("go", mode=go.mode, detail=getattr(go, "detail", ""))

    async def _takeoff(self) -> None:
        """Stream a setpoint at the current position, arm and switch to offboard (unless the pilot
        already did), then ramp up and over to the path start."""
        self.phase = "takeoff"
        cfg = self.cfg.mission
        odom = self.latest_odom.value
        assert odom is not None
        yaw0 = float(self.path.yaw_at(0.0))
        if not self.streaming and not self.vehicle.state.armed:  # still on the ground: measure it now
            check = self._set_ground()
            if not check.ok:
                raise PreflightError(check)
            odom = self.latest_odom.value
            assert odom is not None
        ground = np.asarray(odom.pos_world_m, dtype=np.float64)
        if not self.streaming:
            self.trajectory = RampTrajectory(
                ground[None].repeat(2, 0), cfg.takeoff_speed_m_s, yaw0, time.monotonic()
            )
            self.streaming = True
            await asyncio.sleep(3.0 / self.cfg.vehicle.setpoint_rate_hz)
        # The go may come minutes after preflight: every input must still be healthy to fly. (A
        # pilot who armed and switched to OFFBOARD as the go has armed the vehicle on purpose.)
        pilot_armed = self.vehicle.state.armed
        await self._recheck_inputs(pilot_armed)
        self._kernels_at_arming = jit.signature_counts()  # nothing may compile from here on
        self.flying = True
        if not self.vehicle.state.armed:
            await self.vehicle.arm()
            await self._await_state(lambda st: st.armed, "armed")
        if self.vehicle.state.mode != "OFFBOARD":
            await self._start_offboard()
            await self._await_state(lambda st: st.mode == "OFFBOARD", "in OFFBOARD")
        self.supervising = True
        ramp = RampTrajectory.takeoff(
            ground, self.path.start_m, cfg.takeoff_speed_m_s, yaw0, time.monotonic()
        )
        self.trajectory = ramp
        self.new_trajectory.set()
        log.info("takeoff", ground_m=np.round(ground, 2).tolist(), start_m=self.path.start_m.tolist())
        deadline = time.monotonic() + cfg.takeoff_timeout_s
        while True:
            pos = self.latest_odom.value.pos_world_m  # type: ignore[union-attr]
            done = time.monotonic() >= ramp.t_start_mono_s + ramp.duration_s
            # PX4's land detector reports IN_AIR some time after the climb began (MAVSDK's landed
            # state lagged the emulator's by up to ~0.9 s): a mission started before it would read
            # "on the ground in the middle of the mission" as a crash.
            airborne = self.vehicle.state.landed is not True
            if done and airborne and float(np.linalg.norm(pos - self.path.start_m)) <= cfg.start_tolerance_m:
                return
            if time.monotonic() > deadline:
                self.request_stop(
                    StopReason.TAKEOFF_TIMEOUT, f"path start not reached in {cfg.takeoff_timeout_s} s"
                )
                return
            await asyncio.sleep(0.05)

    async def _recheck_inputs(self, pilot_armed: bool) -> None:
        """The input checks again, at the go. A check that time may fix (a late sample, a dip in
        the odometry rate measured over the last second) gets ``GO_RECHECK_S`` to pass again; one
        that time cannot fix, or still failing then, refuses the flight before anything arms."""
        deadline = time.monotonic() + GO_RECHECK_S
        while True:
            failed = [c for c in self._input_checks(time.monotonic(), allow_armed=pilot_armed) if not c.ok]
            if not failed:
                return
            if any(not c.retry for c in failed) or time.monotonic() > deadline:
                raise PreflightError(failed[0])
            await asyncio.sleep(0.05)

    async def _await_state(self, pred: Callable[[Any], bool], what: str) -> None:
        """Wait until telemetry confirms a command took effect (bounded by command_timeout_s)."""
        try:
            async with asyncio.timeout(self.cfg.vehicle.command_timeout_s):
                while not pred(self.vehicle.state):
                    await asyncio.sleep(0.02)
        except TimeoutError:
            limit = self.cfg.vehicle.command_timeout_s
            raise VehicleError(f"telemetry did not confirm the vehicle {what} within {limit:g} s") from None

    # --- mission -------------------------------------------------------------------------------

    def motion_now(self) -> Motion | None:
        """The vehicle's motion now and the commanded start of its next primitive, for a frame
        prepared between step boundaries (None before the mission: the boundary computes it)."""
        odom, start = self.latest_odom.value, self.next_start
        if odom is None or start is None:
            return None
        yaw = float(self.path.heading_at(np.asarray(odom.pos_world_m, dtype=np.float64)))
        return Motion.of(odom, start[0], start[1], yaw)

    async def _mission(self) -> None:
        self.phase = "mission"
        self.in_mission = True
        duration = self.prims.duration_s
        t0 = time.monotonic()
        self.t_mission_start_mono_s = t0
        start = self.trajectory.end_world_m  # commanded end of the take-off ramp
        end_world, end_vel = np.asarray(start, dtype=np.float64), np.zeros(3)
        self.next_start = (end_world, end_vel)
        pending: dict[str, Any] | None = None
        self.notifier.status("mission")
        k = 0
        while True:
            self.next_step_mono = t0 + k * duration  # frames well before it are only checked
            await asyncio.sleep(max(0.0, t0 + k * duration - time.monotonic()))
            odom = self.latest_odom.value
            pos = np.asarray(odom.pos_world_m, dtype=np.float64)  # type: ignore[union-attr]
            inputs = step_inputs(self.path, k, duration, pos)
            if pending is not None:
                self._finish_step(pending, pos, inputs.distance_m)
                pending = None
            self.steps = k
            if goal_reached(self.path, pos, self.cfg.mission.goal_radius_m):
                self.request_stop(StopReason.GOAL_REACHED, f"goal reached after {k} steps")
                return
            if k >= self.cfg.mission.max_steps:
                self.request_stop(StopReason.STEP_LIMIT, f"{k} steps = mission.max_steps")
                return
            frame = self.latest_depth.value
            t_decide = time.monotonic()
            self.t_decision_start = t_decide
            try:
                prepared, how = await self.prepared_for(frame)  # type: ignore[arg-type]
            except DepthFrameError as exc:
                self.request_stop(StopReason.BAD_DEPTH, str(exc))
                return
            motion = Motion.of(odom, end_world, end_vel, inputs.yaw_rad)  # type: ignore[arg-type]
            # the head and the shield, on the loop
            decision = self.decider.decide(prepared, inputs.rel_pos_body_m, how, motion)
            self.t_decision_start = None
            self.last_inference_s = time.monotonic() - t_decide
            action, q = decision.action, decision.q
            prim = ActivePrimitive(self.prims, action, end_world, end_vel, inputs.yaw_rad, time.monotonic())
            self.next_start = (prim.end_world_m, prim.end_vel_world_m_s)  # before any await: preparations
            self.decision_t = t_decide
            self.trajectory = prim
            self.new_trajectory.set()
            await asyncio.sleep(0)  # let the streamer send the new primitive before we log and record
            end_world, end_vel = prim.end_world_m, prim.end_vel_world_m_s
            self.recorder.network_input(t_decide, k, decision.depth_input)
            frame_age_s = t_decide - frame.t_capture_mono_s  # type: ignore[union-attr]
            self.stats.count_decision(decision.path, frame_age_s)
            pending = {
                "t": t_decide,
                "step": k,
                "action": action,
                "q": q,
                "inputs": inputs,
                "pos": pos,
                "frame_age_s": frame_age_s,
                "allowed": decision.allowed,
                "clearance_m": decision.clearance_m,
                "prim": prim,
            }
            log.info(
                "step",
                step=k,
                action=action,
                q_max=round(float(q.max()), 4),
                q_values=np.round(q, 3).tolist(),
                pos_m=np.round(pos, 2).tolist(),
                rel_m=np.round(inputs.rel_pos_body_m, 2).tolist(),
                progress_m=round(float(self.path.progress_m(pos)), 2),
                inference_ms=round(self.last_inference_s * 1e3, 2),
                decision_path=decision.path,
                frame_age_ms=round(frame_age_s * 1e3, 1),
                **_shield_log(decision),
            )
            k += 1
            self.pending_step = pending


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


def _shield_log(decision: Any) -> dict[str, Any]:
    """The shield's verdict for a step's log line (nothing when it is off)."""
    if decision.allowed is None:
        return {}
    return {
        "shield_allowed": int(decision.allowed.sum()),
        "shield_vetoed_greedy": bool(not decision.allowed[int(np.argmax(decision.q))]),
        "clearance_m": round(float(decision.clearance_m[decision.action]), 2),
    }
