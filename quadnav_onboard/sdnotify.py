"""systemd readiness and watchdog notifications (the ``sd_notify`` datagram protocol, no dependency).

Under ``Type=notify`` systemd passes ``NOTIFY_SOCKET`` (a filesystem path, or ``@name`` for the
abstract namespace) and, with ``WatchdogSec=``, ``WATCHDOG_USEC`` (+ ``WATCHDOG_PID``). Each message
is one AF_UNIX datagram of ``KEY=VALUE`` lines. Without ``NOTIFY_SOCKET`` (a shell, a test, a
container) every call is a no-op, so the daemon can call it unconditionally.

How the daemon uses it (see docs/hardware.md, "systemd"):

* ``ready()`` once preflight has passed (never before: ``systemctl start`` returns only then);
* ``watchdog()`` from the *main loop itself*, once per iteration (or :class:`WatchdogFeeder` to
  rate-limit a fast loop). Never from a separate timer task: a timer keeps pinging while the main
  loop is stuck on a hung await, which is the very failure the watchdog exists to catch;
* ``stopping()`` when a graceful stop begins; ``status(text)`` for ``systemctl status``.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable, Mapping

from quadnav_onboard.logs import get_logger

__all__ = ["SdNotifier", "WatchdogFeeder"]

_log = get_logger(__name__)


class SdNotifier:
    """Sends ``sd_notify`` messages to ``socket_path``; inert when ``socket_path`` is None."""

    def __init__(self, socket_path: str | None, watchdog_timeout_s: float | None = None) -> None:
        self._path = socket_path or None
        self._watchdog_timeout_s = watchdog_timeout_s
        self._sock: socket.socket | None = None
        self._warned = False

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> SdNotifier:
        """Build from ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID`` (``os.environ`` by default).

        The watchdog is ours only if ``WATCHDOG_PID`` is unset or equals this process's pid (the
        variables may have been inherited from a parent that systemd actually watches).
        """
        env = os.environ if environ is None else environ
        timeout_s: float | None = None
        usec, pid = env.get("WATCHDOG_USEC", ""), env.get("WATCHDOG_PID", "")
        if usec.isdigit() and int(usec) > 0 and (not pid or pid == str(os.getpid())):
            timeout_s = int(usec) / 1e6
        return cls(env.get("NOTIFY_SOCKET") or None, timeout_s)

    @property
    def enabled(self) -> bool:
        """True when running under a service manager that listens (``NOTIFY_SOCKET`` set)."""
        return self._path is not None

    def watchdog_timeout_s(self) -> float | None:
        """The unit's ``WatchdogSec`` (s): no ping for this long and systemd kills us; None if off."""
        return self._watchdog_timeout_s if self.enabled else None

    def watchdog_interval_s(self) -> float | None:
        """How often to ping (s): half of ``WatchdogSec``, as sd_watchdog_enabled(3) advises; None if off."""
        timeout_s = self.watchdog_timeout_s()
        return None if timeout_s is None else timeout_s / 2.0

    def notify(self, *fields: str) -> bool:
        """Send one datagram of ``KEY=VALUE`` lines; True if sent, False if inert or it failed.

        A failure is logged once, never raised: losing systemd must not stop a flight.
        """
        if self._path is None:
            return False
        addr = "\0" + self._path[1:] if self._path.startswith("@") else self._path
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            # Non-blocking: a listener that stops reading must never stall the flight loop.
            self._sock.sendto("\n".join(fields).encode("utf-8"), socket.MSG_DONTWAIT, addr)
        except OSError as exc:
            if not self._warned:
                _log.warning("sd_notify failed", socket=self._path, error=str(exc))
                self._warned = True
            return False
        return True

    def ready(self, status: str | None = None) -> bool:
        """Tell systemd that start-up (preflight) is done: ``READY=1``."""
        return self.notify("READY=1", *([f"STATUS={status}"] if status else []))

    def watchdog(self) -> bool:
        """Feed the watchdog: ``WATCHDOG=1``. Call from the main loop, not from a timer."""
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        """Free-form one-line status shown by ``systemctl status``."""
        return self.notify("STATUS=" + " ".join(text.splitlines()))

    def stopping(self) -> bool:
        """Tell systemd that a graceful stop has begun: ``STOPPING=1``."""
        return self.notify("STOPPING=1")

    def close(self) -> None:
        """Close the socket (later calls reopen it)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None


class WatchdogFeeder:
    """Rate-limits ``WATCHDOG=1`` for a loop faster than the watchdog needs (e.g. a 50 Hz setpoint loop).

    Call :meth:`kick` once per main-loop iteration; it pings at most every ``min_period_s`` of the
    monotonic ``clock`` (default: a quarter of ``WatchdogSec``).
    """

    def __init__(
        self,
        notifier: SdNotifier,
        min_period_s: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._notifier = notifier
        timeout_s = notifier.watchdog_timeout_s()
        if min_period_s is None:
            min_period_s = timeout_s / 4.0 if timeout_s is not None else 1.0
        self._min_period_s = min_period_s
        self._clock = clock
        self._last_mono_s: float | None = None

    def kick(self) -> bool:
        """Ping if ``min_period_s`` has passed since the last ping; True if a ping was sent."""
        now_s = self._clock()
        if self._last_mono_s is not None and now_s - self._last_mono_s < self._min_period_s:
            return False
        self._last_mono_s = now_s
        return self._notifier.watchdog()
