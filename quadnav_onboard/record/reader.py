"""Read a flight record back into arrays, including records cut off mid-flight.

The file is read as a stream of MCAP records, one at a time, with chunk CRCs checked. A record
that ends early (SIGKILL, power loss: no summary, no footer, a half-written last chunk) is read up
to the last complete, CRC-valid chunk and marked ``complete=False`` with the reason. Anything that
is not a quadnav flight record raises :class:`RecordError` with a one-line message naming the
file.

Every format is read: version 3 (Foxglove's well-known schemas, protobuf, wall-clock log times,
the step record ``quadnav.Step`` in protobuf with :class:`~quadnav_onboard.step.StepRecord`'s
fields), version 2 (the same with ``quadnav.Step`` in JSON, its reward terms in ``reward_terms``),
each message decoded by its own schema (:mod:`decode`), and version 1 (JSON messages, monotonic
log times). Either way the record's times come back as monotonic seconds of the recording
process, and :meth:`FlightRecord.step_record` gives the steps as one ``StepRecord``.
"""

from __future__ import annotations

import base64
import io
import json
import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Footer, McapRecord, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from numpy.typing import NDArray

from quadnav_onboard.record import schemas as S
from quadnav_onboard.record import step_msg
from quadnav_onboard.record.decode import DecodeError, decoder_for
from quadnav_onboard.step import StepRecord

__all__ = ["FlightRecord", "RecordError", "read_record"]

_MAGIC = b"\x89MCAP0\r\n"
_READABLE_VERSIONS = tuple(str(v) for v in range(1, S.FORMAT_VERSION + 1))
_READ = {
    "/planner/step", "/odometry", "/setpoint", "/planner/input", "/camera/depth", "/vehicle",
    "/vehicle/px4_time", "/events", "/planner/path", "/flight/stop",
}
"""Topics read into a :class:`FlightRecord` (both versions)."""
_MAX_RECORD_BYTES = 1 << 30


class RecordError(ValueError):
    """The file is not a readable quadnav flight record; the message names the file and why."""


def _vec(d: dict[str, Any]) -> list[float]:
    return [_num(d.get("x")), _num(d.get("y")), _num(d.get("z"))]


def _num(v: Any) -> float:
    return float("nan") if v is None else float(v)


