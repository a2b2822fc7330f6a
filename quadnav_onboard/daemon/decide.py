"""The DQN side of a step, split so that the heavy half runs before the step boundary.

When a depth frame arrives, :meth:`Decider.prepare` (in the DQN executor thread) preprocesses it and
runs the network's depth lane on the depth stack the observation history *would* hold with it. At
the step boundary, :meth:`Decider.decide` (on the event loop) pushes the prepared input into the
history and runs only the position lane and the head (~0.1-0.6 ms), provided the prepared frame is
the newest one and the history has not changed since (:meth:`Decider.current`). Otherwise the
daemon prepares the newest frame first, in the executor, and then decides: the same result either
way, since ``Policy.act_from_features(Policy.depth_features(d), r) == Policy.act(d, r)``.

The depth safety filter (:mod:`quadnav_onboard.shield`, when the model flies with it) follows the
same split: a preparation given the vehicle's motion also computes the filter's verdict for the
next step, on a copy of the filter's memory with this view added; the step commits that memory
and masks the head's arg-max with the verdict. Without a prepared verdict the step computes it.

Threads: the history lives on the event loop (read and pushed there only); a preparation gets its
own copy (:meth:`Decider.snapshot`), and hands its result back by replacing ``prepared`` (one
reference), so nothing needs a lock. Filter memories are never mutated once published: the loop
replaces ``memory`` with a new one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav_onboard.observation import ObservationHistory
from quadnav_onboard.policy import Policy
from quadnav_onboard.preprocess import PreprocessConfig, preprocess_depth_mm, preprocess_depth_pair
from quadnav_onboard.primitives import PrimitiveSet
from quadnav_onboard.shield import (
    PointMemory,
    ShieldConfig,
    shield_at_scale,
    shield_config_from_meta,
    shield_verdict,
)
from quadnav_onboard.sources.base import DepthFrame, OdometrySample

__all__ = ["FLOOR_Z_M", "Decider", "Decision", "DecisionPath", "Motion", "PreparedFrame"]

FLOOR_Z_M = 0.0
"""The floor's height in the daemon's world frame (m). The daemon shifts odometry into the frame of
the ground the vehicle stood on at take-off, or of ``safety.ground_z_m`` (``daemon/ground.py``),
never the estimator's origin. So world z is height above that ground, as the supervisor's altitude
band (``safety.altitude_floor_m``) reads it too."""

DecisionPath = Literal["prepared", "waited", "full"]
"""How a step got its prepared frame: ready at the step boundary; being prepared at the boundary
(awaited); or prepared at the boundary (preprocessing and the whole network ran in the step)."""


@dataclass(frozen=True)
class PreparedFrame:
    """One depth frame, preprocessed and through the depth lane."""

    frame: DepthFrame
    depth_input: NDArray[np.float32]
    """The network's depth input for this frame, float32 (32, 32) in [0, 1]."""
    features: NDArray[np.float32]
    """Depth-lane features of the history's last k_d - 1 inputs and this one, float32 (64 * width,)."""
    history_version: int
    """``ObservationHistory.version`` they were computed against."""
    allowed: NDArray[np.bool_] | None = None
    """The shield's verdict for the next step, when prepared with the vehicle's motion (else None:
    the step boundary computes it)."""
    clearance_m: NDArray[np.float64] | None = None
    """The shield's clearance (m) of every primitive, with ``allowed``."""
    memory: PointMemory | None = None
    """The shield's memory with this view added, committed when the frame is decided on."""
    nearest_view: NDArray[np.float32] | None = None
    """The nearest surface per cell of this frame (32, 32), when the shield uses it
    (``depth_pooling: min``, :func:`quadnav_onboard.preprocess.nearest_depth_mm`)."""
    nearest_at: NDArray[np.float32] | None = None
    """Where in each cell that surface was seen (32, 32, 2), with ``nearest_view``
    (:attr:`quadnav_onboard.preprocess.DepthInputs.near_at`)."""

    @property
    def shield_view(self) -> tuple[NDArray[np.float32], NDArray[np.float32] | None]:
        """What the shield remembers of this frame: the nearest view and where in each cell it was
        seen, else the network's input (on the cells' centre rays)."""
        if self.nearest_view is None:
            return self.depth_input, None
        return self.nearest_view, self.nearest_at


@dataclass(frozen=True)
class Motion:
    """Where the vehicle is and where the next primitive starts, at a step boundary (world frame)."""

    pos_world_m: NDArray[np.float64]
    """Measured position (m), (3,): the camera's viewpoint and the tracking prediction's start."""
    vel_world_m_s: NDArray[np.float64]
    """Measured velocity (m/s), (3,) (the commanded one when the odometry has none)."""
    start_world_m: NDArray[np.float64]
    """Commanded start of the next primitive (the previous one's commanded end), (3,)."""
    start_vel_world_m_s: NDArray[np.float64]
    """Commanded velocity there, (3,)."""
    yaw_rad: float
    """Heading of this step's frame (the camera's yaw)."""

    @classmethod
    def of(
        cls, odom: OdometrySample, start_world_m: ArrayLike, start_vel_world_m_s: ArrayLike, yaw_rad: float
    ) -> Motion:
        """From an odometry sample (its velocity, or the commanded one when it has none)."""
        start_vel = np.asarray(start_vel_world_m_s, dtype=np.float64)
        vel = start_vel if odom.vel_world_m_s is None else np.asarray(odom.vel_world_m_s, dtype=np.float64)
        pos = np.asarray(odom.pos_world_m, dtype=np.float64)
        return cls(pos, vel, np.asarray(start_world_m, dtype=np.float64), start_vel, float(yaw_rad))


