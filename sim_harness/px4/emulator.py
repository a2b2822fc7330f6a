"""An emulated PX4 quadrotor on real MAVLink 2 over UDP, for dry runs and end-to-end tests.

``Px4Emulator`` runs in its own thread: it reads MAVLink from its links, integrates the vehicle at
``physics_hz`` (PX4's modes and failsafes in :mod:`sim_harness.px4.vehicle`, the motion in
:mod:`sim_harness.quad`), checks collisions against the world, and streams telemetry. A client
(MAVSDK, QGroundControl) listens with ``udpin://127.0.0.1:<api_port>``.

    with Px4Emulator(world, EmulatorConfig(heartbeat_hz=10), api_port=free_udp_port()) as emu:
        ...  # connect MAVSDK; emu.true_pose(), emu.mode, emu.faults.drop_link(1.0, 2.0)
"""

from __future__ import annotations

import dataclasses
import math
import select
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.frames import quat_from_yaw
from quadnav_onboard.logs import get_logger
from sim_harness.px4 import telemetry as tm
from sim_harness.px4.commands import CommandHandler
from sim_harness.px4.config import EmulatorConfig
from sim_harness.px4.faults import Faults
from sim_harness.px4.mavlink_io import MavlinkLink
from sim_harness.px4.telemetry import TruePose, VehicleSnapshot
from sim_harness.px4.vehicle import Px4Vehicle

if TYPE_CHECKING:
    from sim_harness.world import World

__all__ = ["EmulatorConfig", "Px4Emulator", "TruePose"]

log = get_logger(__name__)

_FAST = ("LOCAL_POSITION_NED", "ATTITUDE_QUATERNION", "ODOMETRY")
SYSTEM_TIME_INTERVAL_S = 1.0
"""SYSTEM_TIME's period (s): PX4 streams it at 1 Hz on every MAVLink instance."""
_SLOW = ("SYS_STATUS", "EXTENDED_SYS_STATE", "HOME_POSITION", "GLOBAL_POSITION_INT")


def _collision_fn(world: World | None, radius_m: float) -> Callable[[NDArray, NDArray], bool] | None:
    if world is None:
        return None
    from sim_harness.collision import sweep_collides  # imported only with a world

    # The floor is the vehicle's ground (landing on it is not a crash): the vehicle model handles
    # it; the collision check sees the obstacles and the ceiling.
    world = dataclasses.replace(world, floor_z_m=None)

    def collide(prev: NDArray[np.float64], new: NDArray[np.float64]) -> bool:
        trail = np.stack([prev, new])[:, None, :]
        return bool(sweep_collides(world, trail, radius_m)[0])

    return collide


def _default_start(world: World | None) -> NDArray[np.float64]:
    if world is None:
        return np.zeros(3)
    first = np.asarray(world.path.waypoints_m, dtype=np.float64)[0]
    return np.array([first[0], first[1], _floor_z(world)])


_SITL_GROUND_Z_RANGE_M = (-0.38, 0.33)
"""PX4 SITL's local height on the ground before take-off over 11 starts (EKF2_HGT_REF=1, GPS)."""


def _ground_offset(cfg: EmulatorConfig, rng: np.random.Generator) -> float:
    if cfg.vision_only:
        return 0.0
    if cfg.ground_offset_m is not None:
        return float(cfg.ground_offset_m)
    lo, hi = _SITL_GROUND_Z_RANGE_M
    return float(rng.uniform(lo, hi))


def _floor_z(world: World | None) -> float:
    return 0.0 if world is None or world.floor_z_m is None else float(world.floor_z_m)


