"""The flight daemon's configuration: one frozen, typed tree loaded and validated before anything arms.

Every section is a frozen dataclass with a docstring per field; YAML files are validated with
:func:`quadnav_onboard.config.parse_config`, so an unknown key, a wrong type or an out-of-range
value raises :class:`quadnav_onboard.config.ConfigError` naming the file, the key path and the value.
Positions are world frame (x forward, y left, z up), metres.

Every numeric field is finite and lies in the range its docstring states (NaN, ±inf and absurd
values would switch a check off or fake an outcome); :func:`load_flight_config` also checks what
one field cannot: the path inside the geofence and the altitude band, and a goal radius the path
leaves room for (:func:`check_mission_path`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import pydantic

from quadnav_onboard.config import CONFIG_DICT, ConfigError, PrimitiveConfig, load_yaml_mapping, parse_config
from quadnav_onboard.path import RoughPath
from quadnav_onboard.preprocess import PreprocessConfig
from quadnav_onboard.reward import RewardParams
from quadnav_onboard.shield import ShieldConfig

__all__ = [
    "DepthSourceConfig",
    "FlightConfig",
    "MissionConfig",
    "OdometrySourceConfig",
    "RecordConfig",
    "SafetyConfig",
    "VehicleConfig",
    "check_mission_path",
    "default_sim_config",
    "dry_run_config",
    "flies_hardware",
    "load_flight_config",
    "room_aware_shield",
]

CoordM = Annotated[float, pydantic.Field(ge=-10_000, le=10_000)]
"""A world coordinate (m): within 10 km of the origin; 0 and negative values are places like any other."""
AltitudeM = Annotated[float, pydantic.Field(ge=-100, le=500)]
"""A world height (m): in [-100, 500]."""
Vec3 = tuple[CoordM, CoordM, CoordM]
_RotationEntry = Annotated[float, pydantic.Field(ge=-1, le=1)]
_RotationRow = tuple[_RotationEntry, _RotationEntry, _RotationEntry]
_IDENTITY: tuple[Vec3, Vec3, Vec3] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@dataclass(frozen=True)
class MissionConfig:
    """The rough path, the moving setpoint and when a flight is done."""

    __pydantic_config__ = CONFIG_DICT  # unknown keys, NaN and ±inf are errors

    waypoints_m: tuple[Vec3, ...] | None = None
    """Rough path (world, m, each coordinate in [-10 000, 10 000]), >= 2 distinct waypoints, inside
    the geofence and the altitude band; the first is where the vehicle takes off to.
    ``None`` only in a dry run, which takes the world file's path."""
    speed_m_s: Annotated[float, pydantic.Field(gt=0, le=5)] = 1.0
    """Speed (m/s) of the moving setpoint along the path, in (0, 5] (paper: 1 in sim, 0.5 real)."""
    max_steps: Annotated[int, pydantic.Field(ge=1, le=10_000)] = 60
    """Step limit, in [1, 10 000]: the flight stops (hold) after this many primitives (paper's real
    flights: 30)."""
    goal_radius_m: Annotated[float, pydantic.Field(gt=0, le=10)] = 1.0
    """The goal is reached within this distance (m) of the last waypoint (or at full progress); in
    (0, 10], and with ``start_tolerance_m`` below the start-to-goal distance, so that the goal cannot
    be reached at the start."""
    takeoff_speed_m_s: Annotated[float, pydantic.Field(gt=0, le=3)] = 0.5
    """Speed (m/s) of the setpoint ramp from the ground to the path start, in (0, 3]."""
    start_tolerance_m: Annotated[float, pydantic.Field(gt=0, le=2)] = 0.3
    """The mission begins once the vehicle is this close (m) to the path start; in (0, 2]."""
    start_settled_speed_m_s: Annotated[float, pydantic.Field(gt=0, le=3)] = 0.2
    """... and moves no faster than this (m/s, from the odometry's positions), so the first step
    starts from a hover as a training episode starts at rest, not mid-way through the climb's
    overshoot; in (0, 3]."""
    start_settled_for_s: Annotated[float, pydantic.Field(ge=0.05, le=10)] = 0.3
    """... and has stayed that slow for this long (s), so that a vehicle swinging about the start
    (slow only at each turn) does not pass for one at rest; in [0.05, 10]."""
    takeoff_timeout_s: Annotated[float, pydantic.Field(gt=0, le=600)] = 60.0
    """Give up (safe abort) if the path start is not reached within this time (s); in (0, 600]."""
    land_at_goal: bool = True
    """At the goal: hold, then land (True) or stay holding (False)."""


