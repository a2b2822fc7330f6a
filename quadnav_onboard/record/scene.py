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
import struct
import threading
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
from quadnav_onboard.record.decode import ProtobufSchema

__all__ = [
    "CURVE_POINTS",
    "encode_geofence",
    "encode_primitives",
    "encode_rough_path",
    "encode_world",
    "primitive_curves_world_m",
]

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
_SETPOINT_SIZE = Vector3(x=0.3, y=0.3, z=0.3)
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


def _varint(n: int) -> bytes:
    out = bytearray()
    while n > 0x7F:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _len_field(number: int, payload_len: int) -> bytes:
    """The key and length of a length-delimited protobuf field (wire type 2)."""
    return _varint(number << 3 | 2) + _varint(payload_len)


_FIELD_NUMBERS = ProtobufSchema(SceneUpdate.get_schema().data).numbers
"""Field numbers of Foxglove's scene messages, read from the SDK's own schema."""
_ENTITIES = _FIELD_NUMBERS["foxglove.SceneUpdate"]["entities"]
_LINES = _FIELD_NUMBERS["foxglove.SceneEntity"]["lines"]
_POINTS = _FIELD_NUMBERS["foxglove.LinePrimitive"]["points"]
_XYZ = [_FIELD_NUMBERS["foxglove.Point3"][k] for k in "xyz"]
_POINT_DTYPE = np.dtype([
    ("key", "u1"), ("len", "u1"),
    ("kx", "u1"), ("x", "<f8"), ("ky", "u1"), ("y", "<f8"), ("kz", "u1"), ("z", "<f8"),
])
"""One ``points`` entry of a LinePrimitive as protobuf puts it on the wire: the field's key and
length, then a Point3's three doubles, each after its key (29 bytes, no padding)."""


class _PrimitiveScene:
    """The fixed parts of one primitive set's ``/planner/primitives`` lines, computed once.

    A primitive's curve from start ``s`` with start velocity ``v`` (world) in the heading frame of
    yaw ``psi`` is ``s + w(u) v + R(psi) e(u)`` (:class:`PrimitiveSet.control_points`: p0 = 0,
    p1 = v T / 3, p2 = 2 d / 3, p3 = d; ``w(u) = 3 (1 - u)^2 u T / 3``, ``e(u) = (2 b2(u) / 3 +
    b3(u)) d``). ``e`` and ``w`` are fixed per set; per step only ``s``, ``v``, ``psi``, the chosen
    primitive and the filter's verdict change. So the lines are one buffer in protobuf's wire
    layout, laid out once: per primitive (in action order) its LinePrimitive's key, length and
    fixed fields (encoded by the SDK; allowed, vetoed and chosen are the same size), then its
    points (:data:`_POINT_DTYPE`); a step writes every point's x, y, z and each line's header into
    their places."""

    def __init__(self, prims: PrimitiveSet, n_points: int) -> None:
        u = np.linspace(0.0, 1.0, n_points)
        b1, b2, b3 = 3 * (1 - u) ** 2 * u, 3 * (1 - u) * u**2, u**3
        ends = prims.end_displacement_m(np.arange(prims.n_actions))  # (A, 3) heading frame
        end_term = (2 * b2 / 3 + b3)[None, :, None] * ends[:, None, :]  # (A, n, 3)
        n_act = self.n_actions = prims.n_actions
        n_all = n_act * n_points
        # a point is [R | s | v] @ [e; 1; w]: one matrix product per step gives every curve
        self._basis = np.vstack([
            np.moveaxis(end_term, -1, 0).reshape(3, n_all), np.ones((1, n_all)),
            np.tile(b1 * prims.duration_s / 3, n_act)[None, :],
        ])
        points_len = n_points * _POINT_DTYPE.itemsize

        def head(color: Color, thickness: float) -> bytes:
            fixed = LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=thickness,
                                  scale_invariant=True, color=color).encode()
            return _len_field(_LINES, len(fixed) + points_len) + fixed

        heads = [head(_ALLOWED, 1.5), head(_VETOED, 1.5), head(_CHOSEN, 4.0)]
        if len({len(h) for h in heads}) != 1:
            raise ValueError("the allowed, vetoed and chosen lines' fixed fields differ in size")
        self._heads = np.frombuffer(b"".join(heads), dtype=np.uint8).reshape(3, -1)  # ALLOWED, VETOED, CHOSEN
        line_dtype = np.dtype([("head", np.uint8, (len(heads[0]),)), ("pts", _POINT_DTYPE, (n_points,))])
        template = np.zeros(n_act, dtype=line_dtype)
        template["pts"]["key"] = _POINTS << 3 | 2
        template["pts"]["len"] = _POINT_DTYPE.itemsize - 2
        for name, num in zip(("kx", "ky", "kz"), _XYZ, strict=True):
            template["pts"][name] = num << 3 | 1
        self._buf = bytearray(template.tobytes())
        # views into the buffer: each line's header; x, y, z of every point (unaligned doubles)
        self._head_view = np.ndarray((n_act, len(heads[0])), dtype=np.uint8, buffer=self._buf,
                                     strides=(line_dtype.itemsize, 1))
        x_at = line_dtype.fields["pts"][1] + _POINT_DTYPE.fields["x"][1]
        self._xyz = np.ndarray((3, n_act, n_points), dtype="<f8", buffer=self._buf, offset=x_at,
                               strides=(9, line_dtype.itemsize, _POINT_DTYPE.itemsize))
        self._tmp = np.empty((3, n_all))
        self._heads_of: dict[tuple[int, bytes | None], np.ndarray] = {}
        self._lock = threading.Lock()

    def lines(
        self, start_world_m: ArrayLike, start_vel_world_m_s: ArrayLike, yaw_rad: float, chosen: int,
        allowed: ArrayLike | None,
    ) -> bytes:
        """Every primitive's LinePrimitive (entity field ``lines``), in action order, as bytes."""
        sx, sy, sz = _floats3(start_world_m)
        vx, vy, vz = _floats3(start_vel_world_m_s)
        c, s = math.cos(yaw_rad), math.sin(yaw_rad)
        m = np.array([[c, -s, 0.0, sx, vx], [s, c, 0.0, sy, vy], [0.0, 0.0, 1.0, sz, vz]])
        if not 0 <= chosen < self.n_actions:
            raise ValueError(f"action {chosen} does not fit {self.n_actions} primitives")
        key = (chosen, None if allowed is None else np.asarray(allowed, dtype=bool).tobytes())
        heads = self._heads_of.get(key)
        if heads is None:
            heads = self._line_heads(chosen, allowed)
            if len(self._heads_of) < 256:  # a flight's verdicts repeat: most steps allow all
                self._heads_of[key] = heads
        with self._lock:
            np.matmul(m, self._basis, out=self._tmp)
            self._xyz[...] = self._tmp.reshape(self._xyz.shape)
            self._head_view[...] = heads
            return bytes(self._buf)

    def _line_heads(self, chosen: int, allowed: ArrayLike | None) -> np.ndarray:
        """Each line's header (allowed, vetoed or chosen), (A, H) bytes."""
        if allowed is None:
            style = np.zeros(self.n_actions, dtype=np.intp)
        else:
            ok = np.asarray(allowed, dtype=bool).reshape(-1)
            if ok.shape != (self.n_actions,):
                raise ValueError(f"filter verdict of {ok.size} does not fit {self.n_actions} primitives")
            style = (~ok).astype(np.intp)
        style[chosen] = 2
        return self._heads[style]


