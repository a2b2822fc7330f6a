"""The recorder interface: what the daemon and the sim call, and the no-op stand-in.

:class:`~quadnav_onboard.record.recorder.FlightRecorder` writes MCAP; :class:`NullRecorder`
does nothing (recording switched off). Both take ``t_mono_s`` (``time.monotonic()`` s) first.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["NullRecorder", "Recorder"]


class Recorder(Protocol):
    """What the daemon and the sim call; :class:`FlightRecorder` and :class:`NullRecorder` fit."""

    def depth(self, t_mono_s: float, depth_mm: np.ndarray) -> None: ...
    def network_input(self, t_mono_s: float, step: int, input_32: np.ndarray) -> None: ...
    def odometry(
        self,
        t_mono_s: float,
        pos_world_m: ArrayLike,
        quat_world_body: ArrayLike,
        vel_world_m_s: ArrayLike | None = None,
    ) -> None: ...
    def setpoint(
        self, t_mono_s: float, pos_world_m: ArrayLike, vel_world_m_s: ArrayLike, yaw_rad: float
    ) -> None: ...
    def step(self, t_mono_s: float, **decision: Any) -> None: ...
    def step_record(
        self, t_mono_s: float, record: Any, *, latency_ms: float = ..., primitive: Any = None
    ) -> None: ...
    def camera(self, t_mono_s: float, **model: Any) -> None: ...
    def geofence(self, t_mono_s: float, min_m: ArrayLike, max_m: ArrayLike) -> None: ...
    def world(self, t_mono_s: float, world: Mapping[str, Any]) -> None: ...
    def px4_time(self, t_mono_s: float, px4_boot_us: int, px4_unix_us: int = 0) -> None: ...
    def vehicle(self, t_mono_s: float, armed: bool, mode: str, health: Mapping[str, Any]) -> None: ...
    def event(self, t_mono_s: float, kind: str, message: str, **fields: Any) -> None: ...
    def rough_path(self, t_mono_s: float, waypoints_m: ArrayLike) -> None: ...
    def add_metadata(self, name: str, data: Mapping[str, str]) -> None: ...
    def close(
        self, stop_reason: str, summary: Mapping[str, Any] | None = None, *, t_mono_s: float | None = None
    ) -> None: ...


class NullRecorder:
    """A recorder that records nothing (recording switched off); same methods, no cost."""

    dropped = 0
    drop_counts: Mapping[str, int] = {}
    path = None
    writer_pid = None

    def __enter__(self) -> NullRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def depth(self, t_mono_s: float, depth_mm: np.ndarray) -> None:
        return None

    def network_input(self, t_mono_s: float, step: int, input_32: np.ndarray) -> None:
        return None

    def odometry(
        self, t_mono_s: float, pos_world_m: Any, quat_world_body: Any, vel_world_m_s: Any = None
    ) -> None:
        return None

    def setpoint(self, t_mono_s: float, pos_world_m: Any, vel_world_m_s: Any, yaw_rad: float) -> None:
        return None

    def rough_path(self, t_mono_s: float, waypoints_m: Any) -> None:
        return None

    def step(self, t_mono_s: float, **decision: Any) -> None:
        return None

    def step_record(
        self, t_mono_s: float, record: Any, *, latency_ms: float = float("nan"), primitive: Any = None
    ) -> None:
        return None

    def vehicle(self, t_mono_s: float, armed: bool, mode: str, health: Mapping[str, Any]) -> None:
        return None

    def camera(self, t_mono_s: float, **model: Any) -> None:
        return None

    def geofence(self, t_mono_s: float, min_m: Any, max_m: Any) -> None:
        return None

    def world(self, t_mono_s: float, world: Mapping[str, Any]) -> None:
        return None

    def px4_time(self, t_mono_s: float, px4_boot_us: int, px4_unix_us: int = 0) -> None:
        return None

    def event(self, t_mono_s: float, kind: str, message: str, **fields: Any) -> None:
        return None

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        return None

    def close(self, stop_reason: str, summary: Mapping[str, Any] | None = None, **_: Any) -> None:
        return None
