"""The MCAP side of the flight recorder: encode quadnav messages and write them into one file.

:class:`McapSink` owns an open file and an ``mcap`` writer (zstd chunks with CRCs); messages are
encoded by :mod:`schemas` and :mod:`scene` (Foxglove's SDK, protobuf; JSON for quadnav's own).
It is not thread-safe: one owner calls it, the recorder's writer thread or its writer process
(:mod:`quadnav_onboard.record.writer_process`). Items are ``(kind, t_mono_s, payload)`` tuples as
the :class:`~quadnav_onboard.record.recorder.FlightRecorder` queues them; log times are
``t_mono_s`` on the wall clock (see :mod:`schemas`).
"""

from __future__ import annotations

import contextlib
import json
import os
import struct
from collections.abc import Callable, Mapping
from typing import Any, BinaryIO

import yaml
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from quadnav_onboard import __version__
from quadnav_onboard.primitives import PrimitiveSet
from quadnav_onboard.record import scene, step_msg
from quadnav_onboard.record import schemas as S

__all__ = ["Item", "McapSink"]

Item = tuple[str, float, Any]
"""One queued datum: (kind, t_mono_s, payload)."""

_BODY_FROM_OPTICAL = S.optical_from_body_quat()


_MESSAGE = int(Opcode.MESSAGE)
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
"""A Message record's opcode, length, channel id, sequence, log time and publish time."""


def _fast_add(writer: Writer) -> Callable[[int, int, bytes, int, int], None] | None:
    """``writer.add_message`` without its per-call objects: the Message record packed in one
    struct, the same statistics, chunk index and chunk size check (tests compare the bytes with
    the library's own). It reaches into the writer's private state, so it is used only when that
    state is as in ``mcap`` 1.x; None otherwise (then the library's method is used)."""
    try:
        stats = writer._Writer__statistics  # type: ignore[attr-defined]
        chunk = writer._Writer__chunk_builder  # type: ignore[attr-defined]
        chunk_size = int(writer._Writer__chunk_size)  # type: ignore[attr-defined]
        finalize = writer._Writer__finalize_chunk  # type: ignore[attr-defined]
        _ = (stats.message_count, stats.channel_message_counts, chunk.message_indices, chunk.num_messages)
        _ = chunk.record_writer._buffer
    except AttributeError:
        return None

    def add(channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int) -> None:
        if stats.message_count == 0 or log_time < stats.message_start_time:
            stats.message_start_time = log_time
        if log_time > stats.message_end_time:
            stats.message_end_time = log_time
        stats.channel_message_counts[channel_id] += 1
        stats.message_count += 1
        if chunk.num_messages == 0 or log_time < chunk.message_start_time:
            chunk.message_start_time = log_time
        if log_time > chunk.message_end_time:
            chunk.message_end_time = log_time
        index = chunk.message_indices.get(channel_id)
        if not index:
            index = chunk.message_indices[channel_id] = MessageIndex(channel_id=channel_id, records=[])
        buf = chunk.record_writer._buffer
        index.records.append((log_time, buf.tell()))
        chunk.num_messages += 1
        buf.write(_MESSAGE_HEAD.pack(_MESSAGE, 22 + len(data), channel_id, sequence, log_time, publish_time))
        buf.write(data)
        if buf.tell() > chunk_size:
            finalize()

    return add


def _one(v: Any) -> int:
    """An int given as a number or a one-element array."""
    return int(v.item() if hasattr(v, "item") else v)