@dataclass(frozen=True)
class SafetyConfig:
    """The supervisor's limits and its response ladder (hold -> land -> optionally disarm)."""

    __pydantic_config__ = CONFIG_DICT  # unknown keys, NaN and ±inf are errors

    max_deviation_m: Annotated[float, pydantic.Field(gt=0, le=50)] = 5.0
    """Stop when farther than this (m) from the rough path, in (0, 50] (paper: 5 m in sim)."""
    geofence_min_m: Vec3 = (-100.0, -100.0, -1.0)
    """Lower corner (world, m, each in [-10 000, 10 000]) of the allowed box."""
    geofence_max_m: Vec3 = (100.0, 100.0, 30.0)
    """Upper corner (world, m, each in [-10 000, 10 000], above the lower one) of the allowed box."""
    altitude_floor_m: AltitudeM = 0.3
    """Lowest allowed altitude (world z, m, in [-100, 500]) during the mission (not during take-off
    or landing)."""
    altitude_ceiling_m: AltitudeM = 10.0
    """Highest allowed altitude (world z, m, in [-100, 500], above the floor)."""
    stale_depth_s: Annotated[float, pydantic.Field(gt=0, le=2)] = 0.3
    """Stop when the newest depth frame is older than this (s); in (0, 2]."""
    stale_odometry_s: Annotated[float, pydantic.Field(gt=0, le=1)] = 0.1
    """Stop when the newest odometry sample is older than this (s); in (0, 1]. In flight the limit
    is at least ``stale_odometry_periods`` periods and twice the longest gap of the stream as
    measured in preflight (``odometry_rate_check``), at most 1 s."""
    stale_odometry_periods: Annotated[float, pydantic.Field(ge=1, le=20)] = 3.0
    """The in-flight stale-odometry limit covers at least this many periods of the measured
    odometry rate; in [1, 20]."""
    min_odometry_rate_hz: Annotated[float, pydantic.Field(ge=1, le=1000)] = 20.0
    """Preflight refuses (until it holds) an odometry stream slower than this, measured over the
    last second (Hz); in [1, 1000]."""
    ground_reference: Literal["takeoff", "configured"] = "takeoff"
    """What z = 0 is for the altitude band, the geofence, the path and the filter's known floor:
    takeoff: the ground the vehicle stands on, measured from the odometry right before arming
    (PX4 on GPS height reports -0.4..+0.9 m on the ground); configured: ``ground_z_m``. Never the
    estimator's origin."""
    ground_z_m: Annotated[float, pydantic.Field(ge=-100, le=100)] = 0.0
    """configured: height (m, in [-100, 100]) of the ground in the odometry source's frame."""
    after_landing: Literal["wait_for_auto_disarm", "disarm"] = "wait_for_auto_disarm"
    """Once landed and still armed: wait (bounded by ``auto_disarm_wait_s``) for PX4's own disarm
    (COM_DISARM_LAND), then disarm if it did not come; or disarm at once."""
    auto_disarm_wait_s: Annotated[float, pydantic.Field(gt=0, le=60)] = 5.0
    """Longest wait (s) for PX4's auto-disarm after touchdown; in (0, 60]. The wait is
    COM_DISARM_LAND (read in preflight) + 1 s when that is shorter."""
    link_timeout_s: Annotated[float, pydantic.Field(gt=0, le=5)] = 0.5
    """Stop when nothing has been heard from the vehicle for this long (s); in (0, 5]."""
    inference_budget_s: Annotated[float, pydantic.Field(gt=0, le=1)] = 0.25
    """Stop when one decision (preprocess + network) takes longer than this (s); in (0, 1]."""
    check_rate_hz: Annotated[float, pydantic.Field(ge=1, le=1000)] = 50.0
    """Rate (Hz) of the in-flight checks, in [1, 1000]; 50 Hz reacts to stale input within 20 ms."""
    hold_before_land_s: Annotated[float, pydantic.Field(ge=0, le=60)] = 2.0
    """After an abort: hold this long (s) before commanding land; in [0, 60] (0: land at once)."""
    land_on_abort: bool = True
    """After an abort: land once held (True), or keep holding (False)."""
    disarm_on_abort: bool = False
    """After an abort: disarm once landed (PX4 also auto-disarms after touchdown)."""
    land_timeout_s: Annotated[float, pydantic.Field(gt=0, le=300)] = 30.0
    """How long (s) to wait for touchdown after commanding land; in (0, 300]."""

    def __post_init__(self) -> None:
        if not all(lo < hi for lo, hi in zip(self.geofence_min_m, self.geofence_max_m, strict=True)):
            raise ValueError(
                f"geofence_min_m {list(self.geofence_min_m)} must be below geofence_max_m "
                f"{list(self.geofence_max_m)} on every axis"
            )
        if not self.altitude_floor_m < self.altitude_ceiling_m:
            raise ValueError(
                f"altitude_floor_m {self.altitude_floor_m!r} must be below altitude_ceiling_m "
                f"{self.altitude_ceiling_m!r}"
            )


