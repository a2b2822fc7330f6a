"""Free UDP ports for stand-ins and tests: the onboard picker, re-exported."""

from __future__ import annotations

from quadnav_onboard.ports import free_udp_port

__all__ = ["free_udp_port"]
