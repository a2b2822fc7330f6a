"""A PX4 SITL's own reported state as the sim's truth: what the camera and mocap render from.

When the vehicle is a PX4 SITL a user started (``make px4_sitl sihsim_quadx``), the sim has no
emulator to read the true state from. :class:`SitlBridge` takes it from PX4's MAVLink stream
instead: LOCAL_POSITION_NED (position, velocity), ATTITUDE_QUATERNION (attitude), HEARTBEAT
(armed, emergency) and EXTENDED_SYS_STATE (landed). Pure: messages in, a pose out.

Frames: the world's x/y are PX4's local north-east axes turned into x forward / y left (through
:mod:`quadnav_onboard.frames`), so the world's origin is PX4's local origin in x and y. The height
is anchored to the ground: while the vehicle is disarmed on the ground, the height PX4 reports is
the world floor (PX4 on GPS height reports the ground anywhere within +-0.4 m, drifting), so the
camera sees the floor where the vehicle really stands.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.frames import frd_to_flu, quat_world_to_ned
from sim_harness.px4.mavlink_io import mavlink2 as m

__all__ = ["BridgePose", "SitlBridge"]

_ON_GROUND = 1  # MAV_LANDED_STATE_ON_GROUND


@dataclass(frozen=True)
class BridgePose:
    """The vehicle's state as PX4 reports it, in the sim's world frame."""

    pos_world_m: NDArray[np.float64]
    """Position (m), shape (3,)."""
    vel_world_m_s: NDArray[np.float64]
    """Velocity (m/s), shape (3,)."""
    quat_world_body: NDArray[np.float64]
    """Attitude (w, x, y, z), body FLU -> world, shape (4,)."""
    t_mono_s: float
    """Arrival time of the newest position (monotonic s)."""


class SitlBridge:
    """Folds one autopilot's MAVLink messages into a world-frame pose (one thread only).

    ``collide(prev, new) -> bool``: the sim world's swept collision test (a crash is latched, as
    the emulator does); ``system_id``: take only this autopilot (None: the first heard).
    """

    def __init__(
        self,
        floor_z_m: float = 0.0,
        *,
        system_id: int | None = None,
        collide: Callable[[NDArray[np.float64], NDArray[np.float64]], bool] | None = None,
    ) -> None:
        self.floor_z_m = float(floor_z_m)
        self.system_id = system_id
        self._collide = collide
        self.ground_up_m: float | None = None
        """PX4's local height (up, m) of the ground, measured while disarmed on the ground."""
        self.armed = False
        self.landed = True
        self.crashed = False
        self._quat = np.array([1.0, 0.0, 0.0, 0.0])
        self._pose: BridgePose | None = None
        self.messages = 0

    @property
    def pose(self) -> BridgePose | None:
        """The newest pose; None until PX4 reported a position."""
        return self._pose

    def on_message(self, msg: Any, t_mono_s: float) -> bool:
        """Take one message; True when it moved the pose."""
        if msg.get_srcComponent() != m.MAV_COMP_ID_AUTOPILOT1:
            return False
        if self.system_id is None and msg.get_type() == "HEARTBEAT":
            self.system_id = msg.get_srcSystem()
        if msg.get_srcSystem() != self.system_id:
            return False
        self.messages += 1
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self.armed = bool(msg.base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED)
            if msg.system_status == m.MAV_STATE_EMERGENCY:
                self.crashed = True
        elif kind == "EXTENDED_SYS_STATE":
            self.landed = msg.landed_state == _ON_GROUND
        elif kind == "ATTITUDE_QUATERNION":
            q = np.array([msg.q1, msg.q2, msg.q3, msg.q4], dtype=np.float64)
            if np.all(np.isfinite(q)) and np.linalg.norm(q) > 0.5:
                self._quat = np.asarray(quat_world_to_ned(q / np.linalg.norm(q)))  # FRD/NED -> FLU/world
        elif kind == "LOCAL_POSITION_NED":
            return self._position(msg, t_mono_s)
        return False

    def _position(self, msg: Any, t: float) -> bool:
        ned = np.array([msg.x, msg.y, msg.z], dtype=np.float64)
        vel = np.array([msg.vx, msg.vy, msg.vz], dtype=np.float64)
        if not (np.all(np.isfinite(ned)) and np.all(np.isfinite(vel))):
            return False
        enu = np.asarray(frd_to_flu(ned), dtype=np.float64)
        if self.ground_up_m is None or (not self.armed and self.landed):
            self.ground_up_m = float(enu[2])
        pos = np.array([enu[0], enu[1], enu[2] - self.ground_up_m + self.floor_z_m])
        pos[2] = max(pos[2], self.floor_z_m)  # the estimate dips below the ground; the vehicle cannot
        prev = self._pose
        self._pose = BridgePose(pos, np.asarray(frd_to_flu(vel), dtype=np.float64), self._quat.copy(), t)
        if (
            self._collide is not None and prev is not None and not self.crashed
            and math.dist(prev.pos_world_m, pos) < 5.0  # a jump (a re-anchored estimate) is no sweep
            and self._collide(prev.pos_world_m, pos)
        ):
            self.crashed = True
        return True