@dataclass
class FlightRecord:
    """A flight record in memory. Times are monotonic seconds of the recording process."""

    path: Path
    metadata: dict[str, dict[str, str]]
    """MCAP metadata records by name: ``quadnav`` (given to the recorder), ``recorder``, ..."""
    complete: bool
    """The file ends with a footer (the recorder was closed)."""
    problem: str | None = None
    """Why the record is incomplete (e.g. cut off inside a chunk), else None."""
    message_counts: dict[str, int] = field(default_factory=dict)
    steps: list[dict[str, Any]] = field(default_factory=list)
    """quadnav.Step messages in step order, each with ``t_mono_s``; the filter's verdicts
    (``shield_allowed``, ``shield_clearance_m``) None or absent when it was off."""
    odom_t_s: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    odom_pos_world_m: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    odom_quat_world_body: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 4)))
    """Attitude (w, x, y, z)."""
    setpoint_t_s: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    setpoint_pos_world_m: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    setpoint_yaw_rad: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    vehicle: list[dict[str, Any]] = field(default_factory=list)
    """quadnav.Vehicle messages (armed, mode, health) with ``t_mono_s``."""
    events: list[dict[str, Any]] = field(default_factory=list)
    """Events (foxglove.Log + kind, fields) with ``t_mono_s``."""
    network_inputs: list[tuple[float, int, NDArray[np.float32]]] = field(default_factory=list)
    """(t_mono_s, decision step, (32, 32) float32) for every decision."""
    depth: list[tuple[float, NDArray[np.uint16]]] = field(default_factory=list)
    """(t_mono_s, (H, W) uint16 mm) decimated raw depth, if loaded."""
    path_waypoints_m: NDArray[np.float64] | None = None
    """The rough path (world, m, (K, 3)) when the recorder was given it."""
    stop: dict[str, Any] | None = None
    """The quadnav.Stop message (stop_reason, summary, dropped) with ``t_mono_s``; None if cut off."""
    px4_time: list[dict[str, Any]] = field(default_factory=list)
    """quadnav.Px4Time messages (PX4's clock: ``unix_minus_px4_boot_us`` lines up the ULog)."""
    format_version: int = 0
    unix_minus_mono_ns: int = 0
    """Version 2: a log time (wall clock, ns) minus the recording process's monotonic time (ns)."""
    """The record's format version (1: JSON, monotonic log times; 2: Foxglove protobuf, UTC)."""

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def info(self) -> dict[str, str]:
        """The ``quadnav`` metadata given to the recorder (config, model hash, world, ...)."""
        return self.metadata.get("quadnav", {})

    def step_array(self, key: str) -> NDArray[np.float64]:
        """A per-step field as an array: scalars -> (N,), vectors {x,y,z} -> (N, 3), lists -> (N, k)."""
        vals = [s[key] for s in self.steps]
        if vals and isinstance(vals[0], dict):
            return np.array([_vec(v) for v in vals], dtype=np.float64).reshape(-1, 3)
        if vals and isinstance(vals[0], list):
            return np.array([[_num(x) for x in v] for v in vals], dtype=np.float64)
        return np.array([_num(v) for v in vals], dtype=np.float64)

    @property
    def step_t_s(self) -> NDArray[np.float64]:
        return np.array([s["t_mono_s"] for s in self.steps], dtype=np.float64)

    def step_record(self) -> StepRecord:
        """Every recorded step as one :class:`~quadnav_onboard.step.StepRecord` (N = steps, in
        step order). A field a record's format did not hold (version 1 and 2: the end position,
        the outcome, ...) is NaN, False or 0; ``d_prev_m``, ``d_now_m``, ``deviated`` and
        ``collided`` come from version 2's ``reward_terms`` where it gave them; the filter's
        verdicts are None unless every step has them."""
        cols: dict[str, Any] = {}
        for f in step_msg.FIELDS[1:-1]:
            vals = [_step_value(s, f.name) for s in self.steps]
            if f.optional and (not vals or any(v is None or len(v) == 0 for v in vals)):
                cols[f.name] = None
                continue
            dtype = {"f": np.float64, "i": np.int64, "b": np.bool_}[f.kind]
            if f.name == "outcome":
                dtype = np.int8
            fill = {"f": math.nan, "i": 0, "b": False}[f.kind]
            rows = [fill if v is None else v for v in vals]
            if f.repeated:
                width = max((len(r) for r in rows if isinstance(r, list)), default=0)
                rows = [r if isinstance(r, list) else [fill] * width for r in rows]
                cols[f.name] = np.array(rows, dtype=np.float64).reshape(len(rows), width).astype(dtype)
            else:
                cols[f.name] = np.array(rows, dtype=np.float64).astype(dtype)
        return StepRecord(**cols)


def _step_value(s: dict[str, Any], name: str) -> Any:
    """A step message's value of StepRecord field ``name`` (lists for vectors; None: not held)."""
    v = s.get(name)
    if v is None:
        v = (s.get("reward_terms") or {}).get(name)
    if isinstance(v, dict):
        return _vec(v)
    if isinstance(v, list):
        return [_num(x) if not isinstance(x, bool) else x for x in v]
    return v


def _opname(opcode: int) -> str:
    try:
        return Opcode(opcode).name
    except ValueError:
        return f"unknown (opcode {opcode:#x})"


