"""Dry-run wiring: the daemon against the sim harness (the only place quadnav_onboard imports it).

:class:`ProcessDryRun` (what ``quadnav-onboard --dry-run`` flies) starts the sim's vehicle side as
child processes (:class:`sim_harness.vehicle_side.VehicleSide`: the emulated PX4, the sim camera,
the emulated OptiTrack Motive) and wires the daemon to them through the sources a flight uses:
MAVSDK over MAVLink/UDP, :class:`~quadnav_onboard.sources.socket_depth.SocketDepthSource` and
:class:`~quadnav_onboard.sources.mocap.MocapOdometrySource` over NatNet (``odometry.kind: px4``:
PX4's own estimate instead, no mocap process).

:class:`DryRun` is the single-process variant for tests that reach into the emulator: the emulated
PX4 (:class:`sim_harness.px4.Px4Emulator`) on an OS-chosen UDP port, the synthetic D435
(:class:`sim_harness.camera.SimDepthCamera`) and the simulated mocap
(:class:`sim_harness.mocap.SimMocap`) on the emulator's true pose, all in the daemon's process, and
a real :class:`~quadnav_onboard.vehicle.MavsdkVehicle` that connects to it over real MAVLink.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from quadnav_onboard.daemon.config import FlightConfig
from quadnav_onboard.daemon.hardware import depth_source, odometry_source
from quadnav_onboard.logs import get_logger
from quadnav_onboard.path import RoughPath
from quadnav_onboard.vehicle import MavsdkVehicle

__all__ = ["DryRun", "ProcessDryRun"]

log = get_logger("quadnav.dryrun")


class _SimWiring:
    """What both wirings share: the world, the config and the path flown."""

    def __init__(
        self,
        cfg: FlightConfig,
        world_path: str | Path | None = None,
        *,
        emulator: dict[str, Any] | None = None,
        mocap: dict[str, Any] | None = None,
        seed: int = 0,
        sitl: dict[str, Any] | None = None,
        depth_noise: bool = False,
    ) -> None:
        from sim_harness.world import load_world, paper_world_path, resolve_world_arg

        self.world_path = paper_world_path(1) if world_path is None else resolve_world_arg(str(world_path))
        self.world = load_world(self.world_path)
        self.depth_noise = depth_noise
        """Render the sim camera's frames with the D435-like noise model (sim_harness.noise)."""
        self.cfg = cfg
        self._emulator_kwargs = emulator or {}
        self._mocap_kwargs = mocap or {}
        self.seed = seed
        self.sitl = sitl
        """Settings of the bridge to a PX4 SITL the user runs (``port``); None: the emulator."""

    @property
    def path(self) -> RoughPath:
        """The rough path to fly: the config's waypoints if given, else the world's."""
        wps = self.cfg.mission.waypoints_m
        if wps is None:
            return self.world.path
        return RoughPath(wps, self.cfg.mission.speed_m_s)


class ProcessDryRun(_SimWiring):
    """Context manager: ``with ProcessDryRun(cfg, world_path) as sim: FlightDaemon(..., **sim.parts())``.

    ``emulator``: keyword arguments for :class:`sim_harness.px4.EmulatorConfig`; ``mocap``:
    settings of the emulated Motive (``rate_hz``, ``noise_m``, ``latency_s``, ``dropout``, ...).
    ``world_path`` None = the paper's Env 1 (a file, or a name in sim_harness/worlds/: ``lab02``).
``depth_noise``: the sim camera renders with the D435-like noise model. ``side`` is the running
    :class:`~sim_harness.vehicle_side.VehicleSide` (its parts can be killed to inject faults).
    """

    side: Any = None

    def __enter__(self) -> ProcessDryRun:
        from sim_harness.natnet import ROTATION_WORLD_FROM_MOTIVE
        from sim_harness.vehicle_side import VehicleSideError

        cfg, d = self.cfg, self.cfg.depth
        mocap = cfg.odometry.kind != "px4"
        try:
            self.side = self._start_side(cfg, mocap)
        except VehicleSideError as exc:  # the command line reports an OSError as "cannot start"
            raise OSError(f"dry run: {exc}") from exc
        side = self.side
        odometry = cfg.odometry
        if mocap:
            host, port = side.mocap_command
            odometry = dataclasses.replace(
                odometry, kind="mocap", system_type="optitrack", host=host, port_command=port,
                rotation_world_from_mocap=ROTATION_WORLD_FROM_MOTIVE, translation_world_m=(0.0, 0.0, 0.0),
            )
        vehicle = cfg.vehicle if self.sitl is not None else dataclasses.replace(cfg.vehicle, url=side.url)
        self.cfg = dataclasses.replace(
            cfg,
            vehicle=vehicle,
            depth=dataclasses.replace(d, kind="socket", socket_path=side.depth_socket),
            odometry=odometry,
        )
        log.info(
            "sim_vehicle_side_ready",
            ready_s=round(side.t_ready_s, 3),
            parts={name: {k: v for k, v in p.info.items() if k != "ready"} for name, p in side.parts.items()},
        )
        return self

    def _start_side(self, cfg: FlightConfig, mocap: bool) -> Any:
        from sim_harness.vehicle_side import VehicleSide

        d = cfg.depth
        head = "vehicle" if self.sitl is None else "bridge"  # a PX4 SITL: its reported state
        return VehicleSide(
            self.world_path,
            camera={"width": d.width, "height": d.height, "fps": d.fps, "seed": self.seed,
                    "noise": self.depth_noise},
            mocap={"rigid_body": cfg.odometry.rigid_body, "seed": self.seed, **self._mocap_kwargs},
            emulator=self._emulator_kwargs,
            parts=(head, "camera", "mocap") if mocap else (head, "camera"),
            bridge=self.sitl,
        ).start()

    def __exit__(self, *exc: object) -> None:
        if self.side is not None:
            self.side.stop()

    def parts(self) -> dict[str, Any]:
        """Keyword arguments for FlightDaemon: path, depth, odometry, vehicle, crash_probe."""
        v = self.cfg.vehicle
        vehicle = MavsdkVehicle(v.url, connect_timeout_s=v.connect_timeout_s,
                                command_timeout_s=v.command_timeout_s)
        return {
            "path": self.path,
            "depth": depth_source(self.cfg, "dry run"),
            "odometry": odometry_source(self.cfg, vehicle, "dry run"),
            "vehicle": vehicle,
            "crash_probe": self.side.crashed,
        }