class Px4Emulator:
    """The emulated vehicle. Thread-safe accessors; ``start()``/``stop()`` or a ``with`` block."""

    def __init__(
        self,
        world: World | None,
        config: EmulatorConfig | None = None,
        api_port: int = 14540,
        gcs_port: int | None = None,
        start_pos_world_m: NDArray[np.float64] | None = None,
        start_yaw_rad: float = 0.0,
    ) -> None:
        self.world = world
        self.config = config or EmulatorConfig()
        self.api_port = int(api_port)
        self.gcs_port = gcs_port
        self.faults = Faults()
        self._start_pos = _default_start(world) if start_pos_world_m is None else np.asarray(
            start_pos_world_m, dtype=np.float64)
        self._start_yaw = float(start_yaw_rad)
        self._floor_z_m = _floor_z(world)
        self.rng = np.random.default_rng(self.config.seed)
        self.ground_offset_m = _ground_offset(self.config, self.rng)
        """PX4's local height (up, m) of the ground: local z = world z - floor + this."""
        self.local_offset_world_m = np.array([0.0, 0.0, self.ground_offset_m - self._floor_z_m])
        """Estimator-local position minus world position (m): the estimator's origin is not the
        world's (PX4 on GPS height); setpoints arrive in the local frame and are converted back."""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._links: list[MavlinkLink] = []
        self._t0 = self._t_last_tick = time.monotonic()
        self.vehicle = Px4Vehicle(self.config, self._start_pos, self._floor_z_m, self._t0,
                                  _collision_fn(world, self.config.quad.radius_m), self._start_yaw)
        self._pose = self._make_pose(self._t0)
        self._frozen: VehicleSnapshot | None = None
        self._grid: dict[str, float] = {}
        """Each stream's regular send grid (monotonic s), before jitter."""
        self.commands = CommandHandler(self)
        self.seen_message_types: dict[str, int] = {}
        """Counts of every MAVLink message type received (to learn what a client sends)."""
        self.on_pose: Callable[[TruePose], None] | None = None
        """Called on the emulator's thread with each physics tick's true pose (under its lock):
        how the vehicle side publishes the true state to the sim's other processes."""

    # --- lifecycle -----------------------------------------------------------------------------
    def start(self) -> Px4Emulator:
        if self._thread is not None:
            raise RuntimeError("emulator already started")
        drop = lambda t: self.faults.active("drop_link", t) is not None  # noqa: E731
        ports = [self.api_port] + ([self.gcs_port] if self.gcs_port else [])
        self._links = [MavlinkLink(p, self.config.system_id, fault_delay_s=self.faults.link_delay_s,
                                   fault_drop=drop) for p in ports]
        self._t0 = self._t_last_tick = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="px4-emulator", daemon=True)
        self._thread.start()
        log.info("px4_emulator_started", api_port=self.api_port, gcs_port=self.gcs_port,
                 heartbeat_hz=self.config.heartbeat_hz, vision_only=self.config.vision_only)
        return self

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        for link in self._links:
            link.close()
        self._links = []

    def __enter__(self) -> Px4Emulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- thread-safe accessors -----------------------------------------------------------------
    def true_pose(self) -> TruePose:
        """The vehicle's true pose now (world frame), as the physics last left it."""
        with self._lock:
            return self._pose

    @property
    def armed(self) -> bool:
        with self._lock:
            return self.vehicle.armed

    @property
    def mode(self) -> str:
        with self._lock:
            return self.vehicle.mode

    @property
    def crashed(self) -> bool:
        with self._lock:
            return self.vehicle.crashed

    @property
    def landed_state(self) -> str:
        with self._lock:
            return self.vehicle.landed_state

    @property
    def events(self) -> list[tuple[float, str, str]]:
        """``(t_mono_s, kind, message)`` of everything notable so far (a copy)."""
        with self._lock:
            return list(self.vehicle.events)

    def wait_for(self, predicate: Callable[[Px4Emulator], bool], timeout_s: float) -> bool:
        """Wait (polling each physics tick) until ``predicate(self)`` holds; False on timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if predicate(self):
                return True
            time.sleep(1.0 / self.config.physics_hz)
        return bool(predicate(self))

    @property
    def local_ports(self) -> list[int]:
        return [link.local_port for link in self._links]

    # --- the thread ----------------------------------------------------------------------------
    def _make_pose(self, t: float) -> TruePose:
        v = self.vehicle
        return TruePose(v.pos_world_m.copy(), v.vel_world_m_s.copy(), quat_from_yaw(v.yaw_rad), t)

    def snapshot(self, t: float) -> VehicleSnapshot:
        v = self.vehicle
        return VehicleSnapshot(
            t_boot_ms=int((t - self._t0) * 1000), pos_world_m=v.pos_world_m.copy(),
            vel_world_m_s=v.vel_world_m_s.copy(), yaw_rad=v.yaw_rad, armed=v.armed, mode=v.mode,
            crashed=v.crashed, landed_state=v.landed_state, position_valid=v.position_valid(t),
            home_world_m=v.home_world_m.copy(), local_offset_m=self.local_offset_world_m,
        )

    def send(self, msg: object, t: float, link: MavlinkLink | None = None) -> None:
        for target in [link] if link is not None else self._links:
            target.send(msg, t)

    def interval_s(self, name: str) -> float:
        return self.commands.intervals_s.get(name, self._default_interval_s(name))

    def _default_interval_s(self, name: str) -> float:
        if name == "HEARTBEAT":
            return 1.0 / self.config.heartbeat_hz
        if name == "SYSTEM_TIME":
            return SYSTEM_TIME_INTERVAL_S
        if name in _FAST:
            return 1.0 / self.config.telemetry_hz
        return 1.0 / self.config.status_hz

    def _next_due(self, name: str, interval: float, now: float) -> float:
        """When ``name`` is next due: a regular grid of ``interval``, the fast messages each up to
        ``telemetry_jitter`` of an interval late (PX4's scheduling on a loaded host)."""
        grid = max(self._grid.get(name, now) + interval, now)
        self._grid[name] = grid
        if name in _FAST and self.config.telemetry_jitter > 0:
            return grid + float(self.rng.uniform(0.0, self.config.telemetry_jitter * interval))
        return grid

    def _run(self) -> None:
        dt = 1.0 / self.config.physics_hz
        t_next_physics = time.monotonic()
        next_send: dict[str, float] = {}
        self._grid = {}
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                with self._lock:
                    self._step(now, dt, next_send)
                    t_next_physics = max(t_next_physics + dt * math.floor((now - t_next_physics) / dt + 1),
                                         now + 1e-4)
                timeout = max(0.0, t_next_physics - time.monotonic())
                select.select(self._links, [], [], timeout)
        except Exception:  # the thread must not die silently: record, then stop
            log.exception("px4_emulator_thread_failed")
            with self._lock:
                self.vehicle.events.append((time.monotonic(), "error", "emulator thread failed"))
            raise

    def _step(self, now: float, dt: float, next_send: dict[str, float]) -> None:
        for link in self._links:
            for msg in link.receive(now):
                name = msg.get_type()
                self.seen_message_types[name] = self.seen_message_types.get(name, 0) + 1
                self.commands.handle(msg, link, now)
        if self.faults.take_crash_request() or self.faults.active("crash", now) is not None:
            self.vehicle.crash(now, "crash injected by fault")
        elapsed = min(max(now - self._t_last_tick, 0.0), 10 * dt)  # a stalled thread loses time
        steps = max(1, math.ceil(elapsed / dt - 1e-9))
        for k in range(steps):
            self.vehicle.tick(now - (steps - 1 - k) * elapsed / steps, elapsed / steps)
        self._t_last_tick = now
        self._pose = self._make_pose(now)
        if self.on_pose is not None:
            self.on_pose(self._pose)
        self._send_telemetry(now, next_send)
        for link in self._links:
            link.flush_delayed(now)

    def _send_telemetry(self, now: float, next_send: dict[str, float]) -> None:
        snap = self.snapshot(now)
        if self.faults.active("freeze_position", now) is not None:
            if self._frozen is None:
                self._frozen = snap
            f = self._frozen
            snap = VehicleSnapshot(**{**snap.__dict__, "pos_world_m": f.pos_world_m,
                                      "vel_world_m_s": f.vel_world_m_s, "yaw_rad": f.yaw_rad})
        else:
            self._frozen = None
        while self.vehicle.outbox:
            severity, text = self.vehicle.outbox.pop(0)
            self.send(tm.m.MAVLink_statustext_message(severity, text[:50].encode(), 0, 0), now)
        builders: dict[str, Callable[[], object]] = {
            "HEARTBEAT": lambda: tm.heartbeat(snap),
            "LOCAL_POSITION_NED": lambda: tm.local_position_ned(snap),
            "ATTITUDE_QUATERNION": lambda: tm.attitude_quaternion(snap),
            "ODOMETRY": lambda: tm.odometry(snap),
            "SYS_STATUS": lambda: tm.sys_status(snap),
            "EXTENDED_SYS_STATE": lambda: tm.extended_sys_state(snap),
            "HOME_POSITION": lambda: tm.home_position(snap, self.config),
            "GLOBAL_POSITION_INT": lambda: tm.global_position_int(snap, self.config),
            "SYSTEM_TIME": lambda: tm.system_time(snap, time.time()),
        }
        for name, build in builders.items():
            interval = self.interval_s(name)
            if interval <= 0.0 or now < next_send.get(name, 0.0):
                continue
            next_send[name] = self._next_due(name, interval, now)
            if name in ("LOCAL_POSITION_NED", "ODOMETRY", "GLOBAL_POSITION_INT") and not snap.position_valid:
                continue  # PX4 does not publish an invalid estimate
            self.send(build(), now)