def _records(path: Path, problems: list[str]) -> Iterator[McapRecord]:
    """Yield the file's MCAP records (chunks opened, CRCs checked); stop at the first bad one."""
    with open(path, "rb") as f:
        size = path.stat().st_size
        if f.read(8) != _MAGIC:
            raise RecordError(f"{path}: not an MCAP file (bad magic bytes)")
        while True:
            start = f.tell()
            head = f.read(9)
            if len(head) == 0:
                problems.append(f"cut off after {start} bytes (no footer)")
                return
            if len(head) < 9:
                problems.append(f"cut off inside a record header at byte {start}")
                return
            opcode, length = struct.unpack("<BQ", head)
            if length > min(_MAX_RECORD_BYTES, size - start - 9):
                problems.append(f"cut off inside a {_opname(opcode)} record at byte {start}")
                return
            body = f.read(length)
            reader = StreamReader(io.BytesIO(head + body), skip_magic=True, validate_crcs=True)
            try:
                out = []
                try:
                    for rec in reader.records:
                        out.append(rec)
                except EndOfFile:
                    pass
            except (McapError, ValueError, struct.error, UnicodeDecodeError) as exc:
                problems.append(f"corrupt {_opname(opcode)} record at byte {start}: {exc}")
                return
            except Exception as exc:  # zstd errors and the like: the chunk is damaged
                problems.append(f"corrupt {_opname(opcode)} record at byte {start}: {type(exc).__name__}")
                return
            if any(isinstance(r, Footer) for r in out):
                if f.read(8) != _MAGIC:
                    problems.append("footer without the closing magic bytes (cut off at the very end)")
                    yield from (r for r in out if not isinstance(r, Footer))
                else:
                    yield from out
                return
            yield from out


def _ts(msg: dict[str, Any], log_time_ns: int) -> float:
    """Version 1: the message's monotonic time stamp, else its log time (also monotonic)."""
    stamp = msg.get("timestamp")
    if isinstance(stamp, dict) and "sec" in stamp:
        return int(stamp["sec"]) + int(stamp.get("nsec", 0)) * 1e-9
    return log_time_ns * 1e-9


def _decode_image_v1(msg: dict[str, Any]) -> np.ndarray:
    dtype = {"16UC1": "<u2", "32FC1": "<f4"}.get(msg["encoding"])
    if dtype is None:
        raise ValueError(f"unsupported image encoding {msg['encoding']!r}")
    raw = base64.b64decode(msg["data"])
    return np.frombuffer(raw, dtype=dtype).reshape(int(msg["height"]), int(msg["width"])).astype(dtype[1:])


def _decode_image(msg: dict[str, Any]) -> np.ndarray:
    """A foxglove.RawImage (16UC1 or 32FC1, little-endian rows of ``step`` bytes) as (H, W)."""
    dtype = {"16UC1": np.dtype("<u2"), "32FC1": np.dtype("<f4")}.get(msg["encoding"])
    if dtype is None:
        raise ValueError(f"unsupported image encoding {msg['encoding']!r}")
    h, w, step = int(msg["height"]), int(msg["width"]), int(msg["step"])
    if step < w * dtype.itemsize or len(msg["data"]) < h * step:
        raise ValueError(f"image data of {len(msg['data'])} bytes is short of {h} rows of {step}")
    rows = np.frombuffer(msg["data"], dtype=np.uint8, count=h * step).reshape(h, step)
    return rows[:, : w * dtype.itemsize].copy().view(dtype).astype(dtype.newbyteorder("="))


