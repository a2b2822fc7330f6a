"""Pure mission geometry: the flight's view of one step, and setpoint trajectories.

The step itself is :mod:`quadnav_onboard.step`, the code the training env runs too; this module
holds its one-vehicle views (:func:`step_inputs`, :func:`goal_reached`, :class:`ActivePrimitive`)
and the trajectories the setpoint streamer samples between decisions.
Positions world frame (x forward, y left, z up), metres; velocities m/s; times seconds.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav_onboard import step
from quadnav_onboard.frames import body_to_world, quat_to_yaw
from quadnav_onboard.path import RoughPath
from quadnav_onboard.primitives import PrimitiveSet

__all__ = [
    "ActivePrimitive",
    "CurrentPose",
    "RampTrajectory",
    "StepInputs",
    "goal_reached",
    "step_inputs",
]


@dataclass(frozen=True)
class StepInputs:
    """The planner's inputs at one step boundary, for the one vehicle flown
    (:class:`quadnav_onboard.step.StepInputs` with N = 1)."""

    setpoint_world_m: NDArray[np.float64]
    """Moving setpoint (world, m), shape (3,)."""
    yaw_rad: float
    """Heading (world yaw, rad) of this step's heading frame."""
    rel_pos_body_m: NDArray[np.float64]
    """Setpoint minus quad in the heading frame (m), shape (3,): the network's position input."""
    distance_m: float
    """|setpoint - quad| (m): the reward's d_t."""
    batch: step.StepInputs
    """The same inputs as the step module computed them (N = 1), for :func:`step.finish_step`."""


def step_inputs(path: RoughPath, k: int, duration_s: float, pos_world_m: ArrayLike) -> StepInputs:
    """State of step ``k`` for a quad measured at ``pos_world_m`` (world, m)."""
    b = step.step_inputs(path, k, duration_s, pos_world_m)
    yaw, d = float(b.yaw_rad[0]), float(b.distance_m[0])
    return StepInputs(b.setpoint_world_m[0], yaw, b.rel_pos_body_m[0], d, b)


def goal_reached(path: RoughPath, pos_world_m: ArrayLike, goal_radius_m: float) -> bool:
    """Within ``goal_radius_m`` of the goal, or progress at (or past) the path's length."""
    return bool(step.goal_reached(path, step.step_inputs(path, 0, 0.0, pos_world_m), goal_radius_m)[0])


@dataclass(frozen=True)
class ActivePrimitive:
    """One commanded primitive, anchored in the world at its start time."""

    primitives: PrimitiveSet
    action: int
    start_world_m: NDArray[np.float64]
    """Commanded start point (world, m): the previous primitive's commanded end point."""
    start_vel_world_m_s: NDArray[np.float64]
    """Velocity at the start (world, m/s): the previous primitive's end velocity."""
    yaw_rad: float
    """Heading frame (world yaw, rad) the primitive is expressed in; also the commanded yaw."""
    t_start_mono_s: float
    """When it started (monotonic s)."""

    def sample(self, t_mono_s: float) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """Commanded (position world m, velocity world m/s, yaw rad) at ``t_mono_s``; clamps at the end."""
        t = min(max(t_mono_s - self.t_start_mono_s, 0.0), self.primitives.duration_s)
        u = np.array([[t / self.primitives.duration_s]])
        pos, vel = step.primitive_targets(
            self.primitives, [self.action], self.start_world_m[None], self.start_vel_world_m_s[None],
            [self.yaw_rad], u,
        )
        return pos[0, 0], vel[0, 0], self.yaw_rad

    @property
    def end_world_m(self) -> NDArray[np.float64]:
        """Commanded end point (world, m)."""
        disp = self.primitives.end_displacement_m(self.action)
        return self.start_world_m + body_to_world(disp, self.yaw_rad)

    @property
    def end_vel_world_m_s(self) -> NDArray[np.float64]:
        """Velocity at the end (world, m/s): the next primitive's start velocity."""
        return body_to_world(self.primitives.end_velocity_m_s(self.action), self.yaw_rad)


@dataclass(frozen=True)
class RampTrajectory:
    """Straight segments through ``points_world_m`` (K, 3) at constant ``speed_m_s``: the take-off."""

    points_world_m: NDArray[np.float64]
    speed_m_s: float
    yaw_rad: float
    t_start_mono_s: float

    @classmethod
    def takeoff(
        cls, ground_world_m: ArrayLike, start_world_m: ArrayLike, speed_m_s: float, yaw_rad: float, t: float
    ) -> RampTrajectory:
        """Straight up from ``ground_world_m`` to the start's altitude, then across to the start."""
        g = np.asarray(ground_world_m, dtype=np.float64)
        s = np.asarray(start_world_m, dtype=np.float64)
        up = np.array([g[0], g[1], s[2]])
        return cls(np.stack([g, up, s]), speed_m_s, yaw_rad, t)

    @property
    def end_world_m(self) -> NDArray[np.float64]:
        return self.points_world_m[-1]

    @property
    def duration_s(self) -> float:
        """Time (s) to travel the whole ramp."""
        return float(np.linalg.norm(np.diff(self.points_world_m, axis=0), axis=1).sum()) / self.speed_m_s

    def sample(self, t_mono_s: float) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """(position world m, velocity world m/s, yaw rad) at ``t_mono_s``; holds the end point after."""
        travel = max(t_mono_s - self.t_start_mono_s, 0.0) * self.speed_m_s
        pts = self.points_world_m
        for a, b in itertools.pairwise(pts):
            seg = b - a
            length = float(np.linalg.norm(seg))
            if length < 1e-9:
                continue
            if travel <= length:
                direction = seg / length
                return a + direction * travel, direction * self.speed_m_s, self.yaw_rad
            travel -= length
        return pts[-1].copy(), np.zeros(3), self.yaw_rad


class CurrentPose:
    """Wherever the vehicle is now, at zero velocity and its own yaw: streamed while waiting for a
    pilot's switch to OFFBOARD, so the switch holds the vehicle in place.

    ``odometry_fn()`` returns the newest :class:`~quadnav_onboard.sources.base.OdometrySample`.
    """

    def __init__(self, odometry_fn: Callable[[], Any]) -> None:
        self._odometry_fn = odometry_fn

    def sample(self, t_mono_s: float) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        odom = self._odometry_fn()
        yaw = float(quat_to_yaw(odom.quat_world_body))
        return np.asarray(odom.pos_world_m, dtype=np.float64).copy(), np.zeros(3), yaw
