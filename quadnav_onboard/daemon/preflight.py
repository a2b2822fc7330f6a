"""Preflight: every check before anything arms, and the input checks again at the go.

The model (its outputs, the mission speed it was trained for, one whole test decision that
compiles every lazy kernel), PX4's parameters, then the inputs (depth, odometry and its rate,
vehicle health, the path start) until they pass or ``vehicle.health_timeout_s`` runs out, the
stale-odometry limit sized from the measured stream, and the ground frame. A failure is a
:class:`~quadnav_onboard.daemon.supervisor.PreflightError` naming its check; whether time may fix
it is the check's typed ``retry`` field, never its text.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import time

import numpy as np

from quadnav_onboard import jit
from quadnav_onboard.daemon.config import FlightConfig
from quadnav_onboard.daemon.decide import Decider, Motion
from quadnav_onboard.daemon.ground import measure_ground
from quadnav_onboard.daemon.loops import DepthIngest, OdometryIngest, Supervisor
from quadnav_onboard.daemon.px4_params import Severity, judge_parameters, parameter_rules
from quadnav_onboard.daemon.recording import SafeRecorder
from quadnav_onboard.daemon.stats import RunStats
from quadnav_onboard.daemon.supervisor import (
    PreflightCheck,
    PreflightError,
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
from quadnav_onboard.preprocess import PreprocessConfig
from quadnav_onboard.primitives import PrimitiveSet
from quadnav_onboard.sources.base import DepthFrame
from quadnav_onboard.vehicle import Px4Setup, VehicleLink

__all__ = ["GO_RECHECK_S", "Preflight"]

log = get_logger("quadnav.daemon")

GO_RECHECK_S = 1.5
"""At the go, how long (s) a failed input check that time may fix has to pass again before the
flight is refused (the odometry rate is measured over the last second)."""


class Preflight:
    """The checks of one flight. Outputs: the ground frame (given to the odometry ingest), the
    in-flight stale-odometry limit (given to the supervisor) and the startup figures in
    ``stats``."""

    def __init__(
        self,
        cfg: FlightConfig,
        *,
        path: RoughPath,
        policy: Policy,
        prims: PrimitiveSet,
        preprocess_cfg: PreprocessConfig,
        decider: Decider,
        vehicle: VehicleLink,
        depth: DepthIngest,
        odometry: OdometryIngest,
        supervisor: Supervisor,
        recorder: SafeRecorder,
        stats: RunStats,
    ) -> None:
        self.cfg = cfg
        self.path = path
        self.policy = policy
        self.prims = prims
        self.preprocess_cfg = preprocess_cfg
        self.decider = decider
        self.vehicle = vehicle
        self.depth = depth
        self.odometry = odometry
        self.supervisor = supervisor
        self.recorder = recorder
        self.stats = stats

    async def run(self) -> None:
        """Every check must pass before anything arms; the first failure names itself."""
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
            checks = self.input_checks(now)
            failed = [c for c in checks if not c.ok]
            if not failed:
                for c in checks:
                    log.info("preflight_check", check=c.name, ok=True, detail=c.detail)
                self._size_stale_odometry(now)
                ground = self.set_ground()
                if not ground.ok:
                    raise PreflightError(ground)
                log.info("preflight_check", check=ground.name, ok=True, detail=ground.detail)
                self.recorder.event(now, "preflight", "all checks passed")
                return
            hard = [c for c in failed if not c.retry]
            if hard or now > deadline:
                raise PreflightError((hard or failed)[0])
            await asyncio.sleep(0.05)

    def input_checks(self, now: float, allow_armed: bool = False) -> list[PreflightCheck]:
        """Depth, odometry, vehicle health and path: run before READY and again right before arming."""
        cfg = self.cfg
        return [
            check_depth_frame(self.depth.latest.value, now, cfg.safety.stale_depth_s, self.preprocess_cfg),
            check_odometry(self.odometry.latest.value, now, cfg.safety.stale_odometry_s),
            check_odometry_rate(
                measure_odometry_rate(self.odometry.arrivals, now), cfg.safety.min_odometry_rate_hz
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
        rate = measure_odometry_rate(self.odometry.arrivals, now)
        limit = in_flight_stale_odometry_s(self.cfg.safety, rate)
        self.supervisor.safety = dataclasses.replace(self.cfg.safety, stale_odometry_s=limit)
        self.stats.odometry = {
            "requested_hz": self.cfg.vehicle.telemetry_rate_hz if self.cfg.odometry.kind == "px4" else None,
            "measured_hz": None if rate is None else round(rate.rate_hz, 1),
            "max_gap_ms": None if rate is None else round(rate.max_gap_s * 1e3, 1),
            "stale_limit_s": round(limit, 3),
        }
        log.info("stale_odometry_limit", **self.stats.odometry)

    def set_ground(self) -> PreflightCheck:
        """Measure the ground frame now, the vehicle standing on the ground (refused when PX4
        reports it in the air)."""
        raw = self.odometry.latest_raw
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
        self.odometry.set_ground(frame)
        self.stats.ground = frame.describe()
        self.recorder.event(time.monotonic(), "ground_reference", str(frame.describe()))
        return PreflightCheck(
            "ground", True, f"{frame.source}: ground at z {frame.ground_z_m:+.2f} m of the odometry frame, "
            f"PX4's frame {np.round(frame.px4_minus_world_m, 2).tolist()} m from the daemon's",
        )

    async def recheck_at_go(self, pilot_armed: bool) -> None:
        """The input checks again, at the go. A check that time may fix (a late sample, a dip in
        the odometry rate measured over the last second) gets ``GO_RECHECK_S`` to pass again; one
        that time cannot fix, or still failing then, refuses the flight before anything arms."""
        deadline = time.monotonic() + GO_RECHECK_S
        while True:
            failed = [c for c in self.input_checks(time.monotonic(), allow_armed=pilot_armed) if not c.ok]
            if not failed:
                return
            if any(not c.retry for c in failed) or time.monotonic() > deadline:
                raise PreflightError(failed[0])
            await asyncio.sleep(0.05)

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
        trained = pol.network.scale_range_m
        scale = self.prims.scale_m
        if trained is not None and not (trained[0] * (1 - 1e-6) <= scale <= trained[1] * (1 + 1e-6)):
            # the scale lane reads the scale across the range trained: past it, a value never seen
            return PreflightCheck(
                "model",
                False,
                f"primitives.scale_m {scale:g} is outside the scales the model reads, "
                f"{trained[0]:g}-{trained[1]:g} m (its network's scale_range_m): fly it within them",
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
