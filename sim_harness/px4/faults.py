"""Fault injection for the emulated PX4: scheduled windows of misbehaviour.

Times given to the methods are seconds from *now* (the call); a scenario file's times are seconds
from the emulator's start (it is applied at start, so the two agree). All methods are thread-safe:
tests call them from their own thread while the emulator thread queries them every tick.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["FaultWindow", "Faults"]


@dataclass(frozen=True)
class FaultWindow:
    """One fault active on [start_mono_s, end_mono_s) (monotonic seconds)."""

    kind: str
    """"drop_link", "delay_link", "freeze_position" or "crash"."""
    start_mono_s: float
    end_mono_s: float
    delay_s: float = 0.0
    """Extra one-way latency (s) for "delay_link"."""

    def active(self, t_mono_s: float) -> bool:
        return self.start_mono_s <= t_mono_s < self.end_mono_s


def _check_window(start_s: float, duration_s: float) -> None:
    if not (math.isfinite(start_s) and start_s >= 0.0):
        raise ValueError(f"fault start_s must be finite and >= 0, got {start_s!r}")
    if not (duration_s > 0.0):
        raise ValueError(f"fault duration_s must be > 0 (inf allowed), got {duration_s!r}")


class Faults:
    """The emulator's fault schedule (one per emulator)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self._windows: list[FaultWindow] = []
        self._denied: set[str] = set()
        self._crash_requested = False

    def _add(self, kind: str, start_s: float, duration_s: float, delay_s: float = 0.0) -> FaultWindow:
        _check_window(start_s, duration_s)
        t0 = self._clock() + start_s
        window = FaultWindow(kind, t0, t0 + duration_s, delay_s)
        with self._lock:
            self._windows.append(window)
        return window

    def drop_link(self, start_s: float, duration_s: float) -> FaultWindow:
        """Drop every MAVLink packet, both ways and on every link, during the window."""
        return self._add("drop_link", start_s, duration_s)

    def delay_link(self, start_s: float, duration_s: float, delay_s: float = 0.3) -> FaultWindow:
        """Delay every MAVLink packet, both ways, by ``delay_s`` seconds during the window."""
        if not (math.isfinite(delay_s) and delay_s > 0.0):
            raise ValueError(f"delay_s must be finite and > 0, got {delay_s!r}")
        return self._add("delay_link", start_s, duration_s, delay_s)

    def freeze_position(self, start_s: float, duration_s: float) -> FaultWindow:
        """The reported position (estimator output) stops updating during the window; the true
        pose, the camera and the mocap keep moving."""
        return self._add("freeze_position", start_s, duration_s)

    def deny_mode(self, mode: str) -> None:
        """Refuse (COMMAND_ACK DENIED) every switch to ``mode`` until :meth:`allow_mode`."""
        with self._lock:
            self._denied.add(mode)

    def allow_mode(self, mode: str) -> None:
        with self._lock:
            self._denied.discard(mode)

    def crash_at(self, start_s: float) -> FaultWindow:
        """Crash the vehicle ``start_s`` seconds from now."""
        return self._add("crash", start_s, math.inf)

    def crash_now(self) -> None:
        """Crash the vehicle at the next physics tick, as a collision would."""
        with self._lock:
            self._crash_requested = True

    def clear(self) -> None:
        """Remove every scheduled and standing fault."""
        with self._lock:
            self._windows.clear()
            self._denied.clear()
            self._crash_requested = False

    # --- queried by the emulator thread -------------------------------------------------------
    def active(self, kind: str, t_mono_s: float) -> FaultWindow | None:
        with self._lock:
            for w in self._windows:
                if w.kind == kind and w.active(t_mono_s):
                    return w
        return None

    def link_delay_s(self, t_mono_s: float) -> float:
        w = self.active("delay_link", t_mono_s)
        return 0.0 if w is None else w.delay_s

    def mode_denied(self, mode: str) -> bool:
        with self._lock:
            return mode in self._denied

    def take_crash_request(self) -> bool:
        with self._lock:
            requested, self._crash_requested = self._crash_requested, False
            return requested