def read_record(path: str | Path, *, load_depth: bool = True) -> FlightRecord:
    """Read the record at ``path``. Raises :class:`RecordError` for anything that is not one."""
    path = Path(path)
    if not path.exists():
        raise RecordError(f"{path}: no such file")
    if not path.is_file():
        raise RecordError(f"{path}: not a regular file")
    problems: list[str] = []
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    decoders: dict[int, Any] = {}
    rec = FlightRecord(path=path, metadata={}, complete=False)
    acc = _Accumulator()
    try:
        for r in _records(path, problems):
            if isinstance(r, Schema):
                schemas[r.id] = r
            elif isinstance(r, Channel):
                channels[r.id] = r
                decoders[r.id] = decoder_for(r.message_encoding, schemas.get(r.schema_id))
            elif isinstance(r, Metadata):
                rec.metadata[r.name] = dict(r.metadata)
            elif isinstance(r, Footer):
                rec.complete = True
            elif isinstance(r, Message):
                ch = channels.get(r.channel_id)
                if ch is None:
                    problems.append(f"message on unknown channel {r.channel_id}")
                    break
                rec.message_counts[ch.topic] = rec.message_counts.get(ch.topic, 0) + 1
                decode = decoders[r.channel_id]
                skip = ch.topic not in _READ or (ch.topic == "/camera/depth" and not load_depth)
                if decode is None or skip:
                    continue  # the 3-D scene and the transforms are for Foxglove: counted, not decoded
                if rec.format_version == 0:
                    rec.format_version = _version(path, rec)
                msg = decode(r.data)
                if rec.format_version == 1:
                    _dispatch_v1(rec, ch.topic, msg, r.log_time, acc)
                else:
                    _dispatch(rec, ch.topic, msg, r.log_time, acc)
    except OSError as exc:
        raise RecordError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        if isinstance(exc, RecordError):
            raise
        what = "undecodable" if isinstance(exc, DecodeError) else "malformed"
        raise RecordError(f"{path}: {what} message in record: {type(exc).__name__}: {exc}") from None
    if rec.format_version == 0:
        if not rec.metadata and not channels:
            raise RecordError(f"{path}: MCAP file holds no readable data ({'; '.join(problems) or 'empty'})")
        rec.format_version = _version(path, rec)
    rec.problem = None if rec.complete else ("; ".join(problems) or None)
    acc.finish(rec)
    world = rec.metadata.get("world", {}).get("yaml")
    if world and "world_yaml" not in rec.info:
        rec.metadata.setdefault("quadnav", {})["world_yaml"] = world
    return rec


def _version(path: Path, rec: FlightRecord) -> int:
    """The format version from the ``recorder`` metadata; RecordError if it is not ours."""
    meta = rec.metadata.get("recorder", {})
    if meta.get("format") != S.FORMAT:
        raise RecordError(f"{path}: an MCAP file, but not a quadnav flight record (no 'recorder' metadata)")
    version = meta.get("format_version", "?")
    if version not in _READABLE_VERSIONS:
        raise RecordError(
            f"{path}: flight record format version {version}, this tool reads {', '.join(_READABLE_VERSIONS)}"
        )
    if version != "1":
        try:
            rec.unix_minus_mono_ns = int(meta["unix_minus_mono_ns"])
        except (KeyError, ValueError):
            raise RecordError(f"{path}: recorder metadata without a valid 'unix_minus_mono_ns'") from None
    return int(version)


@dataclass
class _Accumulator:
    """Rows gathered while reading, turned into the record's arrays at the end."""

    odom: list[tuple[float, list[float], list[float]]] = field(default_factory=list)
    sps: list[tuple[float, list[float], float]] = field(default_factory=list)
    inputs: list[tuple[float, int, NDArray[np.float32]]] = field(default_factory=list)

    def finish(self, rec: FlightRecord) -> None:
        rec.steps.sort(key=lambda s: (s["step"], s["t_mono_s"]))
        if self.odom:
            rec.odom_t_s = np.array([o[0] for o in self.odom])
            rec.odom_pos_world_m = np.array([o[1] for o in self.odom]).reshape(-1, 3)
            rec.odom_quat_world_body = np.array([o[2] for o in self.odom]).reshape(-1, 4)
        if self.sps:
            rec.setpoint_t_s = np.array([s[0] for s in self.sps])
            rec.setpoint_pos_world_m = np.array([s[1] for s in self.sps]).reshape(-1, 3)
            rec.setpoint_yaw_rad = np.array([s[2] for s in self.sps])
        if rec.format_version == 1:
            rec.network_inputs = self.inputs
            return
        # version 2: an input's decision is the step recorded at the same time (-1: none recorded)
        step_at = {round(s["t_mono_s"] * 1e9): int(s["step"]) for s in rec.steps}
        rec.network_inputs = [(t, step_at.get(round(t * 1e9), -1), img) for t, _, img in self.inputs]