@dataclass(frozen=True)
class VehicleConfig:
    """The MAVLink link to PX4 through MAVSDK."""

    __pydantic_config__ = CONFIG_DICT  # unknown keys, NaN and ±inf are errors

    url: str = "serial:///dev/ttyACM0:921600"
    """MAVSDK connection URL: serial:///dev/ttyX:BAUD, udpin://0.0.0.0:14540, ..."""
    connect_timeout_s: Annotated[float, pydantic.Field(gt=0, le=300)] = 15.0
    """How long (s) to wait for the autopilot to appear; in (0, 300]."""
    command_timeout_s: Annotated[float, pydantic.Field(gt=0, le=60)] = 5.0
    """How long (s) any single command (arm, mode switch, ...) may take; in (0, 60]."""
    health_timeout_s: Annotated[float, pydantic.Field(gt=0, le=600)] = 15.0
    """How long (s) preflight waits for PX4 to report local position OK; in (0, 600]."""
    setpoint_rate_hz: Annotated[float, pydantic.Field(ge=2, le=100)] = 20.0
    """Rate (Hz) at which the daemon itself streams position setpoints, in [2, 100] (PX4 needs >= 2)."""
    telemetry_rate_hz: Annotated[float, pydantic.Field(ge=10, le=250)] = 50.0
    """Rate (Hz) asked of PX4 for ODOMETRY and LOCAL_POSITION_NED after connecting (MAVSDK's
    telemetry rate setters; PX4 SITL's default on the API link is ~30 Hz); in [10, 250]."""
    offboard_start_attempts: Annotated[int, pydantic.Field(ge=1, le=10)] = 3
    """Tries of the switch to OFFBOARD, the setpoint stream running between them; in [1, 10]
    (PX4 SITL refused one start in ten flights with NO_SETPOINT_SET)."""
    offboard_retry_s: Annotated[float, pydantic.Field(gt=0, le=5)] = 0.5
    """Wait (s) between OFFBOARD tries, in (0, 5]."""
    check_parameters: bool = True
    """Read PX4's parameters in preflight: refuse on a wrong one the flight needs (naming what to
    set), warn on advice (docs/hardware.md, section "PX4 parameters")."""


