"""The flight recorder: one MCAP file per flight, written by a thread that never blocks the caller.

The control loop calls the recorder's methods (all take ``t_mono_s``, the ``time.monotonic()``
time of the datum, first). Each call copies its arguments into one of two bounded queues and
returns; a writer thread encodes (JSON, see :mod:`schemas`), compresses (zstd chunks with CRCs)
and writes. Under pressure the recorder sheds load in this order:

1. raw depth is decimated at the source (``depth_decimation``: 1 frame in N is kept);
2. kept depth frames wait in a small queue of their own; when it is full, or the control queue
   is more than half full, new depth frames are dropped and counted (``drop_counts['depth']``);
3. control data (decisions, network inputs, odometry, setpoints, vehicle state, events) is never
   dropped while its queue has room; only a writer stalled long enough to fill ``queue_size``
   entries drops control data, counted apart (``drop_counts['control']``).

Durability: every ``flush_interval_s`` the writer closes the open chunk, flushes and (by
default) fsyncs, so a process killed with SIGKILL, or a power cut, loses at most that interval.
:func:`quadnav_onboard.record.reader.read_record` reads such a cut-off record.

A write error (disk full, unplugged) never reaches the caller: the recorder logs it once, stops
writing and counts further calls as ``drop_counts['failed']``.
"""

from __future__ import annotations

import collections
import contextlib
import json
import os
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer
from numpy.typing import ArrayLike

from quadnav_onboard import __version__
from quadnav_onboard.logs import get_logger
from quadnav_onboard.record import schemas as S
from quadnav_onboard.record.protocol import NullRecorder, Recorder

__all__ = ["FlightRecorder", "NullRecorder", "Recorder", "RecorderError"]  # the last three re-exported

_log = get_logger("quadnav.record")


class RecorderError(OSError):
    """The record file cannot be created (the message names the path and the reason)."""


def _valid_t(t_mono_s: float) -> bool:
    try:
        t = float(t_mono_s)
    except (TypeError, ValueError):
        return False
    return 0.0 <= t < float("inf")


