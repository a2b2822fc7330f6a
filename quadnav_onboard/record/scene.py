"""The record's 3-D scene: the world's obstacles, the mission and each step's primitives, as
foxglove.SceneUpdate messages (protobuf, Foxglove's SDK) in the ``world`` frame.

- ``/scene/world``: boxes, spheres and cylinders of a world (the sim harness's world-file
  mapping, see ``sim_harness.world``), the floor and the ceiling; written once (dry runs).
- ``/scene/mission``: entity ``rough_path`` (the path's line) and ``geofence`` (its box's edges).
- ``/planner/primitives``: entity ``primitives``, replaced at every step: every primitive's curve
  from the step's commanded start (green: the filter allowed it or the filter is off; red: it
  vetoed it), the chosen one thick and white, and the moving setpoint as a sphere.

Pure: builders take values and return the message's bytes.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from foxglove.messages import (
    Color,
    CubePrimitive,
    CylinderPrimitive,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)
from numpy.typing import ArrayLike

from quadnav_onboard.primitives import PrimitiveSet

__all__ = ["CURVE_POINTS", "encode_geofence", "encode_primitives", "encode_rough_path", "encode_world"]

CURVE_POINTS = 6
"""Points drawn along each primitive's curve (start and end included)."""

_OBSTACLE = Color(r=0.55, g=0.55, b=0.6, a=0.85)
_BOUND = Color(r=0.4, g=0.3, b=0.2, a=0.25)
_PATH = Color(r=1.0, g=0.6, b=0.1, a=1.0)
_FENCE = Color(r=1.0, g=0.2, b=0.2, a=0.8)
_ALLOWED = Color(r=0.2, g=0.85, b=0.3, a=0.7)
_VETOED = Color(r=0.95, g=0.15, b=0.15, a=0.7)
_CHOSEN = Color(r=1.0, g=1.0, b=1.0, a=1.0)
_SETPOINT = Color(r=1.0, g=0.6, b=0.1, a=0.9)
_IDENTITY = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
_S = math.sqrt(0.5)
_AXIS_Q = {  # rotation taking a cylinder's local z (Foxglove's cylinder axis) onto the world axis
    "z": _IDENTITY,
    "x": Quaternion(x=0.0, y=_S, z=0.0, w=_S),
    "y": Quaternion(x=-_S, y=0.0, z=0.0, w=_S),
}
_FLOOR_MARGIN_M = 5.0


def _stamp(t_ns: int) -> Timestamp:
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    return Timestamp(sec=sec, nsec=nsec)


def _v3(v: Sequence[float] | np.ndarray) -> Vector3:
    x, y, z = (float(c) for c in v)
    return Vector3(x=x, y=y, z=z)


def _pose(center: Sequence[float] | np.ndarray, q: Quaternion = _IDENTITY) -> Pose:
    return Pose(position=_v3(center), orientation=q)


def _points(pts: np.ndarray) -> list[Point3]:
    return [Point3(x=x, y=y, z=z) for x, y, z in pts.tolist()]


def _update(t_ns: int, entity_id: str, **prims: Any) -> bytes:
    entity = SceneEntity(timestamp=_stamp(t_ns), frame_id="world", id=entity_id, **prims)
    return SceneUpdate(entities=[entity]).encode()


def encode_world(t_ns: int, world: Mapping[str, Any]) -> bytes:
    """A world-file mapping's obstacles, floor and ceiling as entity ``world``; an obstacle of an
    unknown type is an error (ValueError)."""
    cubes, spheres, cylinders = [], [], []
    for i, ob in enumerate(world.get("obstacles") or []):
        kind = ob.get("type")
        c = ob["center"]
        if kind == "box":
            yaw = math.radians(float(ob.get("yaw_deg", 0.0)))
            q = Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
            cubes.append(CubePrimitive(pose=_pose(c, q), size=_v3(ob["size"]), color=_OBSTACLE))
        elif kind == "sphere":
            d = 2.0 * float(ob["radius"])
            spheres.append(SpherePrimitive(pose=_pose(c), size=_v3((d, d, d)), color=_OBSTACLE))
        elif kind == "cylinder":
            d, h = 2.0 * float(ob["radius"]), float(ob["height"])
            cylinders.append(CylinderPrimitive(
                pose=_pose(c, _AXIS_Q[str(ob.get("axis", "z"))]), size=_v3((d, d, h)),
                bottom_scale=1.0, top_scale=1.0, color=_OBSTACLE,
            ))
        else:
            raise ValueError(f"obstacles[{i}]: unknown type {kind!r}")
    wps = np.asarray((world.get("path") or {}).get("waypoints") or [[0.0, 0.0, 0.0]], dtype=np.float64)
    lo, hi = wps.min(axis=0) - _FLOOR_MARGIN_M, wps.max(axis=0) + _FLOOR_MARGIN_M
    mid, span = (lo + hi) / 2, hi - lo
    bounds = world.get("bounds") or {}
    for key in ("floor_z", "ceiling_z"):
        if bounds.get(key) is not None:
            z = float(bounds[key])
            cubes.append(CubePrimitive(pose=_pose((mid[0], mid[1], z)), size=_v3((span[0], span[1], 0.02)),
                                       color=_BOUND))
    return _update(t_ns, "world", cubes=cubes, spheres=spheres, cylinders=cylinders)