@dataclass(frozen=True)
class DepthSourceConfig:
    """Where depth frames come from."""

    __pydantic_config__ = CONFIG_DICT  # unknown keys, NaN and ±inf are errors

    kind: Literal["uvc", "replay", "socket", "sim"] = "uvc"
    """uvc: RealSense over V4L2; replay: a folder of 16-bit PNGs; socket: frames from a camera
    process over a Unix socket (the dry run's sim camera, or a driver of your own); sim: the sim
    harness camera inside the daemon's process (tests only)."""
    device: str = "/dev/video0"
    """uvc: V4L2 device path (/dev/videoN) or index ("2")."""
    socket_path: str | None = None
    """socket: path of the camera process's Unix socket (the dry run fills it in)."""
    width: Annotated[int, pydantic.Field(ge=32, le=4096)] = 424
    """Frame width (px), in [32, 4096]."""
    height: Annotated[int, pydantic.Field(ge=32, le=4096)] = 240
    """Frame height (px), in [32, 4096]."""
    fps: Annotated[float, pydantic.Field(ge=1, le=300)] = 30.0
    """Frame rate (Hz) requested from the camera, or the replay rate; in [1, 300]."""
    folder: str | None = None
    """replay: folder of uint16 PNG files (mm), played in name order."""
    loop: bool = True
    """replay: start over at the end of the folder."""
    prepare_within_s: Annotated[float, pydantic.Field(gt=0, le=10)] | None = 0.1
    """In (0, 10] s, or null. In the mission, fully prepare (preprocess, depth lane, filter verdict)
    only the frames that arrive within this many seconds before the next step boundary; earlier
    ones are only checked (a bad frame still stops the flight on arrival). One frame per step is
    used, so this saves most of the work at 30 fps. Never less than 1.5 frame periods
    (``preparation_window_s``), so a frame normally falls inside it. null: prepare every frame."""

    def preparation_window_s(self) -> float | None:
        """The window in effect: ``prepare_within_s``, at least 1.5 frame periods at ``fps``."""
        if self.prepare_within_s is None:
            return None
        return max(self.prepare_within_s, 1.5 / self.fps)


@dataclass(frozen=True)
class OdometrySourceConfig:
    """Where the vehicle pose comes from."""

    __pydantic_config__ = CONFIG_DICT  # unknown keys, NaN and ±inf are errors

    kind: Literal["mocap", "px4", "sim"] = "mocap"
    """mocap: the motioncapture library; px4: PX4's own estimate over MAVSDK; sim: sim harness."""
    system_type: str = "optitrack"
    """mocap: motioncapture system (optitrack, vicon, qualisys, vrpn, mock, ...)."""
    host: str = "192.168.1.100"
    """mocap: host name or address of the mocap server."""
    port_command: Annotated[int, pydantic.Field(ge=1, le=65535)] | None = None
    """mocap, optitrack: NatNet command port in [1, 65535]; null: Motive's default 1510."""
    rigid_body: str = "quad"
    """mocap: name of the vehicle's rigid body."""
    rotation_world_from_mocap: tuple[_RotationRow, _RotationRow, _RotationRow] = _IDENTITY
    """mocap: rotation matrix (rows, entries in [-1, 1]) taking mocap-frame vectors into the world
    frame. OptiTrack's y-up frame: ((1, 0, 0), (0, 0, -1), (0, 1, 0))."""
    translation_world_m: Vec3 = (0.0, 0.0, 0.0)
    """mocap: position (m, world, each in [-10 000, 10 000]) of the mocap origin."""
    forward_to_px4: bool = False
    """mocap: also send each pose to PX4 as a vision position estimate (EKF2 external vision)."""
    forward_rate_hz: Annotated[float, pydantic.Field(ge=30, le=200)] = 50.0
    """mocap: rate limit (Hz) of the forwarding to PX4, in [30, 200] (>= 30 as EKF2 expects)."""

    def __post_init__(self) -> None:
        r = np.asarray(self.rotation_world_from_mocap, dtype=np.float64)
        if not (np.allclose(r @ r.T, np.eye(3), atol=1e-6) and np.linalg.det(r) > 0):
            raise ValueError(f"rotation_world_from_mocap {self.rotation_world_from_mocap} is not a rotation")


