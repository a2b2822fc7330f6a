"""What a flight record holds: topics, JSON schemas and the pure encoders of each message.

A record is one MCAP file per flight, JSON message encoding. Where a Foxglove well-known schema
fits (raw images, poses, logs) it is used by name, so Foxglove shows the record without plugins;
extra fields beyond the Foxglove schema (e.g. the decision step of a network input) are allowed by
JSON and ignored by Foxglove. quadnav's own messages (decisions, setpoints, vehicle state, the
stop) have ``quadnav.*`` JSON schemas.

Frames: ``world`` is the world frame (x forward, y left, z up, m); ``heading`` is the path-yaw
frame the planner sees. Timestamps are ``time.monotonic()`` of the recording process, written as
MCAP log times in ns and as Foxglove ``{sec, nsec}``; metadata ``recorder.unix_minus_mono_s``
converts them to wall-clock time.

Everything here is pure: encoders take values and return JSON-ready dicts.
"""

from __future__ import annotations

import base64
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "SCHEMAS",
    "TOPICS",
    "decode_image",
    "encode_depth",
    "encode_event",
    "encode_moving_setpoint",
    "encode_network_input",
    "encode_odometry",
    "encode_path",
    "encode_setpoint",
    "encode_step",
    "encode_stop",
    "encode_vehicle",
    "from_ns",
    "to_jsonable",
    "to_ns",
]

FORMAT = "quadnav-flight-record"
"""Value of metadata ``recorder.format``: how :mod:`reader` tells our records from other MCAPs."""
FORMAT_VERSION = 1
"""Bumped on an incompatible change of a topic's content."""

_TIME = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    },
}
_VEC3 = {
    "type": "object",
    "properties": {"x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}},
}
_QUAT = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in ("x", "y", "z", "w")},
}
_POSE = {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}}


def _obj(title: str, description: str, **props: Any) -> dict[str, Any]:
    return {"title": title, "description": description, "type": "object", "properties": props}


SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.RawImage": _obj(
        "foxglove.RawImage",
        "A raw image (16UC1 depth in mm, or 32FC1 network input in [0, 1])",
        timestamp=_TIME,
        frame_id={"type": "string"},
        width={"type": "integer", "minimum": 0},
        height={"type": "integer", "minimum": 0},
        encoding={"type": "string"},
        step={"type": "integer", "minimum": 0, "description": "bytes per row"},
        data={"type": "string", "contentEncoding": "base64"},
        decision_step={"type": "integer", "description": "quadnav: planner step of a network input"},
    ),
    "foxglove.PoseInFrame": _obj(
        "foxglove.PoseInFrame",
        "A timestamped pose in a frame (quadnav adds velocity/yaw fields where known)",
        timestamp=_TIME,
        frame_id={"type": "string"},
        pose=_POSE,
        vel_world_m_s=_VEC3,
        yaw_rad={"type": "number"},
    ),
    "foxglove.PosesInFrame": _obj(
        "foxglove.PosesInFrame",
        "An array of poses in a frame (the rough path's waypoints)",
        timestamp=_TIME,
        frame_id={"type": "string"},
        poses={"type": "array", "items": _POSE},
    ),
    "foxglove.Log": _obj(
        "foxglove.Log",
        "A log message (quadnav: supervisor and daemon events; `kind` and `fields` added)",
        timestamp=_TIME,
        level={"type": "integer", "minimum": 0, "maximum": 5},
        message={"type": "string"},
        name={"type": "string"},
        file={"type": "string"},
        line={"type": "integer", "minimum": 0},
        kind={"type": "string"},
        fields={"type": "object"},
    ),
    "quadnav.Step": _obj(
        "quadnav.Step",
        "One planner decision: what it chose, from which Q-values, and how the step went",
        timestamp=_TIME,
        step={"type": "integer", "minimum": 0},
        action={"type": "integer", "minimum": 0},
        q_values={"type": "array", "items": {"type": "number"}},
        rel_pos_body_m={**_VEC3, "description": "setpoint - quad in the heading frame (m)"},
        moving_setpoint_world_m=_VEC3,
        pos_world_m=_VEC3,
        reward={"type": "number"},
        reward_terms={"type": "object"},
        progress_m={"type": "number", "description": "arc length of the closest path point (m)"},
        deviation_m={"type": "number", "description": "distance to the rough path (m)"},
        latency_ms={"type": "number", "description": "depth capture to setpoint sent (ms)"},
        shield_allowed={
            "type": "array",
            "items": {"type": "boolean"},
            "description": "primitives the depth safety filter allowed (absent when it is off)",
        },
        shield_clearance_m={
            "type": "array",
            "items": {"type": "number"},
            "description": "the filter's clearance (m) of every primitive (absent when it is off)",
        },
    ),
    "quadnav.Setpoint": _obj(
        "quadnav.Setpoint",
        "A commanded position setpoint sent to the autopilot (world frame)",
        timestamp=_TIME,
        pos_world_m=_VEC3,
        vel_world_m_s=_VEC3,
        yaw_rad={"type": "number"},
    ),
    "quadnav.Vehicle": _obj(
        "quadnav.Vehicle",
        "Autopilot state: armed, flight mode and health flags",
        timestamp=_TIME,
        armed={"type": "boolean"},
        mode={"type": "string"},
        health={"type": "object"},
    ),
    "quadnav.Stop": _obj(
        "quadnav.Stop",
        "Why the flight stopped, the flight summary, and the recorder's drop counts",
        timestamp=_TIME,
        stop_reason={"type": "string"},
        summary={"type": "object"},
        dropped={"type": "object"},
    ),
}