def encode_rough_path(t_ns: int, waypoints_m: ArrayLike) -> bytes:
    """The rough path (world, m, (K, 3)) as the line of entity ``rough_path``."""
    wps = np.asarray(waypoints_m, dtype=np.float64).reshape(-1, 3)
    line = LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=3.0, scale_invariant=True,
                         points=_points(wps), color=_PATH)
    return _update(t_ns, "rough_path", lines=[line])


def encode_geofence(t_ns: int, min_m: ArrayLike, max_m: ArrayLike) -> bytes:
    """The geofence (world box, m) as the 12 edges of entity ``geofence``."""
    lo, hi = np.asarray(min_m, dtype=np.float64).reshape(3), np.asarray(max_m, dtype=np.float64).reshape(3)
    if not np.all(lo < hi):
        raise ValueError(f"geofence min {lo.tolist()} must be below max {hi.tolist()} on every axis")
    corners = np.array([[(lo, hi)[i >> b & 1][b] for b in range(3)] for i in range(8)])
    edges = [(i, i | 1 << b) for i in range(8) for b in range(3) if not i >> b & 1]
    pts = np.array([corners[k] for e in edges for k in e])
    line = LinePrimitive(type=LinePrimitiveLineType.LineList, thickness=2.0, scale_invariant=True,
                         points=_points(pts), color=_FENCE)
    return _update(t_ns, "geofence", lines=[line])


@functools.lru_cache(maxsize=8)
def _curve_terms(prims: PrimitiveSet, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """The parts of every primitive's curve that do not depend on the start: the end-point term
    (A, n, 3, heading frame, m) and the start velocity's weight (n, 1) times the step time / 3."""
    # PrimitiveSet.control_points: p0 = 0, p1 = v0 T / 3, p2 = 2 d / 3, p3 = d, so a point at u is
    # b1(u) v0 T / 3 + (2 b2(u) / 3 + b3(u)) d
    u = np.linspace(0.0, 1.0, n_points)
    b1, b2, b3 = 3 * (1 - u) ** 2 * u, 3 * (1 - u) * u**2, u**3
    ends = prims.end_displacement_m(np.arange(prims.n_actions))
    end_term = (2 * b2 / 3 + b3)[None, :, None] * ends[:, None, :]
    return end_term, (b1 * prims.duration_s / 3)[:, None]


def primitive_curves_world_m(
    prims: PrimitiveSet, start_world_m: ArrayLike, start_vel_world_m_s: ArrayLike, yaw_rad: float,
    n_points: int = CURVE_POINTS,
) -> np.ndarray:
    """Every primitive's curve (world, m), shape (n_actions, n_points, 3), from the commanded
    start with the start velocity, in the heading frame of ``yaw_rad`` (as the daemon flies it:
    :class:`~quadnav_onboard.daemon.mission.ActivePrimitive`)."""
    end_term, vel_weight = _curve_terms(prims, n_points)
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    vx, vy, vz = np.asarray(start_vel_world_m_s, dtype=np.float64).reshape(3).tolist()
    v0_heading = np.array([c * vx + s * vy, -s * vx + c * vy, vz])
    rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # row vectors: heading -> world
    disp = end_term + vel_weight * v0_heading
    return np.asarray(start_world_m, dtype=np.float64) + disp @ rot


def encode_primitives(
    t_ns: int,
    prims: PrimitiveSet,
    *,
    start_world_m: ArrayLike,
    start_vel_world_m_s: ArrayLike,
    yaw_rad: float,
    action: int,
    allowed: ArrayLike | None,
    moving_setpoint_world_m: ArrayLike,
) -> bytes:
    """One step's primitives as entity ``primitives`` (see the module's docstring)."""
    curves = primitive_curves_world_m(prims, start_world_m, start_vel_world_m_s, yaw_rad)
    ok = np.ones(prims.n_actions, dtype=bool) if allowed is None else np.asarray(allowed, dtype=bool)
    if ok.shape != (prims.n_actions,) or not 0 <= int(action) < prims.n_actions:
        raise ValueError(
            f"action {action} or filter verdict {ok.shape} does not fit {prims.n_actions} primitives"
        )
    points = [[Point3(x=x, y=y, z=z) for x, y, z in curve] for curve in curves.tolist()]
    chosen = int(action)
    lines = [
        LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=1.5, scale_invariant=True,
                      points=pts, color=_ALLOWED if good else _VETOED)
        for i, (pts, good) in enumerate(zip(points, ok.tolist(), strict=True))
        if i != chosen
    ]
    lines.append(LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=4.0, scale_invariant=True,
                               points=points[chosen], color=_CHOSEN))
    sp = SpherePrimitive(pose=_pose(np.asarray(moving_setpoint_world_m, dtype=np.float64).reshape(3)),
                         size=_v3((0.3, 0.3, 0.3)), color=_SETPOINT)
    return _update(t_ns, "primitives", lines=lines, spheres=[sp])