@dataclass(frozen=True)
class RecordConfig:
    """The flight record (MCAP, see quadnav_onboard.record)."""

    __pydantic_config__ = CONFIG_DICT  # unknown keys, NaN and ±inf are errors

    enabled: bool = True
    """Write a flight record."""
    directory: str = "records"
    """Folder for the records (created if missing); one file per flight."""
    depth_decimation: Annotated[int, pydantic.Field(ge=1, le=1000)] = 5
    """Record every N-th raw depth frame, N in [1, 1000] (network inputs are always recorded)."""
    writer: Literal["process", "thread"] = "process"
    """Where the record is encoded and written: a child process (keeps protobuf encoding,
    compression and disk work off the flight process's GIL) or a thread of the flight process."""


@dataclass(frozen=True)
class FlightConfig:
    """Everything one flight needs."""

    __pydantic_config__ = CONFIG_DICT  # unknown keys, NaN and ±inf are errors

    model_path: str | None = None
    """Checkpoint to fly; None = the bundled quadnav_onboard/models/default.pt."""
    mission: MissionConfig = field(default_factory=MissionConfig)
    """Rough path, speed, step limit, goal."""
    primitives: PrimitiveConfig | None = None
    """Action set; None = what the checkpoint was trained with (real flight: scale_m 0.5)."""
    preprocess: PreprocessConfig | None = None
    """Depth preprocessing; None = what the checkpoint was trained with."""
    shield: ShieldConfig | None = None
    """Depth safety filter on the primitives; None = what the checkpoint was evaluated with
    (``meta.shield``; the bundled model flies with it on)."""
    reward: RewardParams = field(default_factory=RewardParams)
    """Reward constants, for the flight's total reward (as in training)."""
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    """Supervisor limits and response ladder."""
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    """MAVLink link."""
    depth: DepthSourceConfig = field(default_factory=DepthSourceConfig)
    """Depth camera."""
    odometry: OdometrySourceConfig = field(default_factory=OdometrySourceConfig)
    """Pose source."""
    record: RecordConfig = field(default_factory=RecordConfig)
    """Flight record."""
    trigger: dict[str, Any] | None = None
    """Mission start condition, passed to quadnav_onboard.trigger (None = mode auto)."""


def load_flight_config(path: str | Path, *, require_waypoints: bool = True) -> FlightConfig:
    """Load and validate a flight YAML file; raises ConfigError naming file, key and value.

    An empty file is refused (it would fly on the dataclass defaults without a word); waypoints, when
    given, are checked against the rest of the file with :func:`check_mission_path`."""
    cfg = parse_config(FlightConfig, load_yaml_mapping(path), source=str(path))
    wps = cfg.mission.waypoints_m
    if require_waypoints and wps is None:
        raise ConfigError(f"{path}: key 'mission.waypoints_m': required for a flight (got None)")
    if wps is not None:
        if len(wps) < 2:
            raise ConfigError(f"{path}: key 'mission.waypoints_m': bad value {wps!r}: need >= 2 waypoints")
        try:
            rough = RoughPath(np.asarray(wps, dtype=np.float64), cfg.mission.speed_m_s)
        except ValueError as exc:
            raise ConfigError(f"{path}: key 'mission.waypoints_m': bad value {wps!r}: {exc}") from None
        check_mission_path(cfg, rough, str(path), "mission.waypoints_m")
    return cfg


