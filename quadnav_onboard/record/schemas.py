"""What a flight record holds: topics, schemas and the pure encoders of each message.

A record is one MCAP file per flight. Where one of Foxglove's well-known schemas fits (images,
camera calibration, transforms, poses, 3-D scenes, logs) the message is that schema, protobuf
encoded by Foxglove's SDK (``foxglove.messages``), so Foxglove shows the record without
plugins. Where none fits the message is quadnav's own: the planner's step record, ``quadnav.Step``,
protobuf with a schema generated from the core's :class:`~quadnav_onboard.step.StepRecord`
(:mod:`step_msg`); the vehicle state, the stop and PX4's clock, JSON with a ``quadnav.*`` JSON
schema (:data:`JSON_SCHEMAS`).

Frames (a FrameTransform tree): ``world`` (x forward, y left, z up, m) -> ``body`` (the odometry's
pose, FLU) -> ``camera_depth_optical`` (the depth camera at its mount offset, optical axes: x
right, y down, z forward). The 3-D scene's entities are in ``world``.

Time: every log time, and every Foxglove ``timestamp``, is wall-clock (UTC) ns: the recording
process's ``time.monotonic()`` plus one offset taken when the record was opened (metadata
``recorder.unix_minus_mono_ns``), so log times keep the monotonic clock's order and spacing. A
channel's log times never go back: a datum its caller stamped before the channel's previous
message (events) is logged at that message's time and keeps its own in ``timestamp``. The quadnav
JSON messages also carry ``t_mono_s``, the monotonic time itself.

Everything here is pure: encoders take values and return the message's bytes.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from foxglove.messages import (
    CameraCalibration,
    FrameTransform,
    Log,
    LogLevel,
    Pose,
    PoseInFrame,
    PosesInFrame,
    Quaternion,
    RawImage,
    SceneUpdate,
    Timestamp,
    Vector3,
)
from numpy.typing import ArrayLike

from quadnav_onboard.record import step_msg

__all__ = [
    "CAMERA_FRAME",
    "FORMAT",
    "FORMAT_VERSION",
    "JSON_SCHEMAS",
    "PROTOBUF_SCHEMAS",
    "QUADNAV_PROTOBUF",
    "TOPICS",
    "encode_calibration",
    "encode_depth",
    "encode_event",
    "encode_network_input",
    "encode_path",
    "encode_pose",
    "encode_px4_time",
    "encode_stop",
    "encode_transform",
    "encode_vehicle",
    "optical_from_body_quat",
    "to_jsonable",
    "to_ns",
]

FORMAT = "quadnav-flight-record"
"""Value of metadata ``recorder.format``: how :mod:`reader` tells our records from other MCAPs."""
FORMAT_VERSION = 3
"""Bumped on an incompatible change of a topic's content (1: JSON messages, monotonic log times;
2: Foxglove's schemas, UTC log times, ``quadnav.Step`` in JSON; 3: ``quadnav.Step`` protobuf, the
fields of :class:`~quadnav_onboard.step.StepRecord`, see :mod:`step_msg`)."""
CAMERA_FRAME = "camera_depth_optical"
"""Frame of the depth image and its calibration."""

PROTOBUF_SCHEMAS: dict[str, Any] = {
    cls.get_schema().name: cls
    for cls in (RawImage, CameraCalibration, FrameTransform, PoseInFrame, PosesInFrame, SceneUpdate, Log)
}
"""Foxglove well-known schema name -> the SDK's message class (protobuf)."""

QUADNAV_PROTOBUF: dict[str, bytes] = {step_msg.SCHEMA_NAME: step_msg.descriptor_set()}
"""quadnav's own protobuf schemas: name -> its ``FileDescriptorSet`` (generated, :mod:`step_msg`)."""

_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}


def _obj(title: str, description: str, required: list[str], **props: Any) -> dict[str, Any]:
    return {"title": title, "description": description, "type": "object", "properties": props,
            "required": required}


JSON_SCHEMAS: dict[str, dict[str, Any]] = {
    "quadnav.Vehicle": _obj(
        "quadnav.Vehicle",
        "Autopilot state: armed, flight mode and health flags",
        ["t_mono_s", "armed", "mode"],
        t_mono_s={"type": "number"},
        armed={"type": "boolean"},
        mode={"type": "string"},
        health={"type": "object"},
    ),
    "quadnav.Px4Time": _obj(
        "quadnav.Px4Time",
        "PX4's clock seen from this computer (MAVLink SYSTEM_TIME): lines the record up with the ULog",
        ["t_mono_s", "px4_boot_us", "unix_minus_px4_boot_us"],
        t_mono_s={"type": "number", "description": "arrival of SYSTEM_TIME, time.monotonic() (s)"},
        px4_boot_us={"type": "integer", "description": "PX4 time since boot (us): ULog timestamps"},
        px4_unix_us={"type": ["integer", "null"], "description": "PX4's own UTC (us); 0/null: unknown"},
        unix_minus_px4_boot_us={
            "type": "integer",
            "description": "this record's UTC (us) minus PX4 boot time (us): add it to a ULog timestamp",
        },
    ),
    "quadnav.Stop": _obj(
        "quadnav.Stop",
        "Why the flight stopped, the flight summary, and the recorder's drop counts",
        ["t_mono_s", "stop_reason"],
        t_mono_s={"type": "number"},
        stop_reason={"type": "string"},
        summary={"type": "object"},
        dropped={"type": "object"},
    ),
}