class FlightRecorder:
    """Record one flight into an MCAP file at ``path`` (parent folders are created).

    ``metadata``: string key/values stored as the MCAP metadata record ``quadnav`` (config, model
    hash, world, ...). ``depth_decimation``: keep 1 raw depth frame in N (0 = none). ``queue_size``:
    control messages that may wait for the writer; ``image_queue_size``: depth frames that may wait.
    ``chunk_size``: bytes per MCAP chunk before compression. ``flush_interval_s``: most data (s) a
    SIGKILL can lose. ``fsync``: also fsync on each flush (power-loss safety).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        metadata: Mapping[str, str],
        depth_decimation: int = 5,
        queue_size: int = 4096,
        image_queue_size: int = 8,
        chunk_size: int = 256 * 1024,
        flush_interval_s: float = 1.0,
        fsync: bool = True,
    ) -> None:
        if depth_decimation < 0 or queue_size < 1 or image_queue_size < 1 or flush_interval_s <= 0:
            raise ValueError(
                "depth_decimation must be >= 0, queue sizes >= 1 and flush_interval_s > 0; got "
                f"{depth_decimation}, {queue_size}, {image_queue_size}, {flush_interval_s}"
            )
        self.path = Path(path)
        self.depth_decimation = int(depth_decimation)
        self._queue_size = int(queue_size)
        self._image_queue_size = int(image_queue_size)
        self._flush_interval_s = float(flush_interval_s)
        self._fsync = fsync
        self._control: collections.deque[tuple[str, float, Any]] = collections.deque()
        self._images: collections.deque[tuple[str, float, Any]] = collections.deque()
        self._cond = threading.Condition()
        self._closing = False
        self._closed = False
        self._failed: BaseException | None = None
        self._stop: tuple[float, str, dict[str, Any]] | None = None
        self._depth_seen = 0
        self._drops: dict[str, int] = {"depth": 0, "control": 0, "failed": 0, "invalid": 0}
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "wb")  # noqa: SIM115 - owned by the writer thread until close
        except OSError as exc:
            raise RecorderError(f"{self.path}: cannot create flight record: {exc.strerror or exc}") from None
        self._writer = Writer(
            self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD, enable_crcs=True
        )
        self._writer.start(profile="", library=f"quadnav {__version__}")
        self._channels: dict[str, int] = {}
        schema_ids = {
            name: self._writer.register_schema(name, SchemaEncoding.JSONSchema, json.dumps(schema).encode())
            for name, schema in S.SCHEMAS.items()
        }
        for topic, schema_name in S.TOPICS.items():
            self._channels[topic] = self._writer.register_channel(
                topic, MessageEncoding.JSON, schema_ids[schema_name]
            )
        self._writer.add_metadata("quadnav", {str(k): str(v) for k, v in metadata.items()})
        self._writer.add_metadata(
            "recorder",
            {
                "format": S.FORMAT,
                "format_version": str(S.FORMAT_VERSION),
                "depth_decimation": str(self.depth_decimation),
                "unix_minus_mono_s": repr(time.time() - time.monotonic()),
                "library": f"quadnav {__version__}",
            },
        )
        self._file.flush()
        self._seq = 0
        self._thread = threading.Thread(target=self._run, name="flight-recorder", daemon=True)
        self._thread.start()

    # -- caller side: copy, enqueue, return -------------------------------------------------

    @property
    def dropped(self) -> int:
        """Messages dropped so far, all kinds together (see :attr:`drop_counts`)."""
        with self._cond:
            return sum(self._drops.values())

    @property
    def drop_counts(self) -> dict[str, int]:
        """Dropped messages by cause: ``depth`` (load shedding), ``control`` (writer stalled with a
        full queue), ``failed`` (after a write error or close), ``invalid`` (could not be encoded)."""
        with self._cond:
            return dict(self._drops)

    @property
    def error(self) -> BaseException | None:
        """The write error that stopped recording, if any."""
        return self._failed

    def _put(self, kind: str, t_mono_s: float, payload: Any, *, image: bool = False) -> None:
        with self._cond:
            if not _valid_t(t_mono_s):
                self._drops["invalid"] += 1
                _log.error("recorder_invalid_time", kind=kind, t_mono_s=repr(t_mono_s))
                return
            t = float(t_mono_s)
            if self._closing or self._failed is not None:
                self._drops["failed"] += 1
                return
            if image:
                if len(self._images) >= self._image_queue_size or len(self._control) > self._queue_size // 2:
                    self._drops["depth"] += 1
                    return
                self._images.append((kind, t, payload))
            else:
                if len(self._control) >= self._queue_size:
                    self._drops["control"] += 1
                    return
                self._control.append((kind, t, payload))
            self._cond.notify()

    def depth(self, t_mono_s: float, depth_mm: np.ndarray) -> None:
        """A raw depth frame (uint16 mm, (H, W), 0 = invalid); 1 in ``depth_decimation`` is kept."""
        with self._cond:
            n = self._depth_seen
            self._depth_seen += 1
        if self.depth_decimation == 0 or n % self.depth_decimation:
            return
        self._put("depth", t_mono_s, np.array(depth_mm, dtype=np.uint16, copy=True), image=True)

    def network_input(self, t_mono_s: float, step: int, input_32: np.ndarray) -> None:
        """The planner's depth input at decision ``step`` (float32 (32, 32) in [0, 1]); every one."""
        self._put("input", t_mono_s, (int(step), np.array(input_32, dtype=np.float32, copy=True)))

    def odometry(
        self,
        t_mono_s: float,
        pos_world_m: ArrayLike,
        quat_world_body: ArrayLike,
        vel_world_m_s: ArrayLike | None = None,
    ) -> None:
        """Vehicle pose: position (world, m, (3,)), attitude (w, x, y, z) body -> world, velocity (m/s)."""
        vel = None if vel_world_m_s is None else np.array(vel_world_m_s, dtype=np.float64)
        self._put(
            "odom",
            t_mono_s,
            (np.array(pos_world_m, dtype=np.float64), np.array(quat_world_body, dtype=np.float64), vel),
        )

    def setpoint(
        self, t_mono_s: float, pos_world_m: ArrayLike, vel_world_m_s: ArrayLike, yaw_rad: float
    ) -> None:
        """A position setpoint sent to the autopilot (world frame, m, m/s, yaw rad)."""
        self._put(
            "setpoint",
            t_mono_s,
            (
                np.array(pos_world_m, dtype=np.float64),
                np.array(vel_world_m_s, dtype=np.float64),
                float(yaw_rad),
            ),
        )

    def rough_path(self, t_mono_s: float, waypoints_m: ArrayLike) -> None:
        """The rough path flown (world, m, (K, 3)); call once at mission start."""
        self._put("path", t_mono_s, np.array(waypoints_m, dtype=np.float64))

    def step(
        self,
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
    ) -> None:
        """One planner decision (see :func:`schemas.encode_step` for units and frames)."""
        decision = {
            "step": int(step),
            "action": int(action),
            "q_values": np.array(q_values, dtype=np.float64),
            "rel_pos_body_m": np.array(rel_pos_body_m, dtype=np.float64),
            "moving_setpoint_world_m": np.array(moving_setpoint_world_m, dtype=np.float64),
            "pos_world_m": np.array(pos_world_m, dtype=np.float64),
            "reward": float(reward),
            "reward_terms": dict(reward_terms),
            "progress_m": float(progress_m),
            "deviation_m": float(deviation_m),
            "latency_ms": float(latency_ms),
            "shield_allowed": None if shield_allowed is None else np.array(shield_allowed, dtype=bool),
            "shield_clearance_m": None if shield_clearance_m is None else np.array(shield_clearance_m),
        }
        self._put("step", t_mono_s, decision)

    def vehicle(self, t_mono_s: float, armed: bool, mode: str, health: Mapping[str, Any]) -> None:
        """Autopilot state: armed, flight mode name (e.g. "OFFBOARD", "HOLD") and health flags."""
        self._put("vehicle", t_mono_s, (bool(armed), str(mode), dict(health)))

    def event(self, t_mono_s: float, kind: str, message: str, **fields: Any) -> None:
        """A supervisor/daemon event (e.g. kind="failsafe"); ``level="warning"`` etc. sets severity."""
        self._put("event", t_mono_s, (str(kind), str(message), dict(fields)))

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """An extra MCAP metadata record (e.g. ``world`` once the world is known)."""
        self._put("metadata", 0.0, (str(name), {str(k): str(v) for k, v in data.items()}))

    def close(
        self, stop_reason: str, summary: Mapping[str, Any] | None = None, *, t_mono_s: float | None = None
    ) -> None:
        """Write why the flight stopped and its summary (at ``t_mono_s``, default now), finish the
        file (index, footer) and wait for the writer (at most ~10 s; a stalled disk leaves a record
        without footer, still readable). A second call does nothing."""
        t_stop = time.monotonic() if t_mono_s is None or not _valid_t(t_mono_s) else float(t_mono_s)
        with self._cond:
            if self._closing:
                return
            self._closing = True
            self._stop = (t_stop, str(stop_reason), dict(summary or {}))
            self._cond.notify()
        self._thread.join(timeout=10.0)
        if self._thread.is_alive():
            _log.warning("recorder_close_timeout", path=str(self.path))

    def __enter__(self) -> FlightRecorder:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        reason = "closed_without_reason" if exc_type is None else f"error:{exc_type.__name__}"
        self.close(reason, {})

    # -- writer thread -----------------------------------------------------------------------

    def _encode(self, kind: str, t: float, p: Any) -> list[tuple[str, dict[str, Any]]]:
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

    def _write(self, kind: str, t: float, payload: Any) -> None:
        if kind == "metadata":
            self._writer.add_metadata(*payload)
            return
        try:
            messages = self._encode(kind, t, payload)
        except (ValueError, TypeError) as exc:
            with self._cond:
                self._drops["invalid"] += 1
            _log.error("recorder_invalid_message", kind=kind, error=str(exc))
            return
        t_ns = S.to_ns(t)
        for topic, msg in messages:
            data = json.dumps(msg, separators=(",", ":"), allow_nan=False).encode()
            self._writer.add_message(
                self._channels[topic], log_time=t_ns, data=data, publish_time=t_ns, sequence=self._seq
            )
            self._seq += 1

    def _flush(self) -> None:
        self._writer.flush()
        if self._fsync:
            os.fsync(self._file.fileno())

    def _take(self) -> tuple[list[tuple[str, float, Any]], bool]:
        """Wait for work; return control items first, then at most two images, and whether to stop."""
        with self._cond:
            if not self._control and not self._images and not self._closing:
                self._cond.wait(timeout=self._flush_interval_s)
            batch = list(self._control)
            self._control.clear()
            for _ in range(min(2, len(self._images))):
                batch.append(self._images.popleft())
            done = self._closing and not self._control and not self._images
            return batch, done

    def _run(self) -> None:
        last_flush = time.monotonic()
        try:
            while True:
                batch, done = self._take()
                for kind, t, payload in batch:
                    self._write(kind, t, payload)
                if done:
                    break
                if time.monotonic() - last_flush >= self._flush_interval_s:
                    self._flush()
                    last_flush = time.monotonic()
            assert self._stop is not None
            t_stop, reason, summary = self._stop
            with self._cond:
                drops = dict(self._drops)
            stop = S.encode_stop(t_stop, reason, summary, drops)
            t_ns = S.to_ns(t_stop)
            data = json.dumps(stop, separators=(",", ":"), allow_nan=False).encode()
            self._writer.add_message(
                self._channels["/flight/stop"], log_time=t_ns, data=data, publish_time=t_ns
            )
            self._writer.finish()
            self._file.flush()
            if self._fsync:
                os.fsync(self._file.fileno())
        except Exception as exc:  # a disk error must not take the flight down with it
            self._failed = exc
            _log.error("recorder_write_failed", path=str(self.path), error=repr(exc))
            with self._cond:
                self._drops["failed"] += len(self._control) + len(self._images)
                self._control.clear()
                self._images.clear()
        finally:
            with contextlib.suppress(OSError):
                self._file.close()
            self._closed = True