def check_mission_path(cfg: FlightConfig, path: RoughPath, source: str, path_source: str) -> None:
    """Refuse a mission the path flown does not fit, naming the file, the key and the value: a
    waypoint outside the geofence or the altitude band (the supervisor would stop the flight on
    it), or a goal radius that, with the start tolerance, reaches back to the start (the goal would
    be "reached" before the first step). ``path_source`` says where the path came from (the key
    ``mission.waypoints_m``, or a world file)."""
    s, m = cfg.safety, cfg.mission
    lo, hi = np.asarray(s.geofence_min_m), np.asarray(s.geofence_max_m)
    for k, wp in enumerate(path.waypoints_m):
        where = f"{path_source}[{k}] {wp.tolist()}"
        if np.any(wp < lo) or np.any(wp > hi):
            raise ConfigError(
                f"{source}: {where}: outside the geofence (keys 'safety.geofence_min_m' "
                f"{list(s.geofence_min_m)}, 'safety.geofence_max_m' {list(s.geofence_max_m)})"
            )
        if not s.altitude_floor_m <= wp[2] <= s.altitude_ceiling_m:
            raise ConfigError(
                f"{source}: {where}: outside the altitude band (keys 'safety.altitude_floor_m' "
                f"{s.altitude_floor_m}, 'safety.altitude_ceiling_m' {s.altitude_ceiling_m})"
            )
    reach_m = float(np.linalg.norm(path.goal_m - path.start_m))
    if m.goal_radius_m + m.start_tolerance_m >= reach_m:
        raise ConfigError(
            f"{source}: key 'mission.goal_radius_m': bad value {m.goal_radius_m!r}: with "
            f"'mission.start_tolerance_m' {m.start_tolerance_m} it must stay below the start-to-goal "
            f"distance {reach_m:.3g} m of {path_source} (path length {path.length_m:.3g} m), or the goal "
            "is reached at the start"
        )


def default_sim_config() -> FlightConfig:
    """The embedded dry-run configuration (quadnav_onboard/defaults/sim.yaml)."""
    ref = resources.files("quadnav_onboard").joinpath("defaults/sim.yaml")
    with resources.as_file(ref) as p:
        return load_flight_config(p, require_waypoints=False)


def flies_hardware(cfg: FlightConfig) -> bool:
    """The config names real hardware: a UVC depth camera or a serial link to the autopilot
    (config/flight.yaml), not a sim or a SITL (config/sim.yaml, config/px4-sitl.yaml)."""
    return cfg.depth.kind == "uvc" or cfg.vehicle.url.startswith("serial:")


def dry_run_config(cfg: FlightConfig) -> FlightConfig:
    """What a dry run flies of ``cfg``: the same mission, primitives, filter, preprocessing, reward
    and safety limits; for a config that :func:`flies_hardware`, the hardware sections are the
    sim's (defaults/sim.yaml): ``vehicle``, ``depth`` (the sim camera, rendered with the D435-like
    noise model), ``odometry``, ``trigger`` (the sim's go) and ``record.directory`` (``records``;
    ``--record-dir`` still overrides). Any other config is flown as it is (the dry run wires its
    vehicle, camera and mocap to the sim in any case)."""
    if not flies_hardware(cfg):
        return cfg
    sim = default_sim_config()
    return dataclasses.replace(
        cfg,
        vehicle=sim.vehicle,
        depth=sim.depth,
        odometry=sim.odometry,
        trigger=sim.trigger,
        record=dataclasses.replace(cfg.record, directory=sim.record.directory),
    )


def room_aware_shield(
    cfg: FlightConfig, meta: dict[str, Any], room: tuple[Any, Any] | None = None
) -> ShieldConfig:
    """The filter a flight flies with (``cfg.shield``, else the checkpoint's ``meta``) knowing the
    room: the geofence as the box the vehicle's centre stays in
    (:meth:`~quadnav_onboard.shield.ShieldConfig.with_fence`) and, in a dry run, the world's walls
    ``room`` (lowest and highest corner inside them, m) as solid faces
    (:meth:`~quadnav_onboard.shield.ShieldConfig.with_room`). The deviation limit round the path
    is added once the path flown is known (:meth:`~quadnav_onboard.shield.ShieldConfig.with_band`,
    ``quadnav-onboard``)."""
    from quadnav_onboard.shield import shield_config_from_meta

    shield = cfg.shield if cfg.shield is not None else shield_config_from_meta(meta)
    if room is not None:
        shield = shield.with_room(*room)
    return shield.with_fence(cfg.safety.geofence_min_m, cfg.safety.geofence_max_m)
