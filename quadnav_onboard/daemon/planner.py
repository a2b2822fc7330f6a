"""The mission task: at each step boundary, the step's inputs, the outcome test, the decision on
the newest depth frame, and the primitive handed to the setpoint streamer.

The step itself is :class:`~quadnav_onboard.daemon.stepper.MissionStepper` (the code the
training env runs, with N = 1); this task adds only the clock, the frames and the I/O. A decided
step waits in :attr:`PlannerTask.pending` until the next boundary (or the stop) ends it; its
typed :class:`~quadnav_onboard.step.StepRecord` then goes to the recorder.
"""

from __future__ import annotations

import asyncio
import math
import time
from typing import Any

import numpy as np

from quadnav_onboard.daemon.decide import Decision, Motion
from quadnav_onboard.daemon.loops import (
    DecisionClock,
    DepthIngest,
    DepthPreparer,
    OdometryIngest,
    SetpointStreamer,
    StopRequester,
)
from quadnav_onboard.daemon.notify import Notifier
from quadnav_onboard.daemon.recording import SafeRecorder, record_step
from quadnav_onboard.daemon.state import FlightState, Phase
from quadnav_onboard.daemon.stats import RunStats
from quadnav_onboard.daemon.stepper import MissionStepper, PendingStep
from quadnav_onboard.daemon.supervisor import StopReason
from quadnav_onboard.logs import get_logger
from quadnav_onboard.preprocess import DepthFrameError

__all__ = ["PlannerTask"]

log = get_logger("quadnav.daemon")


