"""The flight recorder: one MCAP file per flight, written by a thread that never blocks the caller.

The control loop calls the recorder's methods (all take ``t_mono_s``, the ``time.monotonic()``
time of the datum, first). Each call copies its arguments into one of two bounded queues and
returns; a writer thread hands what is queued to the writer (:class:`~.sink.McapSink`), which
encodes (Foxglove's well-known schemas through its SDK, protobuf; JSON for quadnav's own, see
:mod:`schemas` and :mod:`scene`), compresses (zstd chunks with CRCs) and writes. With
``writer="process"`` (what the flight daemon uses) the encoding and writing run in a child process
(:mod:`writer_process`), so they never hold the flight process's GIL; the writer thread then only
pickles batches into a pipe. With ``writer="thread"`` (evaluation records, tests) they run in the
writer thread itself. Log times are wall-clock (UTC): ``t_mono_s`` plus the offset taken when the
recorder was made (:mod:`schemas`). Under pressure the recorder sheds load in this order:

1. raw depth is decimated at the source (``depth_decimation``: 1 frame in N is kept);
2. kept depth frames wait in a small queue of their own; when it is full, or the control queue
   is more than half full, new depth frames are dropped and counted (``drop_counts['depth']``);
3. control data (decisions, network inputs, odometry, setpoints, vehicle state, events, the
   scene: camera, geofence, world, PX4's clock) is never
   dropped while its queue has room; only a writer stalled long enough to fill ``queue_size``
   entries drops control data, counted apart (``drop_counts['control']``).

Durability: every ``flush_interval_s`` the writer closes the open chunk, flushes and (by
default) fsyncs, so a process killed with SIGKILL, or a power cut, loses at most that interval.
:func:`quadnav_onboard.record.reader.read_record` reads such a cut-off record. A writer process
whose flight process dies without closing the record finishes it itself (stop reason
``flight_process_lost``).

A write error (disk full, unplugged, the writer process gone) never reaches the caller: the
recorder logs it once, stops writing and counts further calls as ``drop_counts['failed']``.

A record is never opened over an existing file (``O_EXCL``): :meth:`FlightRecorder.new_in` names
each flight's record by its UTC start time to the microsecond and, should that name be taken (two
flights started together, a clock stepped back), takes the next free ``-2``, ``-3``, ... suffix.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import json
import math
import os
import pickle
import subprocess
import sys
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from quadnav_onboard.logs import get_logger
from quadnav_onboard.record.protocol import NullRecorder, Recorder
from quadnav_onboard.record.schemas import to_jsonable
from quadnav_onboard.record.sink import Item, McapSink
from quadnav_onboard.step import StepRecord

__all__ = [  # NullRecorder, Recorder and RecorderError are re-exported by quadnav_onboard.record
    "FlightRecorder",
    "NullRecorder",
    "RecordExistsError",
    "Recorder",
    "RecorderError",
    "record_name",
]

_log = get_logger("quadnav.record")


class RecorderError(OSError):
    """The record file cannot be created (the message names the path and the reason)."""


class RecordExistsError(RecorderError):
    """A file already exists where the record would be written; it is left as it was."""


_MAX_SUFFIX = 1000
"""Names :meth:`FlightRecorder.new_in` tries for one time stamp before giving up."""


def record_name(t_unix_s: float, n: int = 1) -> str:
    """The record file name of a flight started at ``t_unix_s`` (UTC, to the microsecond), the
    ``n``-th to take that time stamp: ``flight-20261202-061500.123456.mcap``, then ``...-2.mcap``."""
    whole = int(t_unix_s // 1)
    micro = min(int((t_unix_s - whole) * 1e6), 999_999)
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime(whole)) + f".{micro:06d}"
    return f"flight-{stamp}{'' if n == 1 else f'-{n}'}.mcap"


_IMAGES_PER_BATCH = 4
"""Depth frames the writer takes per batch after the control data (80/s at 50 ms batches)."""


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
    ``batch_interval_s``: the writer thread wakes this often while the flight runs and takes all
    that is queued (one wake-up and one delivery per interval, not per call). ``writer``:
    ``"thread"`` encodes and writes in a thread of this process, ``"process"`` in a child process
    (started here; a failure to start raises :class:`RecorderError`).
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
        writer: Literal["thread", "process"] = "thread",
        batch_interval_s: float = 0.05,
    ) -> None:
        if depth_decimation < 0 or queue_size < 1 or image_queue_size < 1 or flush_interval_s <= 0:
            raise ValueError(
                "depth_decimation must be >= 0, queue sizes >= 1 and flush_interval_s > 0; got "
                f"{depth_decimation}, {queue_size}, {image_queue_size}, {flush_interval_s}"
            )
        if not 0 < batch_interval_s <= flush_interval_s:
            raise ValueError(f"batch_interval_s must be in (0, flush_interval_s], got {batch_interval_s}")
        if writer not in ("thread", "process"):
            raise ValueError(f"writer must be 'thread' or 'process', got {writer!r}")
        self.path = Path(path)
        self.depth_decimation = int(depth_decimation)
        self.writer = writer
        self._queue_size = int(queue_size)
        self._image_queue_size = int(image_queue_size)
        self._flush_interval_s = float(flush_interval_s)
        self._batch_interval_s = float(batch_interval_s)
        self._control: collections.deque[Item] = collections.deque()
        self._images: collections.deque[Item] = collections.deque()
        self._cond = threading.Condition()
        self._closing = False
        self._closed = False
        self._failed: BaseException | None = None
        self._stop: tuple[float, str, dict[str, Any]] | None = None
        self._depth_seen = itertools.count()  # next() is atomic: no lock for the frames not kept
        self._drops: dict[str, int] = {"depth": 0, "control": 0, "failed": 0, "invalid": 0}
        self._local_invalid = 0  # invalid items caught in this process (the rest: by a writer process)
        self._prims_sent: Any = None  # the primitive set the writer was last given
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            file = open(self.path, "xb")  # noqa: SIM115 - handed to the writer, which closes it
        except FileExistsError:
            raise RecordExistsError(
                f"{self.path}: cannot create flight record: the file exists (a record is never written over)"
            ) from None
        except OSError as exc:
            raise RecorderError(f"{self.path}: cannot create flight record: {exc.strerror or exc}") from None
        options = {
            "metadata": {str(k): str(v) for k, v in metadata.items()},
            "depth_decimation": self.depth_decimation,
            "unix_minus_mono_s": time.time() - time.monotonic(),
            "chunk_size": int(chunk_size),
            "fsync": bool(fsync),
            "flush_interval_s": self._flush_interval_s,
        }
        self._backend: _ThreadWriter | _ProcessWriter
        if writer == "process":
            self._backend = _ProcessWriter(self.path, file, options, self)
        else:
            try:
                self._backend = _ThreadWriter(file, options, self._invalid_found)
            except OSError as exc:
                file.close()
                raise RecorderError(f"{self.path}: cannot write flight record: {exc}") from None
        self._thread = threading.Thread(target=self._run, name="flight-recorder", daemon=True)
        self._thread.start()

    @classmethod
    def new_in(cls, directory: str | Path, *, t_unix_s: float | None = None, **kwargs: Any) -> FlightRecorder:
        """A recorder writing a new file in ``directory``, named by :func:`record_name` for
        ``t_unix_s`` (default: now); a name already taken, even by a flight starting at the same
        moment, moves on to the next suffix. ``kwargs``: as for the constructor."""
        t = time.time() if t_unix_s is None else float(t_unix_s)
        for n in range(1, _MAX_SUFFIX + 1):
            try:
                return cls(Path(directory) / record_name(t, n), **kwargs)
            except RecordExistsError:
                continue
        raise RecordExistsError(
            f"{Path(directory) / record_name(t)}: cannot create flight record: {_MAX_SUFFIX} files of that "
            "time stamp exist"
        )

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
    def writer_pid(self) -> int | None:
        """Process id of the writer process (``writer="process"``), else None."""
        return self._backend.proc.pid if isinstance(self._backend, _ProcessWriter) else None

    @property
    def error(self) -> BaseException | None:
        """The write error that stopped recording, if any."""
        return self._failed

    def _put(self, kind: str, t_mono_s: float, payload: Any, *, image: bool = False) -> bool:
        """Queue one item; False when it was dropped (counted)."""
        with self._cond:
            if not _valid_t(t_mono_s):
                self._drops["invalid"] += 1
                self._local_invalid += 1
                _log.error("recorder_invalid_time", kind=kind, t_mono_s=repr(t_mono_s))
                return False
            t = float(t_mono_s)
            if self._closing or self._failed is not None:
                self._drops["failed"] += 1
                return False
            if image:
                if len(self._images) >= self._image_queue_size or len(self._control) > self._queue_size // 2:
                    self._drops["depth"] += 1
                    return False
                self._images.append((kind, t, payload))
                return True
            else:
                if len(self._control) >= self._queue_size:
                    self._drops["control"] += 1
                    return False
                self._control.append((kind, t, payload))
                if len(self._control) == self._queue_size // 4:
                    self._cond.notify()  # a burst: drain now rather than at the next batch
                return True

    def depth(self, t_mono_s: float, depth_mm: np.ndarray) -> None:
        """A raw depth frame (uint16 mm, (H, W), 0 = invalid); 1 in ``depth_decimation`` is kept."""
        n = next(self._depth_seen)
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
        primitive: Any = None,
    ) -> None:
        """One planner decision given field by field (units and frames as
        :class:`~quadnav_onboard.step.StepRecord`'s; ``reward_terms`` may give ``d_prev_m``,
        ``d_now_m``, ``deviated`` and ``collided``; the fields it cannot give are recorded as NaN,
        False or 0). :meth:`step_record` records the core's typed record itself. ``primitive``: as
        for :meth:`step_record`."""
        drawn = self._drawn(t_mono_s, primitive)
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
            "primitive": drawn,
        }
        self._put("step", t_mono_s, decision)

    def step_record(
        self, t_mono_s: float, record: StepRecord, *, latency_ms: float = math.nan, primitive: Any = None
    ) -> None:
        """One executed planner step: the core's typed record (N = 1) as ``/planner/step``
        (``quadnav.Step``, its fields; :mod:`step_msg`), decided at ``t_mono_s``, with
        ``latency_ms`` (depth capture to setpoint sent, ms). The record is handed to the writer as
        it is, not copied: its arrays must not be written into afterwards (:func:`~quadnav_onboard.
        step.finish_step` makes new ones for every step). ``primitive``: the commanded primitive
        (an :class:`~quadnav_onboard.daemon.mission.ActivePrimitive`: its primitive set, commanded
        start, start velocity and heading), drawn with every other primitive of its set and the
        filter's verdict on ``/planner/primitives``; None draws nothing."""
        if not isinstance(record, StepRecord) or record.n != 1:
            with self._cond:
                self._drops["invalid"] += 1
                self._local_invalid += 1
            why = f"not a one-vehicle StepRecord: {type(record).__name__}"
            _log.error("recorder_invalid_message", kind="step", error=why)
            return
        self._put("step", t_mono_s, (record, float(latency_ms), self._drawn(t_mono_s, primitive)))

    def _drawn(self, t_mono_s: float, primitive: Any) -> tuple[np.ndarray, np.ndarray, float] | None:
        """What the writer needs to draw ``primitive`` (its set is sent the first time it is seen)."""
        if primitive is None:
            return None
        prims = primitive.primitives
        if prims is not self._prims_sent and self._put("primitive_set", t_mono_s, prims):
            self._prims_sent = prims  # sent once; again only if it changes (or was dropped)
        return (
            np.array(primitive.start_world_m, dtype=np.float64),
            np.array(primitive.start_vel_world_m_s, dtype=np.float64),
            float(primitive.yaw_rad),
        )

    def camera(
        self,
        t_mono_s: float,
        *,
        width_px: int,
        height_px: int,
        hfov_deg: float,
        vfov_deg: float,
        offset_body_m: ArrayLike = (0.0, 0.0, 0.0),
    ) -> None:
        """The depth camera: image size, fields of view (a pinhole model, ``CameraCalibration``)
        and its mount (``offset_body_m``: forward, left, up of the body origin, m; looking along
        body +x), the ``body -> camera_depth_optical`` transform. Call once, before the flight."""
        offset = np.array(offset_body_m, dtype=np.float64).reshape(3)
        model = (int(width_px), int(height_px), float(hfov_deg), float(vfov_deg), offset)
        self._put("camera", t_mono_s, model)

    def geofence(self, t_mono_s: float, min_m: ArrayLike, max_m: ArrayLike) -> None:
        """The geofence (world box, m: its lowest and highest corner), drawn in the 3-D scene."""
        box = (np.array(min_m, dtype=np.float64), np.array(max_m, dtype=np.float64))
        self._put("geofence", t_mono_s, box)

    def world(self, t_mono_s: float, world: Mapping[str, Any]) -> None:
        """The world flown (the sim harness's world-file mapping, ``sim_harness.world``): its
        obstacles, floor and ceiling in the 3-D scene, its YAML as metadata ``world``. Dry runs."""
        self._put("world", t_mono_s, to_jsonable(dict(world)))

    def px4_time(self, t_mono_s: float, px4_boot_us: int, px4_unix_us: int = 0) -> None:
        """PX4's clock: a MAVLink SYSTEM_TIME (``time_boot_ms`` as us, ``time_unix_usec``) that
        arrived at ``t_mono_s``; lines the record up with the flight's ULog."""
        self._put("px4_time", t_mono_s, (int(px4_boot_us), int(px4_unix_us)))

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

    def _invalid_found(self, kind: str, error: str) -> None:
        """The writer could not encode an item: count it and say what it was."""
        with self._cond:
            self._drops["invalid"] += 1
        _log.error("recorder_invalid_message", kind=kind, error=error)

    def _fail(self, exc: BaseException) -> None:
        """Stop recording after a write error (logged once); what is queued is counted as lost."""
        with self._cond:
            if self._failed is not None:
                return
            self._failed = exc
            self._drops["failed"] += len(self._control) + len(self._images)
            self._control.clear()
            self._images.clear()
        _log.error("recorder_write_failed", path=str(self.path), error=repr(exc), writer=self.writer)

    def _deliver(self, batch: list[Item]) -> None:
        """Hand one batch to the writer (a test may stall this to play a slow disk)."""
        self._backend.deliver(batch)

    def _take(self) -> tuple[list[Item], bool]:
        """Wait one batch interval (less on a burst or at close); return the control items queued,
        then at most ``_IMAGES_PER_BATCH`` images, and whether to stop."""
        with self._cond:
            if not self._closing:
                self._cond.wait(timeout=self._batch_interval_s)
            batch = list(self._control)
            self._control.clear()
            for _ in range(min(_IMAGES_PER_BATCH, len(self._images))):
                batch.append(self._images.popleft())
            done = self._closing and not self._control and not self._images
            return batch, done

    def _run(self) -> None:
        try:
            while self._failed is None:
                batch, done = self._take()
                if batch:
                    self._deliver(batch)
                if done:
                    break
                self._backend.tick()
            if self._failed is None:
                assert self._stop is not None
                t_stop, reason, summary = self._stop
                with self._cond:
                    drops = dict(self._drops)
                self._backend.finish(t_stop, reason, summary, drops, self._local_invalid)
        except Exception as exc:  # a disk error must not take the flight down with it
            self._fail(exc)
        finally:
            self._backend.abort()
            self._closed = True