TOPICS: dict[str, str] = {
    "/camera/depth": "foxglove.RawImage",
    "/camera/depth/calibration": "foxglove.CameraCalibration",
    "/planner/input": "foxglove.RawImage",
    "/tf": "foxglove.FrameTransform",
    "/tf_static": "foxglove.FrameTransform",
    "/odometry": "foxglove.PoseInFrame",
    "/setpoint": "foxglove.PoseInFrame",
    "/planner/path": "foxglove.PosesInFrame",
    "/planner/step": "quadnav.Step",
    "/planner/primitives": "foxglove.SceneUpdate",
    "/scene/world": "foxglove.SceneUpdate",
    "/scene/mission": "foxglove.SceneUpdate",
    "/vehicle": "quadnav.Vehicle",
    "/vehicle/px4_time": "quadnav.Px4Time",
    "/events": "foxglove.Log",
    "/flight/stop": "quadnav.Stop",
}
"""Topic -> schema name. Every record registers all of them, in this order."""

_LEVELS = {"debug": LogLevel.Debug, "info": LogLevel.Info, "warning": LogLevel.Warning,
           "error": LogLevel.Error, "fatal": LogLevel.Fatal}
EVENT_FIELDS_SEPARATOR = "\t"
"""In an event's Log message, what separates the text from its fields (JSON)."""


def to_ns(t_s: float) -> int:
    """Seconds -> integer ns; negative or non-finite times are errors."""
    if not math.isfinite(t_s) or t_s < 0:
        raise ValueError(f"time must be finite and >= 0, got {t_s!r}")
    return round(t_s * 1e9)


def _stamp(t_ns: int) -> Timestamp:
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    return Timestamp(sec=sec, nsec=nsec)


def _v3(v: ArrayLike) -> Vector3:
    """A finite 3-vector (a NaN pose or transform would break the 3-D panel's tree: an error)."""
    x, y, z = np.asarray(v, dtype=np.float64).reshape(3).tolist()
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise ValueError(f"vector must be finite, got {[x, y, z]}")
    return Vector3(x=x, y=y, z=z)


def _q(q_wxyz: ArrayLike) -> Quaternion:
    """A finite quaternion given as (w, x, y, z)."""
    w, x, y, z = np.asarray(q_wxyz, dtype=np.float64).reshape(4).tolist()
    if not all(math.isfinite(c) for c in (w, x, y, z)):
        raise ValueError(f"quaternion must be finite, got {[w, x, y, z]}")
    return Quaternion(x=x, y=y, z=z, w=w)


def _yaw_q(yaw_rad: float) -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=math.sin(yaw_rad / 2), w=math.cos(yaw_rad / 2))


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


def _json(msg: Mapping[str, Any]) -> bytes:
    return json.dumps(msg, separators=(",", ":"), allow_nan=False).encode()


def _image(t_ns: int, img: np.ndarray, encoding: str, frame_id: str) -> bytes:
    data = np.ascontiguousarray(img, dtype=img.dtype.newbyteorder("<"))
    return RawImage(
        timestamp=_stamp(t_ns),
        frame_id=frame_id,
        width=int(img.shape[1]),
        height=int(img.shape[0]),
        encoding=encoding,
        step=int(img.shape[1] * img.dtype.itemsize),
        data=data.tobytes(),
    ).encode()


def encode_depth(t_ns: int, depth_mm: np.ndarray) -> bytes:
    """Raw depth (uint16 mm, (H, W), 0 = invalid) as foxglove.RawImage ``16UC1``."""
    img = np.asarray(depth_mm)
    if img.ndim != 2 or img.dtype != np.uint16:
        raise ValueError(f"depth_mm must be uint16 (H, W), got {img.dtype} {img.shape}")
    return _image(t_ns, img, "16UC1", CAMERA_FRAME)


def encode_network_input(t_ns: int, input_32: np.ndarray) -> bytes:
    """The planner's depth input (float32 (32, 32) in [0, 1]) as foxglove.RawImage ``32FC1``; its
    decision is the /planner/step of the same time stamp."""
    img = np.asarray(input_32, dtype=np.float32)
    if img.ndim != 2:
        raise ValueError(f"input_32 must be 2-D, got shape {img.shape}")
    return _image(t_ns, img, "32FC1", "planner_input")