def _quat(q: dict[str, Any] | None) -> list[float]:
    q = q or {}
    return [_num(q.get("w")), _num(q.get("x")), _num(q.get("y")), _num(q.get("z"))]


def _dispatch(
    rec: FlightRecord, topic: str, msg: dict[str, Any], log_time_ns: int, acc: _Accumulator
) -> None:
    """One version-2 message (decoded by its schema) into ``rec``; its time is its own time stamp
    (a log time may be later: see :mod:`sink`)."""
    stamp = msg.get("timestamp")
    if isinstance(stamp, dict):
        log_time_ns = int(stamp["seconds"]) * 1_000_000_000 + int(stamp["nanos"])
    t = (log_time_ns - rec.unix_minus_mono_ns) / 1e9
    if topic == "/planner/step":
        if rec.format_version >= 3:  # protobuf: a field left out (the filter off) reads as []
            for key in ("shield_allowed", "shield_clearance_m"):
                if not msg.get(key):
                    msg[key] = None
        rec.steps.append(msg)
    elif topic == "/odometry":
        pose = msg["pose"] or {}
        acc.odom.append((t, _vec(pose.get("position") or {}), _quat(pose.get("orientation"))))
    elif topic == "/setpoint":
        pose = msg["pose"] or {}
        w, _, _, z = _quat(pose.get("orientation"))
        acc.sps.append((t, _vec(pose.get("position") or {}), 2.0 * math.atan2(z, w)))
    elif topic == "/planner/input":
        acc.inputs.append((t, -1, _decode_image(msg).astype(np.float32)))
    elif topic == "/camera/depth":
        rec.depth.append((t, _decode_image(msg)))
    elif topic == "/vehicle":
        rec.vehicle.append(msg)
    elif topic == "/vehicle/px4_time":
        rec.px4_time.append(msg)
    elif topic == "/events":
        text, sep, tail = str(msg["message"]).partition(S.EVENT_FIELDS_SEPARATOR)
        fields: Any = {}
        if sep:
            try:
                fields = json.loads(tail)
            except ValueError:
                text = str(msg["message"])
        level, kind = int(msg["level"]), str(msg["name"])
        rec.events.append({"t_mono_s": t, "level": level, "kind": kind, "message": text, "fields": fields})
    elif topic == "/planner/path":
        rec.path_waypoints_m = np.array([_vec(p["position"] or {}) for p in msg["poses"]], dtype=np.float64)
    elif topic == "/flight/stop":
        rec.stop = msg


def _dispatch_v1(
    rec: FlightRecord, topic: str, msg: dict[str, Any], log_time_ns: int, acc: _Accumulator
) -> None:
    """One version-1 message (JSON, monotonic times) into ``rec``."""
    t = _ts(msg, log_time_ns)
    if topic == "/planner/step":
        rec.steps.append({**msg, "t_mono_s": t})
    elif topic == "/odometry":
        q = msg["pose"]["orientation"]
        acc.odom.append((t, _vec(msg["pose"]["position"]), [_num(q.get(k)) for k in ("w", "x", "y", "z")]))
    elif topic == "/setpoint":
        acc.sps.append((t, _vec(msg["pos_world_m"]), _num(msg.get("yaw_rad"))))
    elif topic == "/planner/input":
        acc.inputs.append((t, int(msg.get("decision_step", -1)), _decode_image_v1(msg)))
    elif topic == "/camera/depth":
        rec.depth.append((t, _decode_image_v1(msg)))
    elif topic == "/vehicle":
        rec.vehicle.append({**msg, "t_mono_s": t})
    elif topic == "/events":
        rec.events.append({**msg, "t_mono_s": t})
    elif topic == "/planner/path":
        rec.path_waypoints_m = np.array([_vec(p["position"]) for p in msg["poses"]], dtype=np.float64)
    elif topic == "/flight/stop":
        rec.stop = {**msg, "t_mono_s": t}
