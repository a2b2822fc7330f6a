"""Real-vehicle wiring: sources and the vehicle link from the flight config (no sim imports)."""

from __future__ import annotations

import importlib.util
from typing import Any

from quadnav_onboard.config import ConfigError
from quadnav_onboard.daemon.config import FlightConfig
from quadnav_onboard.path import RoughPath
from quadnav_onboard.vehicle import MavsdkVehicle

__all__ = [
    "MOCAP_EXTRA_INSTALL",
    "depth_source",
    "hardware_parts",
    "odometry_source",
    "require_motioncapture",
]

MOCAP_EXTRA_INSTALL = "pip install 'quadnav[mocap]'"
"""How to get the motioncapture library (an optional extra: it has no ARM64 wheel)."""


def require_motioncapture(source: str = "config") -> None:
    """Refuse ``odometry.kind: mocap`` when the motioncapture library is not importable (ConfigError).

    Checked with ``importlib.util.find_spec``, before anything connects or arms; the library itself
    is imported only by the mocap source.
    """
    try:
        found = importlib.util.find_spec("motioncapture") is not None
    except (ImportError, ValueError):  # a broken or half-installed package
        found = False
    if not found:
        raise ConfigError(
            f"{source}: key 'odometry.kind': value 'mocap' needs the motioncapture library, which is "
            f"not installed: {MOCAP_EXTRA_INSTALL} (on ARM64 it builds from source: "
            "docs/hardware.md, section 1)"
        )


def hardware_parts(cfg: FlightConfig, source: str = "config") -> dict[str, Any]:
    """Keyword arguments for FlightDaemon: path, depth, odometry, vehicle (raises ConfigError)."""
    if cfg.mission.waypoints_m is None:
        raise ConfigError(f"{source}: key 'mission.waypoints_m': required for a flight (got None)")
    path = RoughPath(cfg.mission.waypoints_m, cfg.mission.speed_m_s)
    v = cfg.vehicle
    vehicle = MavsdkVehicle(
        v.url, connect_timeout_s=v.connect_timeout_s, command_timeout_s=v.command_timeout_s
    )
    depth = depth_source(cfg, source)
    odometry = odometry_source(cfg, vehicle, source)
    return {"path": path, "depth": depth, "odometry": odometry, "vehicle": vehicle}


def depth_source(cfg: FlightConfig, source: str = "config") -> Any:
    """The depth source ``cfg.depth`` names (raises ConfigError)."""
    d = cfg.depth
    if d.kind == "uvc":
        from quadnav_onboard.sources.uvc import UvcDepthSource

        return UvcDepthSource(d.device, d.width, d.height, d.fps)
    if d.kind == "replay":
        from quadnav_onboard.sources.replay import ReplayDepthSource

        if d.folder is None:
            raise ConfigError(f"{source}: key 'depth.folder': required for kind 'replay'")
        return ReplayDepthSource(d.folder, d.fps, d.loop)
    if d.kind == "socket":
        from quadnav_onboard.sources.socket_depth import SocketDepthSource

        if d.socket_path is None:
            raise ConfigError(f"{source}: key 'depth.socket_path': required for kind 'socket'")
        return SocketDepthSource(d.socket_path, d.width, d.height)
    raise ConfigError(f"{source}: key 'depth.kind': bad value 'sim': only with --dry-run --in-process")


def odometry_source(cfg: FlightConfig, vehicle: MavsdkVehicle, source: str = "config") -> Any:
    """The odometry source ``cfg.odometry`` names (raises ConfigError)."""
    o = cfg.odometry
    if o.kind == "mocap":
        require_motioncapture(source)
        from quadnav_onboard.sources.mocap import MocapOdometrySource, MocapTransform

        transform = MocapTransform(o.rotation_world_from_mocap, o.translation_world_m)
        return MocapOdometrySource(
            o.system_type, o.host, o.rigid_body, transform, port_command=o.port_command
        )
    if o.kind == "px4":
        from quadnav_onboard.sources.px4_odometry import Px4OdometrySource

        return Px4OdometrySource(vehicle)
    raise ConfigError(f"{source}: key 'odometry.kind': bad value 'sim': only with --dry-run --in-process")
