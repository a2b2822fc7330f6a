"""What the daemon tells its service manager: the interface
(:class:`quadnav_onboard.sdnotify.SdNotifier` fits it) and the stand-in used outside systemd."""

from __future__ import annotations

from typing import Protocol

__all__ = ["Notifier", "NullNotifier"]


class Notifier(Protocol):
    """READY, STATUS, the watchdog's pings and STOPPING, as the daemon sends them."""

    def ready(self, status: str | None = None) -> bool: ...
    def watchdog(self) -> bool: ...
    def status(self, text: str) -> bool: ...
    def stopping(self) -> bool: ...
    def watchdog_interval_s(self) -> float | None: ...
    def close(self) -> None: ...


class NullNotifier:
    """Stands in for :class:`~quadnav_onboard.sdnotify.SdNotifier` when not under systemd."""

    def ready(self, status: str | None = None) -> bool:
        return False

    def watchdog(self) -> bool:
        return False

    def status(self, text: str) -> bool:
        return False

    def stopping(self) -> bool:
        return False

    def watchdog_interval_s(self) -> float | None:
        return None

    def close(self) -> None:
        return None