class _ThreadWriter:
    """Encode and write in the recorder's own writer thread."""

    def __init__(self, file: Any, options: dict[str, Any], on_invalid: Any) -> None:
        self._flush_interval_s = options["flush_interval_s"]
        self.sink = McapSink.from_options(file, options, on_invalid)
        self._last_flush = time.monotonic()

    def deliver(self, batch: list[Item]) -> None:
        for item in batch:
            self.sink.write(*item)

    def tick(self) -> None:
        if time.monotonic() - self._last_flush >= self._flush_interval_s:
            self.sink.flush()
            self._last_flush = time.monotonic()

    def finish(
        self, t_stop: float, reason: str, summary: dict[str, Any], drops: dict[str, int], local_invalid: int
    ) -> None:
        self.sink.finish(t_stop, reason, summary, drops)

    def abort(self) -> None:
        self.sink.close_file()


class _ProcessWriter:
    """Encode and write in a child process (:mod:`writer_process`); this side pickles batches into
    its stdin and reads its status lines in a thread of its own."""

    START_TIMEOUT_S = 30.0

    def __init__(self, path: Path, file: Any, options: dict[str, Any], recorder: FlightRecorder) -> None:
        # imported here, not at the top: ``python -m`` of a module that its package's __init__
        # already imported would warn (and run it twice)
        from quadnav_onboard.record import writer_process

        self._frame = writer_process.write_frame
        self._recorder = recorder
        self._ready = threading.Event()
        self._done = threading.Event()
        self._start_error: str | None = None
        self._child_invalid: int | None = None
        # the child imports this very copy of quadnav_onboard, installed or not
        package_root = str(Path(writer_process.__file__).resolve().parents[2])
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (package_root, env.get("PYTHONPATH", "")) if p)
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "quadnav_onboard.record.writer_process", str(file.fileno())],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                pass_fds=(file.fileno(),),
                env=env,
            )
        except OSError as exc:
            file.close()
            raise RecorderError(f"{path}: cannot start the recorder's writer process: {exc}") from None
        file.close()  # the child holds it now
        self._status = threading.Thread(target=self._read_status, name="flight-recorder-status", daemon=True)
        self._status.start()
        try:
            assert self.proc.stdin is not None
            self._frame(self.proc.stdin, ("open", options))
        except OSError:
            pass  # the child died at once: its status says why (below)
        if not self._ready.wait(self.START_TIMEOUT_S) or self._start_error is not None:
            self.abort()
            why = self._start_error or f"no answer within {self.START_TIMEOUT_S:.0f} s"
            raise RecorderError(f"{path}: the recorder's writer process did not start: {why}")

    def _read_status(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            try:
                msg = json.loads(line)
            except ValueError:
                continue
            if "ready" in msg:
                self._ready.set()
            elif "invalid" in msg:
                self._recorder._invalid_found(str(msg["invalid"]), str(msg.get("error", "")))
            elif "failed" in msg:
                if not self._ready.is_set():
                    self._start_error = str(msg["failed"])
                    self._ready.set()
                else:
                    self._recorder._fail(OSError(f"writer process: {msg['failed']}"))
            elif "closed" in msg:
                self._child_invalid = int(msg["closed"].get("invalid", 0))
        code = self.proc.wait()
        if not self._ready.is_set():
            self._start_error = self._start_error or f"it exited with code {code}"
            self._ready.set()
        elif self._child_invalid is None and not self._recorder._closed:
            why = f"writer process exited with code {code} before the record was closed"
            self._recorder._fail(OSError(why))
        self._done.set()

    def deliver(self, batch: list[Item]) -> None:
        assert self.proc.stdin is not None
        try:
            self._frame(self.proc.stdin, ("batch", batch))
        except (pickle.PicklingError, TypeError, AttributeError):  # nothing was sent: find the culprit
            kept = []
            for item in batch:
                try:
                    pickle.dumps(item, protocol=pickle.HIGHEST_PROTOCOL)
                    kept.append(item)
                except (pickle.PicklingError, TypeError, AttributeError) as exc:
                    with self._recorder._cond:
                        self._recorder._local_invalid += 1
                    self._recorder._invalid_found(item[0], f"cannot be sent to the writer process: {exc}")
            self._frame(self.proc.stdin, ("batch", kept))

    def tick(self) -> None:
        return None  # the child flushes on its own clock

    def finish(
        self, t_stop: float, reason: str, summary: dict[str, Any], drops: dict[str, int], local_invalid: int
    ) -> None:
        assert self.proc.stdin is not None
        self._frame(self.proc.stdin, ("stop", t_stop, reason, summary, {**drops, "invalid": local_invalid}))
        self.proc.stdin.close()
        if not self._done.wait(timeout=10.0):
            raise OSError("writer process did not finish the record within 10 s")
        if self._child_invalid is None:
            code = self.proc.returncode
            raise OSError(f"writer process exited with code {code} without finishing the record")
        with self._recorder._cond:
            self._recorder._drops["invalid"] = local_invalid + self._child_invalid

    def abort(self) -> None:
        with contextlib.suppress(OSError):
            if self.proc.stdin is not None:
                self.proc.stdin.close()
        try:
            self.proc.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
