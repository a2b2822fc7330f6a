"""The MCAP side of the flight recorder: encode quadnav messages and write them into one file.

:class:`McapSink` owns an open file and an ``mcap`` writer (zstd chunks with CRCs). It is not
thread-safe: one owner calls it, the recorder's writer thread or its writer process
(:mod:`quadnav_onboard.record.writer_process`). Items are ``(kind, t_mono_s, payload)`` tuples as
the :class:`~quadnav_onboard.record.recorder.FlightRecorder` queues them.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable, Mapping
from typing import Any, BinaryIO

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from quadnav_onboard import __version__
from quadnav_onboard.record import schemas as S

__all__ = ["Item", "McapSink"]

Item = tuple[str, float, Any]
"""One queued datum: (kind, t_mono_s, payload)."""


def _json(msg: Mapping[str, Any]) -> bytes:
    return json.dumps(msg, separators=(",", ":"), allow_nan=False).encode()


class McapSink:
    """Write one flight record into ``file`` (opened for binary writing; closed by :meth:`finish`).

    ``on_invalid(kind, error)`` is called for an item that cannot be encoded (it is skipped).
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
        self._writer = Writer(file, chunk_size=chunk_size, compression=CompressionType.ZSTD, enable_crcs=True)
        self._writer.start(profile="", library=f"quadnav {__version__}")
        schema_ids = {
            name: self._writer.register_schema(name, SchemaEncoding.JSONSchema, json.dumps(schema).encode())
            for name, schema in S.SCHEMAS.items()
        }
        self._channels = {
            topic: self._writer.register_channel(topic, MessageEncoding.JSON, schema_ids[schema_name])
            for topic, schema_name in S.TOPICS.items()
        }
        self._writer.add_metadata("quadnav", {str(k): str(v) for k, v in metadata.items()})
        self._writer.add_metadata(
            "recorder",
            {
                "format": S.FORMAT,
                "format_version": str(S.FORMAT_VERSION),
                "depth_decimation": str(int(depth_decimation)),
                "unix_minus_mono_s": repr(float(unix_minus_mono_s)),
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

    @staticmethod
    def encode(kind: str, t: float, p: Any) -> list[tuple[str, dict[str, Any]]]:
        """The (topic, message) pairs of one item; raises ValueError/TypeError if it is invalid."""
        if kind == "depth":
            return [("/camera/depth", S.encode_depth(t, p))]
        if kind == "input":
            return [("/planner/input", S.encode_network_input(t, p[0], p[1]))]
        if kind == "odom":
            return [("/odometry", S.encode_odometry(t, *p))]
        if kind == "setpoint":
            sp, pose = S.encode_setpoint(t, *p)
            return [("/setpoint", sp), ("/setpoint/pose", pose)]
        if kind == "path":
            return [("/planner/path", S.encode_path(t, p))]
        if kind == "step":
            msg = S.encode_step(t, **p)
            return [
                ("/planner/step", msg),
                ("/planner/moving_setpoint", S.encode_moving_setpoint(t, p["moving_setpoint_world_m"])),
            ]
        if kind == "vehicle":
            return [("/vehicle", S.encode_vehicle(t, *p))]
        if kind == "event":
            return [("/events", S.encode_event(t, *p))]
        raise ValueError(f"unknown message kind {kind!r}")

    def write(self, kind: str, t: float, payload: Any) -> None:
        """Encode and write one item; an invalid one is counted (:attr:`invalid`) and skipped.
        Disk errors (OSError) propagate to the owner."""
        if kind == "metadata":
            self._writer.add_metadata(*payload)
            return
        try:
            messages = self.encode(kind, t, payload)
            blobs = [(topic, _json(msg)) for topic, msg in messages]
        except (ValueError, TypeError) as exc:
            self.invalid += 1
            if self._on_invalid is not None:
                self._on_invalid(kind, str(exc))
            return
        t_ns = S.to_ns(t)
        for topic, data in blobs:
            self._writer.add_message(
                self._channels[topic], log_time=t_ns, data=data, publish_time=t_ns, sequence=self._seq
            )
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
        t_ns = S.to_ns(t_stop)
        data = _json(S.encode_stop(t_stop, reason, summary, drops))
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