def _floats3(v: ArrayLike) -> list[float]:
    """Three floats from a (3,) array or sequence (ValueError otherwise)."""
    a = v if isinstance(v, np.ndarray) and v.dtype == np.float64 else np.asarray(v, dtype=np.float64)
    if a.size != 3:
        raise ValueError(f"expected 3 values, got shape {a.shape}")
    return a.ravel().tolist()


@functools.lru_cache(maxsize=8)
def _scene_of(prims: PrimitiveSet, n_points: int) -> _PrimitiveScene:
    return _PrimitiveScene(prims, n_points)


def primitive_curves_world_m(
    prims: PrimitiveSet, start_world_m: ArrayLike, start_vel_world_m_s: ArrayLike, yaw_rad: float,
    n_points: int = CURVE_POINTS,
) -> np.ndarray:
    """Every primitive's curve (world, m), shape (n_actions, n_points, 3), from the commanded
    start with the start velocity, in the heading frame of ``yaw_rad`` (as the daemon flies it:
    :class:`~quadnav_onboard.daemon.mission.ActivePrimitive`), as the scene draws them."""
    sc = _scene_of(prims, n_points)
    sc.lines(start_world_m, start_vel_world_m_s, float(yaw_rad), 0, None)
    with sc._lock:
        return np.moveaxis(sc._xyz, 0, -1).copy()


_N = _FIELD_NUMBERS
_STAMP_HEAD = _varint(_N["foxglove.SceneEntity"]["timestamp"] << 3 | 2)
_STAMP_KEYS = tuple(_varint(_N["google.protobuf.Timestamp"][k] << 3) for k in ("seconds", "nanos"))
_ENTITY_IDS = SceneEntity(frame_id="world", id="primitives").encode()
_VEC3 = struct.Struct("<BBBdBdBd")
_VEC3_KEYS = (
    _N["foxglove.Pose"]["position"] << 3 | 2,
    _VEC3.size - 2,
    *(_N["foxglove.Vector3"][k] << 3 | 1 for k in "xyz"),
)
_ORIENT = _IDENTITY.encode()
_ORIENT_FIELD = _len_field(_N["foxglove.Pose"]["orientation"], len(_ORIENT)) + _ORIENT
_SPHERE_REST = SpherePrimitive(size=_SETPOINT_SIZE, color=_SETPOINT).encode()
_POSE_LEN = _VEC3.size + len(_ORIENT_FIELD)
_SPHERE_LEN = len(_len_field(1, _POSE_LEN)) + _POSE_LEN + len(_SPHERE_REST)
_SPHERE_HEAD = (
    _len_field(_N["foxglove.SceneEntity"]["spheres"], _SPHERE_LEN)
    + _len_field(_N["foxglove.SpherePrimitive"]["pose"], _POSE_LEN)
)
"""The moving setpoint's sphere: its pose (position written per step) before its size and color."""


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
    """One step's primitives as entity ``primitives`` (see the module's docstring): the same
    message the SDK would encode from LinePrimitives of Point3s, built without either."""
    lines = _scene_of(prims, CURVE_POINTS).lines(
        start_world_m, start_vel_world_m_s, float(yaw_rad), int(action), allowed
    )
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    stamp = _STAMP_KEYS[0] + _varint(sec) + _STAMP_KEYS[1] + _varint(nsec)
    x, y, z = _floats3(moving_setpoint_world_m)
    position = _VEC3.pack(*_VEC3_KEYS[:3], x, _VEC3_KEYS[3], y, _VEC3_KEYS[4], z)
    entity = b"".join([
        _STAMP_HEAD, _varint(len(stamp)), stamp, _ENTITY_IDS,
        _SPHERE_HEAD, position, _ORIENT_FIELD, _SPHERE_REST, lines,
    ])  # fields in number order: timestamp, frame_id, id, spheres, lines
    return _len_field(_ENTITIES, len(entity)) + entity
