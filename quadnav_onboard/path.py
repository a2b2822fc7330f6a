"""The rough path to the goal and the moving setpoint that slides along it.

The paper gives the planner a *rough path* (here: a polyline of world-frame waypoints) and a
*moving setpoint* that advances along it at a nominal speed from the start of the mission. The
planner's position input is the vector from the quad to that setpoint, in the heading frame.

All positions are world frame (x forward, y left, z up), metres, shape (3,) or (N, 3).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav_onboard.frames import world_to_body

__all__ = ["RoughPath"]


@dataclass(frozen=True)
class RoughPath:
    """A polyline of waypoints (world frame, m, shape (K, 3), K >= 2) and a nominal speed (m/s)."""

    waypoints_m: NDArray[np.float64]
    speed_m_s: float = 1.0
    _seg_start_m: NDArray[np.float64] = field(init=False, repr=False)
    _seg_len_m: NDArray[np.float64] = field(init=False, repr=False)
    _seg_dir: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        wps = np.asarray(self.waypoints_m, dtype=np.float64)
        if wps.ndim != 2 or wps.shape[0] < 2 or wps.shape[1] != 3:
            raise ValueError(f"waypoints must have shape (K>=2, 3), got {wps.shape}")
        bad = np.flatnonzero(~np.all(np.isfinite(wps), axis=1))
        if bad.size:
            raise ValueError(f"waypoints must be finite: waypoint [{bad[0]}] is {wps[bad[0]].tolist()}")
        if not (np.isfinite(self.speed_m_s) and self.speed_m_s > 0):
            raise ValueError(f"speed_m_s must be > 0, got {self.speed_m_s}")
        seg = np.diff(wps, axis=0)
        seg_len = np.linalg.norm(seg, axis=1)
        same = np.flatnonzero(seg_len < 1e-6)
        if same.size:
            k = int(same[0])
            raise ValueError(
                f"consecutive waypoints must be distinct: [{k}] and [{k + 1}] are both {wps[k].tolist()}"
            )
        wps.setflags(write=False)
        object.__setattr__(self, "waypoints_m", wps)
        object.__setattr__(self, "_seg_len_m", seg_len)
        object.__setattr__(self, "_seg_dir", seg / seg_len[:, None])
        object.__setattr__(self, "_seg_start_m", np.concatenate([[0.0], np.cumsum(seg_len)[:-1]]))

    @classmethod
    def straight(cls, start_m: ArrayLike, goal_m: ArrayLike, speed_m_s: float = 1.0) -> RoughPath:
        """A one-segment path from ``start_m`` to ``goal_m``."""
        return cls(np.array([start_m, goal_m], dtype=np.float64), speed_m_s)

    @property
    def length_m(self) -> float:
        """Total arc length of the polyline (m)."""
        return float(self._seg_len_m.sum())

    @property
    def start_m(self) -> NDArray[np.float64]:
        return self.waypoints_m[0]

    @property
    def goal_m(self) -> NDArray[np.float64]:
        return self.waypoints_m[-1]

    @property
    def duration_s(self) -> float:
        """Time for the moving setpoint to reach the goal (s)."""
        return self.length_m / self.speed_m_s

    def point_at(self, arc_m: ArrayLike) -> NDArray[np.float64]:
        """World position (m) at arc length ``arc_m`` (clipped to [0, length]); shape (..., 3)."""
        s = np.clip(np.asarray(arc_m, dtype=np.float64), 0.0, self.length_m)
        idx = np.clip(np.searchsorted(self._seg_start_m, s, side="right") - 1, 0, len(self._seg_len_m) - 1)
        local = (s - self._seg_start_m[idx])[..., None]
        return self.waypoints_m[idx] + local * self._seg_dir[idx]

    def yaw_at(self, arc_m: ArrayLike) -> NDArray[np.float64]:
        """Path heading (rad, world yaw) of the segment at arc length ``arc_m``."""
        s = np.clip(np.asarray(arc_m, dtype=np.float64), 0.0, self.length_m)
        idx = np.clip(np.searchsorted(self._seg_start_m, s, side="right") - 1, 0, len(self._seg_len_m) - 1)
        d = self._seg_dir[idx]
        return np.arctan2(d[..., 1], d[..., 0])

    def heading_at(self, pos_world_m: ArrayLike) -> NDArray[np.float64]:
        """The heading frame's yaw for a quad at ``pos_world_m``: the path's heading at its progress
        (what the planner's body frame is, in training and in flight)."""
        return self.yaw_at(self.progress_m(pos_world_m))

    def setpoint_at(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """Moving setpoint (world, m) ``t_s`` seconds after the mission start; stops at the goal."""
        return self.point_at(np.maximum(np.asarray(t_s, dtype=np.float64), 0.0) * self.speed_m_s)

    def closest(self, pos_world_m: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Arc length (m) of the closest path point and the distance (m) to it.

        Works on shape (3,) or (N, 3); returns arrays of shape () or (N,).
        """
        p = np.asarray(pos_world_m, dtype=np.float64)
        rel = p[..., None, :] - self.waypoints_m[:-1]  # (..., S, 3)
        along = np.clip(np.einsum("...sk,sk->...s", rel, self._seg_dir), 0.0, self._seg_len_m)
        foot = self.waypoints_m[:-1] + along[..., None] * self._seg_dir
        dist = np.linalg.norm(p[..., None, :] - foot, axis=-1)
        best = np.argmin(dist, axis=-1)
        arc = np.take_along_axis(self._seg_start_m + along, best[..., None], axis=-1)[..., 0]
        dmin = np.take_along_axis(dist, best[..., None], axis=-1)[..., 0]
        return arc, dmin

    def progress_m(self, pos_world_m: ArrayLike) -> NDArray[np.float64]:
        """Navigation distance (m): arc length of the path point closest to the quad."""
        return self.closest(pos_world_m)[0]

    def deviation_m(self, pos_world_m: ArrayLike) -> NDArray[np.float64]:
        """Distance (m) from the quad to the closest point of the path (lateral + vertical)."""
        return self.closest(pos_world_m)[1]

    def relative_state(
        self, setpoint_world_m: ArrayLike, pos_world_m: ArrayLike, yaw_rad: ArrayLike
    ) -> NDArray[np.float64]:
        """The planner's position input: ``setpoint - quad`` rotated into the heading frame (m)."""
        rel = np.asarray(setpoint_world_m, dtype=np.float64) - np.asarray(pos_world_m, dtype=np.float64)
        return world_to_body(rel, yaw_rad)