def optical_from_body_quat() -> tuple[float, float, float, float]:
    """Rotation (w, x, y, z) of the optical frame (x right, y down, z forward) in the body (FLU)."""
    return (0.5, -0.5, 0.5, -0.5)


def encode_calibration(
    t_ns: int, width_px: int, height_px: int, hfov_deg: float, vfov_deg: float
) -> bytes:
    """A pinhole model of the depth camera from its fields of view, as foxglove.CameraCalibration."""
    if width_px < 1 or height_px < 1 or not (0 < hfov_deg < 180 and 0 < vfov_deg < 180):
        raise ValueError(f"bad camera model {width_px}x{height_px} px, fov {hfov_deg} x {vfov_deg} deg")
    fx = (width_px / 2) / math.tan(math.radians(hfov_deg) / 2)
    fy = (height_px / 2) / math.tan(math.radians(vfov_deg) / 2)
    cx, cy = width_px / 2, height_px / 2
    return CameraCalibration(
        timestamp=_stamp(t_ns),
        frame_id=CAMERA_FRAME,
        width=int(width_px),
        height=int(height_px),
        distortion_model="plumb_bob",
        D=[0.0] * 5,
        K=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        P=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    ).encode()


def encode_transform(
    t_ns: int, parent: str, child: str, translation_m: ArrayLike, rotation_wxyz: ArrayLike
) -> bytes:
    """``child``'s pose in ``parent`` as foxglove.FrameTransform (rotation w, x, y, z)."""
    return FrameTransform(
        timestamp=_stamp(t_ns),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=_v3(translation_m),
        rotation=_q(rotation_wxyz),
    ).encode()


def encode_pose(t_ns: int, pos_world_m: ArrayLike, quat_wxyz: ArrayLike | None = None,
                yaw_rad: float = 0.0) -> bytes:
    """A pose in ``world`` as foxglove.PoseInFrame: attitude ``quat_wxyz``, else the yaw alone."""
    q = _yaw_q(float(yaw_rad)) if quat_wxyz is None else _q(quat_wxyz)
    return PoseInFrame(
        timestamp=_stamp(t_ns), frame_id="world", pose=Pose(position=_v3(pos_world_m), orientation=q)
    ).encode()


def encode_path(t_ns: int, waypoints_m: ArrayLike) -> bytes:
    """The rough path's waypoints (world, m, (K, 3)) as foxglove.PosesInFrame."""
    wps = np.asarray(waypoints_m, dtype=np.float64)
    if wps.ndim != 2 or wps.shape[1] != 3 or len(wps) < 2:
        raise ValueError(f"waypoints_m must have shape (K>=2, 3), got {wps.shape}")
    poses = [Pose(position=_v3(w), orientation=_yaw_q(0.0)) for w in wps]
    return PosesInFrame(timestamp=_stamp(t_ns), frame_id="world", poses=poses).encode()


def encode_vehicle(t_mono_s: float, armed: bool, mode: str, health: Mapping[str, Any]) -> bytes:
    return _json({"t_mono_s": float(t_mono_s), "armed": bool(armed), "mode": str(mode),
                  "health": to_jsonable(dict(health))})


def encode_px4_time(t_mono_s: float, unix_minus_mono_ns: int, px4_boot_us: int, px4_unix_us: int) -> bytes:
    """PX4's clock at ``t_mono_s`` (SYSTEM_TIME's arrival) as quadnav.Px4Time."""
    if px4_boot_us < 0:
        raise ValueError(f"px4_boot_us must be >= 0, got {px4_boot_us}")
    unix_us = (to_ns(t_mono_s) + unix_minus_mono_ns) // 1000
    return _json({
        "t_mono_s": float(t_mono_s),
        "px4_boot_us": int(px4_boot_us),
        "px4_unix_us": int(px4_unix_us) or None,
        "unix_minus_px4_boot_us": int(unix_us - px4_boot_us),
    })


def encode_event(t_ns: int, kind: str, message: str, fields: Mapping[str, Any]) -> bytes:
    """A supervisor/daemon event as foxglove.Log: ``name`` is its kind; ``fields['level']``
    (debug..fatal) sets the level; the other fields follow the text as JSON after a tab."""
    f = dict(fields)
    level = _LEVELS.get(str(f.pop("level", "info")).lower(), LogLevel.Info)
    text = str(message).replace(EVENT_FIELDS_SEPARATOR, " ")
    if f:
        text += EVENT_FIELDS_SEPARATOR + json.dumps(to_jsonable(f), separators=(",", ":"))
    return Log(timestamp=_stamp(t_ns), level=level, message=text, name=str(kind)).encode()


def encode_stop(
    t_mono_s: float, stop_reason: str, summary: Mapping[str, Any], dropped: Mapping[str, int]
) -> bytes:
    return _json({
        "t_mono_s": float(t_mono_s),
        "stop_reason": str(stop_reason),
        "summary": to_jsonable(dict(summary)),
        "dropped": to_jsonable(dict(dropped)),
    })
