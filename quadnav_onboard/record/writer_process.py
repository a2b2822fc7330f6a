"""The recorder's writer process: encodes and writes a flight record away from the flight's GIL.

:class:`~quadnav_onboard.record.recorder.FlightRecorder` with ``writer="process"`` starts
``python -m quadnav_onboard.record.writer_process FD``, FD being the record file it opened. The
parent sends length-prefixed pickled frames on this process's stdin:

- ``("open", options)`` first: metadata, depth_decimation, unix_minus_mono_s, chunk_size, fsync,
  flush_interval_s;
- ``("batch", [(kind, t_mono_s, payload), ...])``: items as the recorder queued them;
- ``("stop", t_mono_s, reason, summary, drops)``: finish the file; then stdin is closed.

This process answers with JSON lines on stdout: ``{"ready": true}``, ``{"invalid": kind,
"error": ...}`` per item it could not encode, ``{"failed": ...}`` on a write error (then it exits
1), ``{"closed": {"invalid": n}}`` once the file is finished.

It ignores SIGINT and SIGTERM: the flight process decides when the record ends (Ctrl-C on a
terminal and ``systemctl stop`` reach the whole process group). If the flight process dies
without a stop (stdin reaches EOF first), the record is finished with the stop reason
``flight_process_lost``. SIGKILL of both (power loss, systemd's final kill) leaves a file that
:func:`quadnav_onboard.record.reader.read_record` reads up to its last flushed chunk.
"""

from __future__ import annotations

import contextlib
import json
import os
import pickle
import select
import signal
import struct
import sys
import time
from typing import Any, BinaryIO

__all__ = ["HEADER", "LOST_REASON", "FrameReader", "main", "write_frame"]

HEADER = struct.Struct("<I")
"""Frame header: the pickled body's length in bytes."""
LOST_REASON = "flight_process_lost"
"""Stop reason of a record whose flight process died before closing it."""


def write_frame(pipe: BinaryIO, obj: Any) -> None:
    """Send one frame (blocks while the pipe is full; raises OSError/BrokenPipeError)."""
    body = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    pipe.write(HEADER.pack(len(body)))
    pipe.write(body)
    pipe.flush()


class FrameReader:
    """Read frames from a file descriptor with a timeout (``select``), buffering partial ones."""

    def __init__(self, fd: int) -> None:
        self._fd = fd
        self._buf = bytearray()
        self._eof = False

    def _complete(self) -> bytes | None:
        if len(self._buf) < HEADER.size:
            return None
        (n,) = HEADER.unpack_from(self._buf)
        if len(self._buf) < HEADER.size + n:
            return None
        body = bytes(self._buf[HEADER.size : HEADER.size + n])
        del self._buf[: HEADER.size + n]
        return body

    def next(self, timeout_s: float | None) -> Any | None:
        """The next frame's object; None when ``timeout_s`` passes first; EOFError at the end
        (a partial frame left by a dying sender is discarded)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            body = self._complete()
            if body is not None:
                return pickle.loads(body)
            if self._eof:
                raise EOFError
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            ready, _, _ = select.select([self._fd], [], [], wait)
            if not ready:
                return None
            chunk = os.read(self._fd, 1 << 20)
            if not chunk:
                self._eof = True
            self._buf += chunk


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    # stdout carries the status lines; anything else printed goes to stderr
    status = os.fdopen(os.dup(1), "w", buffering=1, encoding="utf-8")
    os.dup2(2, 1)

    def say(**msg: Any) -> None:
        with contextlib.suppress(OSError):  # the parent is gone; the record is still finished
            status.write(json.dumps(msg, default=str) + "\n")

    from quadnav_onboard.record.sink import McapSink

    reader = FrameReader(sys.stdin.fileno())
    try:
        kind, opts = reader.next(None)
        if kind != "open":
            raise ValueError(f"first frame must be 'open', got {kind!r}")
        file = os.fdopen(int(args[0]), "wb")
        sink = McapSink.from_options(file, opts, lambda k, e: say(invalid=k, error=e))
    except (OSError, ValueError, EOFError, IndexError, KeyError, TypeError, pickle.UnpicklingError) as exc:
        say(failed=f"{type(exc).__name__}: {exc}")
        return 1
    say(ready=True)
    flush_s = float(opts["flush_interval_s"])
    last_flush = time.monotonic()
    try:
        while True:
            try:
                frame = reader.next(max(0.0, last_flush + flush_s - time.monotonic()))
            except EOFError:
                sink.finish(
                    time.monotonic(),
                    LOST_REASON,
                    {"detail": "the flight process ended without closing the record (killed or crashed)"},
                    {"invalid": sink.invalid},
                )
                return 0
            if frame is not None and frame[0] == "batch":
                for item in frame[1]:
                    sink.write(*item)
            elif frame is not None and frame[0] == "stop":
                _, t_stop, reason, summary, drops = frame
                drops = {**drops, "invalid": drops.get("invalid", 0) + sink.invalid}
                sink.finish(t_stop, reason, summary, drops)
                say(closed={"invalid": sink.invalid})
                return 0
            if time.monotonic() - last_flush >= flush_s:
                sink.flush()
                last_flush = time.monotonic()
    except Exception as exc:  # a disk error: say so, keep what is on disk
        say(failed=f"{type(exc).__name__}: {exc}")
        sink.close_file()
        return 1


if __name__ == "__main__":
    sys.exit(main())
