"""The flight's planner step: :mod:`quadnav_onboard.step` with N = 1, around the decider.

The mission task calls :meth:`MissionStepper.inputs` at each step boundary, :meth:`decide` with
the prepared depth frame, and :meth:`finish` at the next boundary (or when the flight stops
mid-step), which returns the step's :class:`~quadnav_onboard.step.StepRecord`. Nothing here
awaits, reads a clock or touches the vehicle: the parity test drives it with the training env's
poses and frames and compares records.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav_onboard import step
from quadnav_onboard.daemon.decide import Decider, Decision, DecisionPath, Motion, PreparedFrame
from quadnav_onboard.daemon.mission import ActivePrimitive, StepInputs, step_inputs
from quadnav_onboard.path import RoughPath
from quadnav_onboard.primitives import PrimitiveSet
from quadnav_onboard.reward import RewardParams

__all__ = ["MissionStepper", "PendingStep"]


@dataclass(frozen=True)
class PendingStep:
    """A decided step whose end is not known yet."""

    step: int
    """Step index k."""
    t_mono_s: float
    """When the decision started (monotonic s)."""
    inputs: StepInputs
    """The step's inputs (from the position at the boundary)."""
    pos_world_m: NDArray[np.float64]
    """Measured position at the boundary (world, m), (3,)."""
    decision: Decision
    """What the policy (and the depth safety filter) chose."""
    primitive: ActivePrimitive
    """The commanded primitive."""


class MissionStepper:
    """One flight's steps: inputs, decision, primitive, and the typed record of each."""

    def __init__(
        self,
        path: RoughPath,
        prims: PrimitiveSet,
        decider: Decider,
        limits: step.EpisodeLimits,
        reward: RewardParams,
    ) -> None:
        self.path = path
        self.prims = prims
        self.decider = decider
        self.limits = limits
        self.reward = reward

    def inputs(self, k: int, pos_world_m: ArrayLike) -> StepInputs:
        """Inputs of step ``k`` from the measured position."""
        return step_inputs(self.path, k, self.prims.duration_s, pos_world_m)

    def goal_reached(self, inputs: StepInputs) -> bool:
        """The vehicle is at the goal (as the training env's outcome test reads it)."""
        return bool(step.goal_reached(self.path, inputs.batch, self.limits.goal_radius_m)[0])

    def step_limit_reached(self, k: int) -> bool:
        """``k`` steps flown is the limit."""
        return k >= self.limits.max_steps

    def decide(
        self,
        k: int,
        inputs: StepInputs,
        prepared: PreparedFrame,
        how: DecisionPath,
        motion: Motion,
        t_mono_s: float,
    ) -> PendingStep:
        """Pick the primitive of step ``k``: it starts at ``motion``'s commanded start, at
        ``t_mono_s`` (monotonic s)."""
        decision = self.decider.decide(prepared, inputs.rel_pos_body_m, how, motion)
        prim = ActivePrimitive(
            self.prims, decision.action, motion.start_world_m, motion.start_vel_world_m_s, inputs.yaw_rad,
            t_mono_s,
        )
        pos = np.asarray(motion.pos_world_m, dtype=np.float64)
        return PendingStep(k, t_mono_s, inputs, pos, decision, prim)

    def finish(self, pending: PendingStep, pos_world_m: ArrayLike, collided: bool = False) -> step.StepRecord:
        """The record of ``pending`` now that the vehicle is at ``pos_world_m`` (``collided``: the
        step ended in a crash)."""
        after = self.inputs(pending.step + 1, pos_world_m)
        d = pending.decision
        return step.finish_step(
            pending.inputs.batch,
            after.batch,
            step=pending.step,
            action=d.action,
            q_values=d.q,
            pos_world_m=pending.pos_world_m,
            end_pos_world_m=pos_world_m,
            collided=collided,
            path=self.path,
            limits=self.limits,
            reward_params=self.reward,
            shield_allowed=d.allowed,
            shield_clearance_m=d.clearance_m,
        )
