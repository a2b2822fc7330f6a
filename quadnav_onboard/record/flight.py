"""What a flight's record is told before and after the flight: the scene and PX4's clock.

:func:`describe_flight` gives the recorder the depth camera (size, fields of view, mount offset),
the geofence and, in dry runs, the world; :func:`record_px4_time` the newest MAVLink SYSTEM_TIME
the vehicle link saw. Both are called by the daemon's shell (``quadnav_onboard.cli``,
``quadnav_onboard.daemon``) and never raise into the flight: the recorder is the daemon's
``SafeRecorder`` or a recorder whose calls only queue.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from quadnav_onboard.shield import ShieldConfig, shield_config_from_meta

__all__ = ["describe_flight", "record_px4_time"]


def describe_flight(
    recorder: Any, cfg: Any, policy: Any = None, world: Mapping[str, Any] | None = None
) -> None:
    """Record the camera model and mount, the geofence and ``world`` (a world-file mapping) of a
    flight flown with ``cfg`` (a :class:`~quadnav_onboard.daemon.config.FlightConfig`). The camera's
    fields of view and mount offset are the depth filter's (``cfg.shield``, else the model's own,
    else the defaults: a D435's 87 x 58 deg at the body origin)."""
    t = time.monotonic()
    shield = cfg.shield
    if shield is None:
        meta = getattr(getattr(policy, "checkpoint", None), "meta", None)
        shield = shield_config_from_meta(meta) if isinstance(meta, dict) else ShieldConfig()
    recorder.camera(
        t,
        width_px=cfg.depth.width,
        height_px=cfg.depth.height,
        hfov_deg=shield.hfov_deg,
        vfov_deg=shield.vfov_deg,
        offset_body_m=shield.camera_offset_m,
    )
    recorder.geofence(t, cfg.safety.geofence_min_m, cfg.safety.geofence_max_m)
    if world is not None:
        recorder.world(t, world)


def record_px4_time(recorder: Any, state: Any) -> bool:
    """Record the vehicle state's newest SYSTEM_TIME (``state.px4_time``: arrival monotonic s,
    PX4 boot time us, PX4 UTC us); False when the link has reported none."""
    sample = getattr(state, "px4_time", None)
    if sample is None:
        return False
    t_mono_s, boot_us, unix_us = sample
    recorder.px4_time(t_mono_s, boot_us, unix_us)
    return True
