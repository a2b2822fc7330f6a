"""The paper's reward (Camci & Kayacan, eq. 3).

With ``Δd = d_t - d_{t-1}`` the change over one step of the distance between the moving setpoint
and the quad (negative = the quad closed in), and ``d_t`` that distance at the end of the step::

    R = R_l / d_t                                          if Δd_u < Δd
    R = (R_l + (R_u - R_l) (Δd_u - Δd) / (Δd_u - Δd_l)) / d_t   if Δd_l <= Δd <= Δd_u
    R = R_u / d_t                                          if Δd < Δd_l
    R = R_dp   on excessive deviation (> 5 m from the rough path)
    R = R_cp   on collision (takes precedence over deviation)

``d_t`` is floored at ``d_floor_m`` (default 0.25 m, about the quad's radius): the paper leaves
``d_t -> 0`` undefined, and the floor caps one step's reward at ``R_u / d_floor_m`` = 2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["RewardParams", "reward"]


@dataclass(frozen=True)
class RewardParams:
    """Constants of the paper's reward; defaults are the paper's."""

    __pydantic_config__ = {"extra": "forbid"}  # config files: unknown keys are errors

    r_lower: float = 0.0
    """R_l: shaping reward at or beyond the upper saturation bound of Δd."""
    r_upper: float = 0.5
    """R_u: shaping reward at or beyond the lower saturation bound of Δd."""
    dd_lower_m: float = -1.0
    """Δd_l (m): lower saturation bound of the distance change."""
    dd_upper_m: float = 1.0
    """Δd_u (m): upper saturation bound of the distance change."""
    deviation_penalty: float = -0.5
    """R_dp: reward when the quad is farther than ``max_deviation_m`` from the path."""
    collision_penalty: float = -1.0
    """R_cp: reward on collision."""
    max_deviation_m: float = 5.0
    """Deviation (m) from the rough path past which the episode ends with R_dp."""
    d_floor_m: float = 0.25
    """Floor (m) on d_t so the shaping reward stays finite as the quad meets the setpoint."""

    def __post_init__(self) -> None:
        if not self.dd_lower_m < self.dd_upper_m:
            raise ValueError("dd_lower_m must be < dd_upper_m")
        if not self.d_floor_m > 0 or not self.max_deviation_m > 0:
            raise ValueError("d_floor_m and max_deviation_m must be > 0")


def reward(
    d_prev_m: ArrayLike,
    d_now_m: ArrayLike,
    deviated: ArrayLike,
    collided: ArrayLike,
    params: RewardParams = RewardParams(),
) -> NDArray[np.float64]:
    """Reward for one step, elementwise over arrays.

    ``d_prev_m``/``d_now_m``: setpoint-to-quad distance (m) at the start/end of the step;
    ``deviated``: deviation past the limit at the end of the step; ``collided``: a collision
    happened during the step.
    """
    p = params
    d_prev = np.asarray(d_prev_m, dtype=np.float64)
    d_now = np.asarray(d_now_m, dtype=np.float64)
    dd = d_now - d_prev
    frac = np.clip((p.dd_upper_m - dd) / (p.dd_upper_m - p.dd_lower_m), 0.0, 1.0)
    shaped = (p.r_lower + (p.r_upper - p.r_lower) * frac) / np.maximum(d_now, p.d_floor_m)
    out = np.where(np.asarray(deviated, dtype=bool), p.deviation_penalty, shaped)
    return np.where(np.asarray(collided, dtype=bool), p.collision_penalty, out)
