"""Read a flight record back into arrays, including records cut off mid-flight.

The file is read as a stream of MCAP records, one at a time, with chunk CRCs checked. A record
that ends early (SIGKILL, power loss: no summary, no footer, a half-written last chunk) is read up
to the last complete, CRC-valid chunk and marked ``complete=False`` with the reason. Anything that
is not a quadnav flight record raises :class:`RecordError` with a one-line message naming the
file.
"""

from __future__ import annotations

import io
import json
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

__all__ = ["FlightRecord", "RecordError", "read_record"]

_MAGIC = b"\x89MCAP0\r\n"
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
    """quadnav.Step messages in step order, each with ``t_mono_s`` added."""
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
    stamp = msg.get("timestamp")
    if isinstance(stamp, dict) and "sec" in stamp:
        return int(stamp["sec"]) + int(stamp.get("nsec", 0)) * 1e-9
    return S.from_ns(log_time_ns)


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
    rec = FlightRecord(path=path, metadata={}, complete=False)
    odom: list[tuple[float, list[float], list[float]]] = []
    sps: list[tuple[float, list[float], float]] = []
    try:
        for r in _records(path, problems):
            if isinstance(r, Schema):
                schemas[r.id] = r
            elif isinstance(r, Channel):
                channels[r.id] = r
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
                if ch.message_encoding != "json":
                    continue
                _dispatch(rec, ch.topic, json.loads(r.data), r.log_time, odom, sps, load_depth)
    except OSError as exc:
        raise RecordError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, RecordError):
            raise
        raise RecordError(f"{path}: malformed message in record: {type(exc).__name__}: {exc}") from None
    if rec.metadata.get("recorder", {}).get("format") != S.FORMAT:
        if not rec.metadata and not channels:
            raise RecordError(f"{path}: MCAP file holds no readable data ({'; '.join(problems) or 'empty'})")
        raise RecordError(f"{path}: an MCAP file, but not a quadnav flight record (no 'recorder' metadata)")
    version = rec.metadata["recorder"].get("format_version", "?")
    if version != str(S.FORMAT_VERSION):
        raise RecordError(
            f"{path}: flight record format version {version}, this tool reads {S.FORMAT_VERSION}"
        )
    rec.problem = "; ".join(problems) or None
    if rec.complete:
        rec.problem = None
    rec.steps.sort(key=lambda s: (s["step"], s["t_mono_s"]))
    if odom:
        rec.odom_t_s = np.array([o[0] for o in odom])
        rec.odom_pos_world_m = np.array([o[1] for o in odom]).reshape(-1, 3)
        rec.odom_quat_world_body = np.array([o[2] for o in odom]).reshape(-1, 4)
    if sps:
        rec.setpoint_t_s = np.array([s[0] for s in sps])
        rec.setpoint_pos_world_m = np.array([s[1] for s in sps]).reshape(-1, 3)
        rec.setpoint_yaw_rad = np.array([s[2] for s in sps])
    return rec


def _dispatch(
    rec: FlightRecord,
    topic: str,
    msg: dict[str, Any],
    log_time_ns: int,
    odom: list[tuple[float, list[float], list[float]]],
    sps: list[tuple[float, list[float], float]],
    load_depth: bool,
) -> None:
    t = _ts(msg, log_time_ns)
    if topic == "/planner/step":
        rec.steps.append({**msg, "t_mono_s": t})
    elif topic == "/odometry":
        q = msg["pose"]["orientation"]
        odom.append((t, _vec(msg["pose"]["position"]), [_num(q.get(k)) for k in ("w", "x", "y", "z")]))
    elif topic == "/setpoint":
        sps.append((t, _vec(msg["pos_world_m"]), _num(msg.get("yaw_rad"))))
    elif topic == "/planner/input":
        rec.network_inputs.append((t, int(msg.get("decision_step", -1)), S.decode_image(msg)))
    elif topic == "/camera/depth" and load_depth:
        rec.depth.append((t, S.decode_image(msg)))
    elif topic == "/vehicle":
        rec.vehicle.append({**msg, "t_mono_s": t})
    elif topic == "/events":
        rec.events.append({**msg, "t_mono_s": t})
    elif topic == "/planner/path":
        rec.path_waypoints_m = np.array([_vec(p["position"]) for p in msg["poses"]], dtype=np.float64)
    elif topic == "/flight/stop":
        rec.stop = {**msg, "t_mono_s": t}