class McapSink:
    """Write one flight record into ``file`` (opened for binary writing; closed by :meth:`finish`).

    ``unix_minus_mono_s``: wall-clock minus monotonic time (s) when the record was opened; every
    log time is ``t_mono_s`` plus it. ``on_invalid(kind, error)`` is called for an item that
    cannot be encoded (it is skipped).
    """

    def __init__(
        self,
        file: BinaryIO,
        *,
        metadata: Mapping[str, str],
        depth_decimation: int,
        unix_minus_mono_s: float,
        chunk_size: int = 256 * 1024,
        fsync: bool = True,
        on_invalid: Callable[[str, str], None] | None = None,
    ) -> None:
        self._file = file
        self._fsync = fsync
        self._on_invalid = on_invalid
        self.invalid = 0
        self._seq = 0
        self._offset_ns = round(float(unix_minus_mono_s) * 1e9)
        self._prims: PrimitiveSet | None = None
        self._last_ns: dict[str, int] = {}
        self._writer = Writer(file, chunk_size=chunk_size, compression=CompressionType.ZSTD, enable_crcs=True)
        self._writer.start(profile="", library=f"quadnav {__version__}")
        self._add = _fast_add(self._writer) or self._writer_add
        schema_ids: dict[str, int] = {}
        for name, cls in S.PROTOBUF_SCHEMAS.items():
            sch = cls.get_schema()
            schema_ids[name] = self._writer.register_schema(name, sch.encoding, sch.data)
        for name, data in S.QUADNAV_PROTOBUF.items():
            schema_ids[name] = self._writer.register_schema(name, SchemaEncoding.Protobuf, data)
        for name, js in S.JSON_SCHEMAS.items():
            data = json.dumps(js).encode()
            schema_ids[name] = self._writer.register_schema(name, SchemaEncoding.JSONSchema, data)
        self._channels = {
            topic: self._writer.register_channel(
                topic,
                MessageEncoding.JSON if name in S.JSON_SCHEMAS else MessageEncoding.Protobuf,
                schema_ids[name],
            )
            for topic, name in S.TOPICS.items()
        }
        self._writer.add_metadata("quadnav", {str(k): str(v) for k, v in metadata.items()})
        self._writer.add_metadata(
            "recorder",
            {
                "format": S.FORMAT,
                "format_version": str(S.FORMAT_VERSION),
                "depth_decimation": str(int(depth_decimation)),
                "unix_minus_mono_ns": str(self._offset_ns),
                "log_time": "wall clock (UTC) ns: time.monotonic() + unix_minus_mono_ns",
                "library": f"quadnav {__version__}",
            },
        )
        self._file.flush()

    @classmethod
    def from_options(
        cls, file: BinaryIO, options: Mapping[str, Any], on_invalid: Callable[[str, str], None] | None = None
    ) -> McapSink:
        """A sink from the recorder's options dict (the one sent to a writer process; extra keys,
        such as ``flush_interval_s``, are the writer's own)."""
        keys = ("metadata", "depth_decimation", "unix_minus_mono_s", "chunk_size", "fsync")
        return cls(file, **{k: options[k] for k in keys}, on_invalid=on_invalid)

    def _writer_add(self, channel_id: int, log_time: int, data: bytes, publish_time: int, seq: int) -> None:
        self._writer.add_message(channel_id, log_time=log_time, data=data, publish_time=publish_time,
                                 sequence=seq)

    def wall_ns(self, t_mono_s: float) -> int:
        """The log time (wall clock, ns) of monotonic time ``t_mono_s``."""
        return S.to_ns(t_mono_s) + self._offset_ns

    def encode(self, kind: str, t: float, p: Any) -> list[tuple[str, bytes]]:
        """The (topic, message bytes) pairs of one item; raises ValueError/TypeError/KeyError if
        it is invalid."""
        ns = self.wall_ns(t)
        if kind == "depth":
            return [("/camera/depth", S.encode_depth(ns, p))]
        if kind == "input":
            return [("/planner/input", S.encode_network_input(ns, p[1]))]
        if kind == "odom":
            pos, quat, _vel = p
            return [
                ("/odometry", S.encode_pose(ns, pos, quat)),
                ("/tf", S.encode_transform(ns, "world", "body", pos, quat)),
            ]
        if kind == "setpoint":
            pos, _vel, yaw = p
            return [("/setpoint", S.encode_pose(ns, pos, yaw_rad=yaw))]
        if kind == "path":
            return [
                ("/planner/path", S.encode_path(ns, p)),
                ("/scene/mission", scene.encode_rough_path(ns, p)),
            ]
        if kind == "step":
            return self._step(ns, t, p)
        if kind == "vehicle":
            return [("/vehicle", S.encode_vehicle(t, *p))]
        if kind == "event":
            return [("/events", S.encode_event(ns, *p))]
        if kind == "camera":
            width, height, hfov, vfov, offset = p
            return [
                ("/camera/depth/calibration", S.encode_calibration(ns, width, height, hfov, vfov)),
                ("/tf_static", S.encode_transform(ns, "body", S.CAMERA_FRAME, offset, _BODY_FROM_OPTICAL)),
            ]
        if kind == "geofence":
            return [("/scene/mission", scene.encode_geofence(ns, *p))]
        if kind == "world":
            return [("/scene/world", scene.encode_world(ns, p))]
        if kind == "px4_time":
            return [("/vehicle/px4_time", S.encode_px4_time(t, self._offset_ns, *p))]
        raise ValueError(f"unknown message kind {kind!r}")

    def _step(self, ns: int, t: float, p: Any) -> list[tuple[str, bytes]]:
        """A step: ``(StepRecord, latency_ms, primitive)`` from :meth:`FlightRecorder.step_record`,
        or the keyword dict of :meth:`FlightRecorder.step`; ``primitive``: (commanded start,
        start velocity, heading) or None."""
        if isinstance(p, tuple):
            record, latency_ms, prim = p
            out = [("/planner/step", step_msg.encode_record(t, record, latency_ms))]
            action, allowed, setpoint = record.action, record.shield_allowed, record.moving_setpoint_world_m
        else:
            row, prim = step_msg.row_of_kwargs(t, p), p.get("primitive")
            out = [("/planner/step", step_msg.encode(row))]
            action, allowed, setpoint = row["action"], row["shield_allowed"], row["moving_setpoint_world_m"]
        if prim is not None and self._prims is not None:
            start, vel, yaw = prim
            out.append((
                "/planner/primitives",
                scene.encode_primitives(
                    ns, self._prims, start_world_m=start, start_vel_world_m_s=vel, yaw_rad=yaw,
                    action=_one(action), allowed=allowed, moving_setpoint_world_m=setpoint,
                ),
            ))
        return out

    def write(self, kind: str, t: float, payload: Any) -> None:
        """Encode and write one item; an invalid one is counted (:attr:`invalid`) and skipped.
        Disk errors (OSError) propagate to the owner."""
        if kind == "metadata":
            self._writer.add_metadata(*payload)
            return
        try:
            if kind == "primitive_set":
                if not isinstance(payload, PrimitiveSet):
                    raise TypeError(f"primitive_set must be a PrimitiveSet, got {type(payload).__name__}")
                self._prims = payload
                return
            blobs = self.encode(kind, t, payload)
            if kind == "world":
                text = yaml.safe_dump(S.to_jsonable(payload), sort_keys=False)
                self._writer.add_metadata("world", {"yaml": text})
        except (ValueError, TypeError, KeyError, IndexError) as exc:
            self.invalid += 1
            if self._on_invalid is not None:
                self._on_invalid(kind, f"{type(exc).__name__}: {exc}")
            return
        t_ns = self.wall_ns(t)
        for topic, data in blobs:
            # a channel's log times never go back: a datum stamped before the channel's previous
            # message (an event timed by its caller) is logged at that message's time; its own
            # time stays in the message (``timestamp``, ``t_mono_s``)
            log_ns = max(t_ns, self._last_ns.get(topic, 0))
            self._last_ns[topic] = log_ns
            self._add(self._channels[topic], log_ns, data, t_ns, self._seq)
            self._seq += 1

    def flush(self) -> None:
        """Close the open chunk and push it to the disk (fsync unless switched off)."""
        self._writer.flush()
        if self._fsync:
            os.fsync(self._file.fileno())

    def finish(
        self, t_stop: float, reason: str, summary: Mapping[str, Any], drops: Mapping[str, int]
    ) -> None:
        """Write the stop message, the index and the footer; flush and close the file."""
        t_ns = max(self.wall_ns(t_stop), self._last_ns.get("/flight/stop", 0))
        data = S.encode_stop(t_stop, reason, summary, drops)
        self._writer.add_message(self._channels["/flight/stop"], log_time=t_ns, data=data, publish_time=t_ns)
        self._writer.finish()
        self._file.flush()
        if self._fsync:
            os.fsync(self._file.fileno())
        self._file.close()

    def close_file(self) -> None:
        """Close the file without finishing it (after an error); never raises."""
        with contextlib.suppress(OSError):
            self._file.close()