@dataclass(frozen=True)
class Decision:
    """The outcome of one step's decision."""

    action: int
    q: NDArray[np.float32]
    """Q-values, shape (n_actions,)."""
    depth_input: NDArray[np.float32]
    """The depth input pushed into the history (what the network saw last), (32, 32)."""
    path: DecisionPath
    allowed: NDArray[np.bool_] | None = None
    """Primitives the shield allowed (n_actions,); None when the shield is off."""
    clearance_m: NDArray[np.float64] | None = None
    """The shield's clearance (m) of every primitive (n_actions,); None when it is off."""


class Decider:
    """The observation history, the policy, and the newest prepared frame (latest wins)."""

    def __init__(
        self,
        policy: Policy,
        preprocess: PreprocessConfig,
        prims: PrimitiveSet | None = None,
        shield: ShieldConfig | None = None,
    ) -> None:
        self.policy = policy
        self.preprocess = preprocess
        self.history = ObservationHistory(policy.depth_history, policy.position_history)
        self.prepared: PreparedFrame | None = None
        self.prims = prims or policy.primitive_set()
        shield = shield if shield is not None else shield_config_from_meta(policy.checkpoint.meta)
        self.shield = shield_at_scale(shield, policy.primitive_config().scale_m, self.prims.scale_m)
        """The depth safety filter (default: the one the model was evaluated with), its memory
        counted for the primitives flown (:func:`quadnav_onboard.shield.shield_at_scale`)."""
        self.memory = PointMemory(1, self.shield) if self.shield.enabled else None

    def snapshot(self) -> ObservationHistory:
        """Loop side: a copy of the history for one preparation."""
        return self.history.copy()

    def prepare(
        self,
        frame: DepthFrame,
        history: ObservationHistory,
        motion: Motion | None = None,
        memory: PointMemory | None = None,
    ) -> PreparedFrame:
        """Executor side: preprocess ``frame``, run the depth lane on ``history`` (a snapshot) plus
        this input, and keep the result as the newest prepared frame. With the shield on and the
        vehicle's ``motion`` now, also its verdict for the next step, from ``memory`` (the
        decider's memory when the snapshot was taken; memories are never mutated once published).

        Raises :class:`quadnav_onboard.preprocess.DepthFrameError` for an unusable frame.
        """
        nearest = nearest_at = None
        if self.shield.enabled and self.shield.depth_pooling == "min":
            depth_in, nearest, nearest_at = preprocess_depth_pair(frame.depth_mm, self.preprocess)
        else:
            depth_in = preprocess_depth_mm(frame.depth_mm, self.preprocess)
        features = self.policy.depth_features(history.depth_with(depth_in))
        prepared = PreparedFrame(frame, depth_in, features, history.version, nearest_view=nearest,
                                 nearest_at=nearest_at)
        if memory is not None and motion is not None and self.shield.enabled:
            allowed, clearance, after = self._verdict(memory, *prepared.shield_view, motion)
            prepared = replace(prepared, allowed=allowed, clearance_m=clearance, memory=after)
        self.prepared = prepared
        return prepared

    def current(self, frame: DepthFrame) -> PreparedFrame | None:
        """The prepared frame if it is ``frame`` and was prepared against the history as it is now."""
        p = self.prepared
        if p is not None and p.frame is frame and p.history_version == self.history.version:
            return p
        return None

    def decide(
        self,
        prepared: PreparedFrame,
        rel_pos_body_m: ArrayLike,
        path: DecisionPath,
        motion: Motion | None = None,
    ) -> Decision:
        """Loop side: push (the prepared input, ``rel_pos_body_m``) and pick the action (head only),
        among the primitives the shield allows from ``motion`` (required when the shield is on)."""
        if prepared.history_version != self.history.version:
            raise RuntimeError("decide() with a frame prepared against an older history")
        allowed = clearance = None
        if self.memory is not None:
            if prepared.memory is not None:  # verdict prepared with the frame, off the loop
                allowed, clearance, self.memory = prepared.allowed, prepared.clearance_m, prepared.memory
            elif motion is None:
                raise ValueError("the shield is on: decide() needs the vehicle's motion")
            else:
                allowed, clearance, self.memory = self._verdict(self.memory, *prepared.shield_view, motion)
        self.history.push(prepared.depth_input, rel_pos_body_m)
        action, q = self.policy.act_from_features(prepared.features, self.history.rel_array(), allowed,
                                                  self.prims.scale_m)
        return Decision(action, q, prepared.depth_input, path, allowed, clearance)

    def _verdict(
        self, memory: PointMemory, depth_input: NDArray[np.float32], at: NDArray[np.float32] | None,
        m: Motion,
    ) -> tuple[NDArray, NDArray, PointMemory]:
        """A new memory with this view (its surfaces placed by ``at``, if given), and every
        primitive checked against it (as the sim does)."""
        cfg, mem = self.shield, memory.copy()
        pos, yaw = m.pos_world_m[None], np.array([m.yaw_rad])
        mem.add([0], depth_input[None], pos, yaw, None if at is None else at[None])
        allowed, clearance = shield_verdict(
            self.prims, mem.points, mem.depth_m, mem.pose, m.start_world_m[None],
            m.start_vel_world_m_s[None], yaw, pos, m.vel_world_m_s[None], cfg,
            floor_z_m=FLOOR_Z_M,
        )
        return allowed[0], clearance[0], mem