class _CameraPose:
    """The emulator's true pose with the camera no lower than landing-gear height
    (:data:`sim_harness.sidecar.GEAR_HEIGHT_M`: a real D435 never sits on the floor)."""

    def __init__(self, pose_fn: Any, floor_z_m: float | None) -> None:
        self._pose_fn = pose_fn
        from sim_harness.sidecar import GEAR_HEIGHT_M

        self._min_z_m = (floor_z_m or 0.0) + GEAR_HEIGHT_M

    def __call__(self) -> Any:
        pose = self._pose_fn()
        if pose.pos_world_m[2] >= self._min_z_m:
            return pose
        pos = pose.pos_world_m.copy()
        pos[2] = self._min_z_m
        return dataclasses.replace(pose, pos_world_m=pos)


class DryRun(_SimWiring):
    """Context manager: ``with DryRun(cfg, world_path) as sim: FlightDaemon(..., **sim.parts())``.

    ``emulator``: keyword arguments for :class:`sim_harness.px4.EmulatorConfig` (e.g. a faster
    heartbeat in tests). ``world_path`` None = the paper's Env 1.
    """

    emulator: Any = None

    def __enter__(self) -> DryRun:
        from sim_harness.px4 import EmulatorConfig, Px4Emulator, free_udp_port

        port = free_udp_port()
        self.emulator = Px4Emulator(self.world, EmulatorConfig(**self._emulator_kwargs), api_port=port)
        self.emulator.start()
        self.cfg = dataclasses.replace(
            self.cfg, vehicle=dataclasses.replace(self.cfg.vehicle, url=f"udpin://127.0.0.1:{port}")
        )
        return self

    def __exit__(self, *exc: object) -> None:
        if self.emulator is not None:
            self.emulator.stop()

    def parts(self) -> dict[str, Any]:
        """Keyword arguments for FlightDaemon: path, depth, odometry, vehicle, crash_probe."""
        from sim_harness.camera import SimDepthCamera
        from sim_harness.mocap import SimMocap
        from sim_harness.noise import DepthNoise
        from sim_harness.render import CameraModel

        emu, d = self.emulator, self.cfg.depth
        camera = CameraModel(width=d.width, height=d.height)
        return {
            "path": self.path,
            "depth": SimDepthCamera(
                self.world,
                _CameraPose(emu.true_pose, self.world.floor_z_m),
                camera=camera,
                fps=d.fps,
                noise=DepthNoise() if self.depth_noise else None,
                seed=self.seed,
            ),
            "odometry": SimMocap(emu.true_pose, seed=self.seed, **self._mocap_kwargs),
            "vehicle": MavsdkVehicle(
                self.cfg.vehicle.url,
                connect_timeout_s=self.cfg.vehicle.connect_timeout_s,
                command_timeout_s=self.cfg.vehicle.command_timeout_s,
            ),
            "crash_probe": lambda: bool(emu.crashed),
        }
