"""Cubic Bézier motion primitives (the planner's action set).

Our reading of the paper's action figure: 18 forward-biased primitives whose end displacement per
step, in the heading frame (x forward, y left, z up), is ``scale_m * (f, l, v)`` with
``f in {1, 0}``, ``l in {-1, 0, 1}``, ``v in {-1, 0, 1}``; scale 1 m in simulation, 0.5 m for real
flight; one primitive per step of ``duration_s`` (1 s).

Each primitive is a cubic Bézier curve in Bernstein form, ``C(u) = sum_i binom(3, i) P_i
(1-u)^(3-i) u^i`` with ``u = t / duration_s``. The control points make consecutive primitives join
with continuous position *and* velocity:

* ``P0 = 0`` (the primitive starts where the previous one ended),
* ``P1 = P0 + v0 * T / 3`` (start velocity = end velocity of the previous primitive),
* ``P3 = d`` (the end displacement of the chosen action),
* ``P2 = P3 - (d / T) * T / 3`` (end velocity = the primitive's mean velocity ``d / T``).

Displacements are relative; add the start position (and rotate with :mod:`quadnav_onboard.frames`)
to get world setpoints.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "DEFAULT_DIRECTIONS",
    "PrimitiveSet",
    "bezier_control_points",
    "bezier_position",
    "bezier_velocity",
]


def _default_directions() -> tuple[tuple[int, int, int], ...]:
    return tuple((f, lat, v) for f, lat, v in itertools.product((1, 0), (-1, 0, 1), (-1, 0, 1)))


DEFAULT_DIRECTIONS: tuple[tuple[int, int, int], ...] = _default_directions()
"""The 18 unit end displacements (forward, left, up); action index = position in this tuple."""


def bezier_control_points(
    end_disp_m: ArrayLike, start_vel_m_s: ArrayLike, duration_s: float
) -> NDArray[np.float64]:
    """Control points (m, relative to the start, shape (..., 4, 3)) of one primitive.

    ``end_disp_m``: end displacement, shape (..., 3). ``start_vel_m_s``: velocity at the start
    (the previous primitive's end velocity, same frame), shape (..., 3).
    """
    d = np.asarray(end_disp_m, dtype=np.float64)
    v0 = np.broadcast_to(np.asarray(start_vel_m_s, dtype=np.float64), d.shape)
    p0 = np.zeros_like(d)
    p1 = p0 + v0 * duration_s / 3.0
    p2 = d - d / 3.0
    return np.stack([p0, p1, p2, d], axis=-2)


def bezier_position(ctrl_m: ArrayLike, u: ArrayLike) -> NDArray[np.float64]:
    """Position on a cubic Bézier at normalised time ``u`` in [0, 1] (clipped).

    ``ctrl_m``: shape (..., 4, 3); ``u``: scalar or shape broadcastable to ``ctrl_m[..., 0, 0]``.
    Returns shape (..., 3).
    """
    p = np.asarray(ctrl_m, dtype=np.float64)
    uu = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)[..., None]
    a = 1.0 - uu
    return (
        a**3 * p[..., 0, :]
        + 3 * a**2 * uu * p[..., 1, :]
        + 3 * a * uu**2 * p[..., 2, :]
        + uu**3 * p[..., 3, :]
    )


def bezier_velocity(ctrl_m: ArrayLike, u: ArrayLike, duration_s: float) -> NDArray[np.float64]:
    """Time derivative (m/s) of the primitive at normalised time ``u``; shape (..., 3)."""
    p = np.asarray(ctrl_m, dtype=np.float64)
    uu = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)[..., None]
    a = 1.0 - uu
    d_du = 3 * (
        a**2 * (p[..., 1, :] - p[..., 0, :])
        + 2 * a * uu * (p[..., 2, :] - p[..., 1, :])
        + uu**2 * (p[..., 3, :] - p[..., 2, :])
    )
    return d_du / duration_s


@dataclass(frozen=True)
class PrimitiveSet:
    """The action set: unit directions (heading frame), a scale (m per axis) and a step time (s)."""

    directions: tuple[tuple[float, float, float], ...] = DEFAULT_DIRECTIONS
    scale_m: float = 1.0
    duration_s: float = 1.0

    def __post_init__(self) -> None:
        if len(self.directions) < 1:
            raise ValueError("a primitive set needs at least one direction")
        if any(len(d) != 3 for d in self.directions):
            raise ValueError("every primitive direction needs 3 components (forward, left, up)")
        if not self.scale_m > 0 or not self.duration_s > 0:
            raise ValueError("scale_m and duration_s must be > 0")

    @property
    def n_actions(self) -> int:
        return len(self.directions)

    def end_displacement_m(self, action: ArrayLike) -> NDArray[np.float64]:
        """End displacement (heading frame, m) of action index(es); shape (..., 3)."""
        a = np.asarray(action)
        if np.any((a < 0) | (a >= self.n_actions)):
            raise IndexError(f"action {a.tolist()} outside 0..{self.n_actions - 1}")
        return np.asarray(self.directions, dtype=np.float64)[a] * self.scale_m

    def end_velocity_m_s(self, action: ArrayLike) -> NDArray[np.float64]:
        """Velocity (heading frame, m/s) at the end of the primitive: its mean velocity."""
        return self.end_displacement_m(action) / self.duration_s

    def control_points(self, action: ArrayLike, start_vel_m_s: ArrayLike) -> NDArray[np.float64]:
        """Control points (heading frame, m, relative to the start), shape (..., 4, 3)."""
        return bezier_control_points(self.end_displacement_m(action), start_vel_m_s, self.duration_s)

    def sample(
        self, action: ArrayLike, start_vel_m_s: ArrayLike, t_s: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Displacement (m) and velocity (m/s) at time ``t_s`` into the step (heading frame)."""
        ctrl = self.control_points(action, start_vel_m_s)
        u = np.asarray(t_s, dtype=np.float64) / self.duration_s
        return bezier_position(ctrl, u), bezier_velocity(ctrl, u, self.duration_s)