class PlannerTask:
    """Steps the planner from the commanded end of the take-off ramp until the goal, the step
    limit or a stop. Outputs: :attr:`steps`, :attr:`total_reward`, the mission's start and end
    times, and a stop request at the goal or the step limit."""

    def __init__(
        self,
        stepper: MissionStepper,
        *,
        state: FlightState,
        request_stop: StopRequester,
        depth: DepthIngest,
        odometry: OdometryIngest,
        preparer: DepthPreparer,
        streamer: SetpointStreamer,
        clock: DecisionClock,
        notifier: Notifier,
        recorder: SafeRecorder,
        stats: RunStats,
    ) -> None:
        self.stepper = stepper
        self.state = state
        self.request_stop = request_stop
        self.depth = depth
        self.odometry = odometry
        self.preparer = preparer
        self.streamer = streamer
        self.clock = clock
        self.notifier = notifier
        self.recorder = recorder
        self.stats = stats
        self.steps = 0
        """Steps flown (the step in progress not counted until it ends)."""
        self.total_reward = 0.0
        """Sum of the ended steps' rewards, as in training."""
        self.pending: PendingStep | None = None
        """The step in progress: decided, its end not known yet."""
        self._t_decided = math.nan
        """When the pending step's decision started (its record's time; the primitive starts once
        the decision is made)."""
        self.t_start_mono_s = math.nan
        self.t_end_mono_s = math.nan

    async def run(self, start_world_m: np.ndarray) -> None:
        """Fly from ``start_world_m`` (world, m): the commanded end of the take-off ramp."""
        self.state.enter(Phase.MISSION)
        stepper = self.stepper
        duration = stepper.prims.duration_s
        t0 = time.monotonic()
        self.t_start_mono_s = t0
        end_world, end_vel = np.asarray(start_world_m, dtype=np.float64), np.zeros(3)
        self.preparer.next_start = (end_world, end_vel)
        self.notifier.status("mission")
        k = 0
        while True:
            self.preparer.next_step_mono_s = t0 + k * duration  # frames well before it are only checked
            await asyncio.sleep(max(0.0, t0 + k * duration - time.monotonic()))
            odom = self.odometry.latest.value
            assert odom is not None  # preflight saw odometry; a stale one stops the flight
            pos = np.asarray(odom.pos_world_m, dtype=np.float64)
            inputs = stepper.inputs(k, pos)
            if self.pending is not None:
                self._end_step(self.pending, pos)
            self.steps = k
            if stepper.goal_reached(inputs):
                self.request_stop(StopReason.GOAL_REACHED, f"goal reached after {k} steps")
                return
            if stepper.step_limit_reached(k):
                self.request_stop(StopReason.STEP_LIMIT, f"{k} steps = mission.max_steps")
                return
            frame = self.depth.latest.value
            assert frame is not None  # as for odometry
            t_decide = time.monotonic()
            self.clock.t_start_mono_s = t_decide
            try:
                prepared, how = await self.preparer.prepared_for(frame)
            except DepthFrameError as exc:
                self.request_stop(StopReason.BAD_DEPTH, str(exc))
                return
            motion = Motion.of(odom, end_world, end_vel, inputs.yaw_rad)
            # the head and the shield, on the loop; the primitive starts when they are done
            pending = stepper.decide(k, inputs, prepared, how, motion, time.monotonic())
            self.clock.t_start_mono_s = None
            self.clock.last_s = time.monotonic() - t_decide
            prim = pending.primitive
            self.preparer.next_start = (prim.end_world_m, prim.end_vel_world_m_s)  # before any await
            self.streamer.command(prim, t_decision_mono_s=t_decide)
            await asyncio.sleep(0)  # let the streamer send the new primitive before we log and record
            end_world, end_vel = prim.end_world_m, prim.end_vel_world_m_s
            decision = pending.decision
            self.recorder.network_input(t_decide, k, decision.depth_input)
            frame_age_s = t_decide - frame.t_capture_mono_s
            self.stats.count_decision(decision.path, frame_age_s)
            self._t_decided = t_decide
            self.pending = pending
            self._log_step(pending, frame_age_s)
            k += 1

    def close(self, reason: StopReason) -> None:
        """The flight stopped: end the step in progress where the vehicle is now (a crash ends it
        collided), and the mission's time."""
        self.t_end_mono_s = time.monotonic()
        p, odom = self.pending, self.odometry.latest.value
        if p is None or odom is None:
            return
        self._end_step(p, np.asarray(odom.pos_world_m, dtype=np.float64), collided=reason is StopReason.CRASH)

    def _end_step(self, p: PendingStep, pos_world_m: np.ndarray, collided: bool = False) -> None:
        """Step ``p`` ended with the vehicle at ``pos_world_m``: its reward and its record."""
        record = self.stepper.finish(p, pos_world_m, collided)
        self.total_reward += float(record.reward[0])
        self.steps = p.step + 1
        self.pending = None
        record_step(
            self.recorder,
            self._t_decided,
            record,
            latency_ms=self.streamer.decision_latency_last_s * 1e3,
            primitive=p.primitive,
        )

    def _log_step(self, p: PendingStep, frame_age_s: float) -> None:
        d, inputs = p.decision, p.inputs
        q = d.q
        log.info(
            "step",
            step=p.step,
            action=d.action,
            q_max=round(float(q.max()), 4),
            q_values=np.round(q, 3).tolist(),
            pos_m=np.round(p.pos_world_m, 2).tolist(),
            rel_m=np.round(inputs.rel_pos_body_m, 2).tolist(),
            progress_m=round(float(self.stepper.path.progress_m(p.pos_world_m)), 2),
            inference_ms=round(self.clock.last_s * 1e3, 2),
            decision_path=d.path,
            frame_age_ms=round(frame_age_s * 1e3, 1),
            **_shield_log(d),
        )


def _shield_log(decision: Decision) -> dict[str, Any]:
    """The shield's verdict for a step's log line (nothing when it is off)."""
    if decision.allowed is None or decision.clearance_m is None:
        return {}
    return {
        "shield_allowed": int(decision.allowed.sum()),
        "shield_vetoed_greedy": bool(not decision.allowed[int(np.argmax(decision.q))]),
        "clearance_m": round(float(decision.clearance_m[decision.action]), 2),
    }
