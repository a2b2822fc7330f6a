"""The daemon's world frame: z = 0 is the ground the vehicle stood on, not the estimator's origin.

PX4 on GPS height (``EKF2_HGT_REF=1``) reports the vehicle on the ground anywhere from -0.38 to
+0.33 m (11 SITL starts; up to 0.9 m after a landing). The altitude band, the geofence, the path and
the safety filter's known floor are all heights above the ground, so the daemon flies in a frame
whose z = 0 is the ground: odometry is shifted into it on arrival, setpoints out of it into PX4's
local frame before they are sent. Pure: the offsets are measured by the caller.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.sources.base import OdometrySample

__all__ = ["GroundFrame", "measure_ground"]


def _zeros() -> NDArray[np.float64]:
    return np.zeros(3)


@dataclass(frozen=True)
class GroundFrame:
    """Offsets between the odometry's frame, the daemon's ground frame and PX4's local frame."""

    ground_in_odometry_m: NDArray[np.float64] = field(default_factory=_zeros)
    """Where the ground frame's origin lies in the odometry source's frame (m), shape (3,): only
    z is ever non-zero (the ground's height)."""
    px4_minus_world_m: NDArray[np.float64] = field(default_factory=_zeros)
    """PX4's local position minus the ground-frame position of the same vehicle (m), shape (3,)."""
    source: str = "identity"
    """How it was found: identity (before take-off), takeoff, configured."""

    @property
    def ground_z_m(self) -> float:
        """Height of the ground in the odometry source's frame (m)."""
        return float(self.ground_in_odometry_m[2])

    def to_world(self, s: OdometrySample) -> OdometrySample:
        """An odometry sample in the ground frame."""
        if not np.any(self.ground_in_odometry_m):
            return s
        return replace(s, pos_world_m=np.asarray(s.pos_world_m, dtype=np.float64) - self.ground_in_odometry_m)

    def to_px4(self, pos_world_m: NDArray[np.float64]) -> NDArray[np.float64]:
        """A ground-frame position (a setpoint) in PX4's local frame (world axes, m)."""
        return np.asarray(pos_world_m, dtype=np.float64) + self.px4_minus_world_m

    def describe(self) -> dict[str, object]:
        return {
            "source": self.source,
            "ground_z_m": round(self.ground_z_m, 3),
            "px4_minus_world_m": np.round(self.px4_minus_world_m, 3).tolist(),
        }


def measure_ground(
    odometry_pos_m: NDArray[np.float64],
    px4_pos_m: NDArray[np.float64] | None,
    *,
    configured_z_m: float | None = None,
) -> GroundFrame:
    """The ground frame from one instant on the ground: the odometry's position (its own frame)
    and PX4's local position then (None when the odometry is PX4's own estimate: the same frame).
    ``configured_z_m``: the ground's height is configured, not the vehicle's height now."""
    odo = np.asarray(odometry_pos_m, dtype=np.float64)
    z = float(odo[2]) if configured_z_m is None else float(configured_z_m)
    ground = np.array([0.0, 0.0, z])
    world = odo - ground
    px4 = odo if px4_pos_m is None else np.asarray(px4_pos_m, dtype=np.float64)
    return GroundFrame(ground, px4 - world, "takeoff" if configured_z_m is None else "configured")