TOPICS: dict[str, str] = {
    "/camera/depth": "foxglove.RawImage",
    "/planner/input": "foxglove.RawImage",
    "/odometry": "foxglove.PoseInFrame",
    "/setpoint": "quadnav.Setpoint",
    "/setpoint/pose": "foxglove.PoseInFrame",
    "/planner/moving_setpoint": "foxglove.PoseInFrame",
    "/planner/path": "foxglove.PosesInFrame",
    "/planner/step": "quadnav.Step",
    "/vehicle": "quadnav.Vehicle",
    "/events": "foxglove.Log",
    "/flight/stop": "quadnav.Stop",
}
"""Topic -> schema name. Every record registers all of them, in this order."""

_LEVELS = {"debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}


def to_ns(t_mono_s: float) -> int:
    """Monotonic seconds -> integer ns (MCAP log time); negative or non-finite times are errors."""
    if not math.isfinite(t_mono_s) or t_mono_s < 0:
        raise ValueError(f"t_mono_s must be finite and >= 0, got {t_mono_s!r}")
    return round(t_mono_s * 1e9)


def from_ns(t_ns: int) -> float:
    return t_ns * 1e-9


def _stamp(t_mono_s: float) -> dict[str, int]:
    sec, nsec = divmod(to_ns(t_mono_s), 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def _vec3(v: ArrayLike) -> dict[str, float]:
    a = np.asarray(v, dtype=np.float64).reshape(3)
    return {"x": float(a[0]), "y": float(a[1]), "z": float(a[2])}


def _quat(q_wxyz: ArrayLike) -> dict[str, float]:
    q = np.asarray(q_wxyz, dtype=np.float64).reshape(4)
    return {"x": float(q[1]), "y": float(q[2]), "z": float(q[3]), "w": float(q[0])}


def _yaw_quat(yaw_rad: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw_rad / 2), "w": math.cos(yaw_rad / 2)}


def to_jsonable(value: Any) -> Any:
    """Numpy scalars/arrays, tuples and mappings -> plain JSON types; NaN/inf -> None."""
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        f = float(value)
        return f if math.isfinite(f) else None
    if value is None or isinstance(value, str):
        return value
    return str(value)


def _image(t_mono_s: float, img: np.ndarray, encoding: str, frame_id: str) -> dict[str, Any]:
    data = np.ascontiguousarray(img.astype(img.dtype.newbyteorder("<"), copy=False))
    return {
        "timestamp": _stamp(t_mono_s),
        "frame_id": frame_id,
        "width": int(img.shape[1]),
        "height": int(img.shape[0]),
        "encoding": encoding,
        "step": int(img.shape[1] * img.dtype.itemsize),
        "data": base64.b64encode(data.tobytes()).decode("ascii"),
    }


def encode_depth(t_mono_s: float, depth_mm: np.ndarray) -> dict[str, Any]:
    """Raw depth (uint16 mm, (H, W), 0 = invalid) as foxglove.RawImage ``16UC1``."""
    img = np.asarray(depth_mm)
    if img.ndim != 2 or img.dtype != np.uint16:
        raise ValueError(f"depth_mm must be uint16 (H, W), got {img.dtype} {img.shape}")
    return _image(t_mono_s, img, "16UC1", "camera_depth_optical")


def encode_network_input(t_mono_s: float, step: int, input_32: np.ndarray) -> dict[str, Any]:
    """The planner's depth input (float32 (32, 32) in [0, 1]) as foxglove.RawImage ``32FC1``."""
    img = np.asarray(input_32, dtype=np.float32)
    if img.ndim != 2:
        raise ValueError(f"input_32 must be 2-D, got shape {img.shape}")
    msg = _image(t_mono_s, img, "32FC1", "planner_input")
    msg["decision_step"] = int(step)
    return msg


def decode_image(msg: Mapping[str, Any]) -> np.ndarray:
    """Inverse of :func:`encode_depth` / :func:`encode_network_input`: (H, W) uint16 or float32."""
    dtype = {"16UC1": "<u2", "32FC1": "<f4"}.get(msg["encoding"])
    if dtype is None:
        raise ValueError(f"unsupported image encoding {msg['encoding']!r}")
    raw = base64.b64decode(msg["data"])
    return np.frombuffer(raw, dtype=dtype).reshape(int(msg["height"]), int(msg["width"])).astype(dtype[1:])


def encode_odometry(
    t_mono_s: float, pos_world_m: ArrayLike, quat_world_body: ArrayLike, vel_world_m_s: ArrayLike | None
) -> dict[str, Any]:
    """Vehicle pose (world frame, quaternion w,x,y,z body FLU -> world) as foxglove.PoseInFrame."""
    msg: dict[str, Any] = {
        "timestamp": _stamp(t_mono_s),
        "frame_id": "world",
        "pose": {"position": _vec3(pos_world_m), "orientation": _quat(quat_world_body)},
    }
    if vel_world_m_s is not None:
        msg["vel_world_m_s"] = _vec3(vel_world_m_s)
    return msg


def encode_setpoint(
    t_mono_s: float, pos_world_m: ArrayLike, vel_world_m_s: ArrayLike, yaw_rad: float
) -> tuple[dict[str, Any], dict[str, Any]]:
    """A commanded setpoint: (quadnav.Setpoint, the same as foxglove.PoseInFrame for the 3D view)."""
    sp = {
        "timestamp": _stamp(t_mono_s),
        "pos_world_m": _vec3(pos_world_m),
        "vel_world_m_s": _vec3(vel_world_m_s),
        "yaw_rad": float(yaw_rad),
    }
    pose = {
        "timestamp": sp["timestamp"],
        "frame_id": "world",
        "pose": {"position": sp["pos_world_m"], "orientation": _yaw_quat(float(yaw_rad))},
    }
    return sp, pose


def encode_moving_setpoint(t_mono_s: float, pos_world_m: ArrayLike) -> dict[str, Any]:
    return {
        "timestamp": _stamp(t_mono_s),
        "frame_id": "world",
        "pose": {"position": _vec3(pos_world_m), "orientation": _yaw_quat(0.0)},
    }


def encode_path(t_mono_s: float, waypoints_m: ArrayLike) -> dict[str, Any]:
    """The rough path's waypoints (world, m, (K, 3)) as foxglove.PosesInFrame."""
    wps = np.asarray(waypoints_m, dtype=np.float64)
    if wps.ndim != 2 or wps.shape[1] != 3 or len(wps) < 2:
        raise ValueError(f"waypoints_m must have shape (K>=2, 3), got {wps.shape}")
    poses = [{"position": _vec3(w), "orientation": _yaw_quat(0.0)} for w in wps]
    return {"timestamp": _stamp(t_mono_s), "frame_id": "world", "poses": poses}


def encode_step(
    t_mono_s: float,
    *,
    step: int,
    action: int,
    q_values: ArrayLike,
    rel_pos_body_m: ArrayLike,
    moving_setpoint_world_m: ArrayLike,
    pos_world_m: ArrayLike,
    reward: float,
    reward_terms: Mapping[str, Any],
    progress_m: float,
    deviation_m: float,
    latency_ms: float,
    shield_allowed: ArrayLike | None = None,
    shield_clearance_m: ArrayLike | None = None,
) -> dict[str, Any]:
    """One planner decision as quadnav.Step (the shield's verdict only when it was on)."""
    shield = {}
    if shield_allowed is not None:
        shield["shield_allowed"] = [bool(a) for a in np.asarray(shield_allowed).reshape(-1)]
    if shield_clearance_m is not None:
        clearance = np.asarray(shield_clearance_m, dtype=np.float64).reshape(-1)
        shield["shield_clearance_m"] = to_jsonable(clearance)
    return shield | {
        "timestamp": _stamp(t_mono_s),
        "step": int(step),
        "action": int(action),
        "q_values": to_jsonable(np.asarray(q_values, dtype=np.float64).reshape(-1)),
        "rel_pos_body_m": _vec3(rel_pos_body_m),
        "moving_setpoint_world_m": _vec3(moving_setpoint_world_m),
        "pos_world_m": _vec3(pos_world_m),
        "reward": to_jsonable(float(reward)),
        "reward_terms": to_jsonable(dict(reward_terms)),
        "progress_m": to_jsonable(float(progress_m)),
        "deviation_m": to_jsonable(float(deviation_m)),
        "latency_ms": to_jsonable(float(latency_ms)),
    }


def encode_vehicle(t_mono_s: float, armed: bool, mode: str, health: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "timestamp": _stamp(t_mono_s),
        "armed": bool(armed),
        "mode": str(mode),
        "health": to_jsonable(dict(health)),
    }


def encode_event(t_mono_s: float, kind: str, message: str, fields: Mapping[str, Any]) -> dict[str, Any]:
    """A supervisor/daemon event as foxglove.Log; ``fields['level']`` (debug..fatal) sets the level."""
    f = dict(fields)
    level = _LEVELS.get(str(f.pop("level", "info")).lower(), 2)
    return {
        "timestamp": _stamp(t_mono_s),
        "level": level,
        "message": str(message),
        "name": "quadnav",
        "file": "",
        "line": 0,
        "kind": str(kind),
        "fields": to_jsonable(f),
    }


def encode_stop(
    t_mono_s: float, stop_reason: str, summary: Mapping[str, Any], dropped: Mapping[str, int]
) -> dict[str, Any]:
    return {
        "timestamp": _stamp(t_mono_s),
        "stop_reason": str(stop_reason),
        "summary": to_jsonable(dict(summary)),
        "dropped": to_jsonable(dict(dropped)),
    }
