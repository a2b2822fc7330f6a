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
from typing import Annotated

import numpy as np
import pydantic
from numpy.typing import ArrayLike, NDArray

__all__ = ["RewardParams", "reward"]


_Reward = Annotated[float, pydantic.Field(ge=-10, le=10)]
"""A reward constant, in [-10, 10] (the paper's: [-1, 0.5]); 0 and negative values mean what they say."""
_DistanceChangeM = Annotated[float, pydantic.Field(ge=-10, le=10)]
"""A saturation bound (m) of the distance change over one step: in [-10, 10]."""


@dataclass(frozen=True)
class RewardParams:
    """Constants of the paper's reward; defaults are the paper's. The reward constants lie in
    [-10, 10], the distance-change bounds in [-10, 10] m (lower below upper), ``max_deviation_m`` in
    (0, 50] m and ``d_floor_m`` in (0, 5] m; a config file outside these is refused."""

    # config files: unknown keys are errors, and so are NaN and ±inf (quadnav_onboard.config.CONFIG_DICT)
    __pydantic_config__ = {"extra": "forbid", "allow_inf_nan": False}

    r_lower: _Reward = 0.0
    """R_l: shaping reward at or beyond the upper saturation bound of Δd."""
    r_upper: _Reward = 0.5
    """R_u: shaping reward at or beyond the lower saturation bound of Δd."""
    dd_lower_m: _DistanceChangeM = -1.0
    """Δd_l (m): lower saturation bound of the distance change."""
    dd_upper_m: _DistanceChangeM = 1.0
    """Δd_u (m): upper saturation bound of the distance change."""
    deviation_penalty: _Reward = -0.5
    """R_dp: reward when the quad is farther than ``max_deviation_m`` from the path."""
    collision_penalty: _Reward = -1.0
    """R_cp: reward on collision."""
    max_deviation_m: Annotated[float, pydantic.Field(gt=0, le=50)] = 5.0
    """Deviation (m) from the rough path past which the episode ends with R_dp."""
    d_floor_m: Annotated[float, pydantic.Field(gt=0, le=5)] = 0.25
    """Floor (m) on d_t so the shaping reward stays finite as the quad meets the setpoint."""

    def __post_init__(self) -> None:
        if not self.dd_lower_m < self.dd_upper_m:
            raise ValueError(f"dd_lower_m {self.dd_lower_m!r} must be < dd_upper_m {self.dd_upper_m!r}")
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
