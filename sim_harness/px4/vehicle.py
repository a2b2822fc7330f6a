"""PX4's flight-mode and safety logic around the sim quad model: no sockets, no clocks.

Everything takes the current monotonic time ``t`` (s) from the caller, so the behaviour is a pure
function of the inputs and can be unit-tested with fake time. Positions are world frame (x fwd,
y left, z up, m); the MAVLink layer converts to and from NED with :mod:`quadnav_onboard.frames`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.frames import wrap_angle
from sim_harness.px4.config import EmulatorConfig
from sim_harness.quad import QuadState, step

__all__ = ["LANDED_STATES", "CommandResult", "Px4Vehicle", "Setpoint"]

LANDED_STATES = ("ON_GROUND", "IN_AIR", "TAKING_OFF", "LANDING")
"""MAV_LANDED_STATE names (1..4) reported in EXTENDED_SYS_STATE."""

_POSITION_MODES = frozenset({"HOLD", "POSCTL", "ALTCTL", "MANUAL", "STABILIZED", "ACRO", "OFFBOARD"})
_ACCEPTED_MODES = _POSITION_MODES | {"TAKEOFF", "LAND"}
_GROUND_EPS_M = 0.02
_GRAVITY_M_S2 = 9.81


@dataclass(frozen=True)
class CommandResult:
    """Outcome of a command: ``accepted`` and, if refused, why (goes to STATUSTEXT and the log)."""

    accepted: bool
    reason: str = ""
    unsupported: bool = False


@dataclass(frozen=True)
class Setpoint:
    """One offboard position setpoint, world frame; ``None`` fields were masked out."""

    pos_world_m: NDArray[np.float64] | None
    vel_world_m_s: NDArray[np.float64] | None
    yaw_rad: float | None
    t_mono_s: float


CollideFn = Callable[[NDArray[np.float64], NDArray[np.float64]], bool]
"""``collide(prev_pos_world_m (3,), new_pos_world_m (3,)) -> bool``: swept collision test."""


class Px4Vehicle:
    """The emulated vehicle: armed state, flight mode, failsafes and the quad's true motion.

    Events (``(t_mono_s, kind, message)``) accumulate in :attr:`events`; messages the autopilot
    would announce go to :attr:`outbox` (severity, text) for the MAVLink layer to send as
    STATUSTEXT.
    """

    def __init__(
        self,
        config: EmulatorConfig,
        start_pos_world_m: NDArray[np.float64],
        floor_z_m: float,
        t_mono_s: float,
        collide: CollideFn | None = None,
        start_yaw_rad: float = 0.0,
    ) -> None:
        self.cfg = config
        self.quad_params = dataclasses.replace(config.quad, dt_s=1.0 / config.physics_hz)
        self.floor_z_m = float(floor_z_m)
        self.state = QuadState.at_rest(np.asarray(start_pos_world_m, dtype=np.float64))
        self.yaw_rad = float(start_yaw_rad)
        self.home_world_m = self.state.pos_m[0].copy()
        self.armed = False
        self.mode = "HOLD"
        self.crashed = False
        self.landed_state = "ON_GROUND" if self._on_floor() else "IN_AIR"
        self.events: list[tuple[float, str, str]] = []
        self.outbox: list[tuple[int, str]] = []
        self._collide = collide
        self._setpoint: Setpoint | None = None
        self._hold_world_m = self.state.pos_m[0].copy()
        self._hold_yaw_rad = self.yaw_rad
        self.takeoff_alt_m = config.takeoff_alt_m
        """MIS_TAKEOFF_ALT (m above the floor); a PARAM_SET may change it."""
        self._takeoff_z_m = self.floor_z_m + config.takeoff_alt_m
        self._last_vision_mono_s = -np.inf
        self._armed_since_s = t_mono_s
        self._touchdown_since_s: float | None = None
        self._has_flown = False
        self._t_start_s = t_mono_s
        self._offboard_refusals_left = config.offboard_refusals
        self._failsafe_land_at_s: float | None = None
        """When the offboard-loss failsafe's hold ends in its land (px4 action); None when idle."""
        self._companion_heard_s: float | None = None
        self._companion_lost = False

    # --- queries -------------------------------------------------------------------------------
    @property
    def pos_world_m(self) -> NDArray[np.float64]:
        return self.state.pos_m[0]

    @property
    def vel_world_m_s(self) -> NDArray[np.float64]:
        return self.state.vel_m_s[0]

    def position_valid(self, t: float) -> bool:
        """Is the local position estimate valid (PX4: xy_valid and z_valid)?"""
        if self.cfg.vision_only:
            return t - self._last_vision_mono_s <= self.cfg.vision_timeout_s
        return True

    def setpoint_fresh(self, t: float, window_s: float) -> bool:
        return self._setpoint is not None and t - self._setpoint.t_mono_s <= window_s

    # --- events --------------------------------------------------------------------------------
    def _event(self, t: float, kind: str, message: str, severity: int | None = None) -> None:
        self.events.append((t, kind, message))
        if severity is not None:
            self.outbox.append((severity, message))

    def _enter_mode(self, t: float, mode: str) -> None:
        if mode == self.mode:
            return
        if mode in _POSITION_MODES - {"OFFBOARD"}:
            self._hold_world_m = self.pos_world_m.copy()
            self._hold_yaw_rad = self.yaw_rad
        self._event(t, "mode", f"{self.mode} -> {mode}")
        self.mode = mode

    # --- commands ------------------------------------------------------------------------------
    def arm(self, t: float, force: bool = False) -> CommandResult:
        if self.crashed:
            return self._refuse(t, "arm", "Arming denied: vehicle crashed")
        if self.armed:
            return CommandResult(True)
        if not force:
            if not self.position_valid(t):
                return self._refuse(t, "arm", "Arming denied: no valid local position")
            if self.mode not in _ACCEPTED_MODES - {"LAND", "TAKEOFF"}:
                return self._refuse(t, "arm", f"Arming denied: not in a position mode ({self.mode})")
        self.armed = True
        self._armed_since_s = t
        self._has_flown = not self._on_floor()
        self._touchdown_since_s = None
        self._event(t, "armed", "Armed by external command", severity=6)
        return CommandResult(True)

    def disarm(self, t: float, force: bool = False, reason: str = "external command") -> CommandResult:
        if not self.armed:
            return CommandResult(True)
        if not force and not self._on_floor():
            return self._refuse(t, "disarm", "Disarming denied: not landed")
        self.armed = False
        self._event(t, "disarmed", f"Disarmed by {reason}", severity=6)
        return CommandResult(True)

    def set_mode(self, t: float, mode: str) -> CommandResult:
        if mode not in _ACCEPTED_MODES:
            return CommandResult(False, f"mode {mode} not supported by the emulator", unsupported=True)
        if mode == self.mode:
            return CommandResult(True)
        if mode == "OFFBOARD" and not self.setpoint_fresh(t, self.cfg.offboard_stream_window_s):
            return self._refuse(t, "mode_denied", "Switching to Offboard denied: no setpoint stream")
        if mode == "OFFBOARD" and self._offboard_refusals_left > 0:
            self._offboard_refusals_left -= 1
            return self._refuse(t, "mode_denied", "Switching to Offboard denied: no setpoint set")
        if mode in _POSITION_MODES | {"TAKEOFF"} and not self.position_valid(t):
            return self._refuse(t, "mode_denied", f"Switching to {mode} denied: no local position")
        if mode == "TAKEOFF":
            return self.takeoff(t, None)
        self._enter_mode(t, mode)
        return CommandResult(True)

    def takeoff(self, t: float, alt_above_floor_m: float | None) -> CommandResult:
        if not self.armed:
            return self._refuse(t, "takeoff", "Takeoff denied: disarmed")
        if not self.position_valid(t):
            return self._refuse(t, "takeoff", "Takeoff denied: no local position")
        alt = self.takeoff_alt_m if alt_above_floor_m is None else alt_above_floor_m
        self._takeoff_z_m = self.floor_z_m + max(alt, 0.5)
        self._hold_world_m = self.pos_world_m.copy()
        self._hold_yaw_rad = self.yaw_rad
        self._event(t, "mode", f"{self.mode} -> TAKEOFF")
        self.mode = "TAKEOFF"
        return CommandResult(True)

    def land(self, t: float) -> CommandResult:
        self._hold_world_m = self.pos_world_m.copy()
        self._hold_yaw_rad = self.yaw_rad
        if self.mode != "LAND":
            self._event(t, "mode", f"{self.mode} -> LAND")
            self.mode = "LAND"
        return CommandResult(True)

    def on_setpoint(self, sp: Setpoint) -> None:
        self._setpoint = sp

    def on_companion_heartbeat(self, t: float) -> None:
        """A HEARTBEAT from an onboard controller (the companion computer's MAVSDK)."""
        self._companion_heard_s = t
        self._companion_lost = False

    def on_vision(self, t: float) -> None:
        self._last_vision_mono_s = t

    def crash(self, t: float, why: str) -> None:
        if self.crashed:
            return
        self.crashed = True
        self.armed = False
        # stopped where it hit; from there it falls, motors off, and lies on the floor
        self.state = QuadState.at_rest(self.pos_world_m.copy())
        self.landed_state = "ON_GROUND" if self._on_floor() else "IN_AIR"
        self._event(t, "crash", f"crash: {why} at {np.round(self.pos_world_m, 2).tolist()}", severity=2)

    def _refuse(self, t: float, kind: str, message: str) -> CommandResult:
        self._event(t, kind, message, severity=4)
        return CommandResult(False, message)

    # --- the tick ------------------------------------------------------------------------------
    def _on_floor(self) -> bool:
        return bool(self.pos_world_m[2] <= self.floor_z_m + _GROUND_EPS_M)

    def _failsafes(self, t: float) -> None:
        in_air = self.armed and not self._on_floor()
        if self.mode == "OFFBOARD" and not self.setpoint_fresh(t, self.cfg.com_of_loss_t_s):
            self._offboard_lost(t)
        if self._failsafe_land_at_s is not None:
            if self.mode != "HOLD" or not self.armed:  # the pilot (or a client) took over
                self._failsafe_land_at_s = None
            elif t >= self._failsafe_land_at_s:
                self._failsafe_land_at_s = None
                self._event(t, "failsafe", "Failsafe: landing", 4)
                self.land(t)
        heard = self._companion_heard_s
        if heard is not None and not self._companion_lost and t - heard > self.cfg.companion_loss_s:
            self._companion_lost = True
            self._event(t, "companion_lost", "Connection to mission computer lost", 4)
        if in_air and self.mode in _POSITION_MODES | {"TAKEOFF"} and not self.position_valid(t):
            self._event(t, "failsafe", "Failsafe: no local position, switching to LAND", 3)
            self._enter_mode(t, "LAND")
        idle_s = t - self._armed_since_s
        if self.armed and not self._has_flown and self.mode != "TAKEOFF" and self._on_floor() and (
            idle_s > self.cfg.preflight_disarm_s
        ):
            self.disarm(t, reason="auto-disarm: no takeoff (COM_DISARM_PRFLT)")

    def _offboard_lost(self, t: float) -> None:
        """The offboard-loss failsafe. px4 (PX4 v1.16 SITL, no RC): announce, hold for
        COM_FAIL_ACT_T, then land (Position mode, COM_OBL_RC_ACT=0, needs manual control); the
        auto-disarm follows the touchdown. hold / land: that mode at once (idealised)."""
        action = self.cfg.offboard_loss_action
        if action == "px4":
            self._event(t, "failsafe", "Failsafe activated", 2)
            if self.position_valid(t) and self.cfg.failsafe_delay_s > 0:
                self._enter_mode(t, "HOLD")
                self._failsafe_land_at_s = t + self.cfg.failsafe_delay_s
            else:
                self.land(t)
            return
        mode = "LAND" if action == "land" or not self.position_valid(t) else "HOLD"
        self._event(t, "failsafe", f"Failsafe: offboard setpoints lost, switching to {mode}", 3)
        self._enter_mode(t, mode)

    def _target(self, t: float, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, float]:
        """Position (m) and velocity feed-forward (m/s) targets, world frame, and the yaw target."""
        pos = self.pos_world_m
        if self.mode == "OFFBOARD" and self._setpoint is not None:
            sp = self._setpoint
            vel = sp.vel_world_m_s
            if sp.pos_world_m is not None:
                target = sp.pos_world_m
            else:  # velocity-only: move the position target along with the commanded velocity
                target = pos + (np.zeros(3) if vel is None else vel * dt)
            yaw = self.yaw_rad if sp.yaw_rad is None else sp.yaw_rad
            return target, vel, yaw
        if self.mode == "TAKEOFF":
            target = np.array([*self._hold_world_m[:2], self._takeoff_z_m])
            if abs(pos[2] - self._takeoff_z_m) < 0.1 and np.linalg.norm(self.vel_world_m_s) < 0.3:
                self._event(t, "takeoff", "Takeoff complete, holding", severity=6)
                self._enter_mode(t, "HOLD")
            return target, None, self._hold_yaw_rad
        if self.mode == "LAND":
            target = np.array([*self._hold_world_m[:2], pos[2]])
            return target, np.array([0.0, 0.0, -self.cfg.land_speed_m_s]), self._hold_yaw_rad
        return self._hold_world_m, None, self._hold_yaw_rad

    def tick(self, t: float, dt: float) -> None:
        """Advance the vehicle by ``dt`` seconds to time ``t`` (monotonic s)."""
        if self.crashed:
            self._fall_after_crash(dt)
            return
        self._failsafes(t)
        prev = self.pos_world_m.copy()
        if self.armed and (self.mode in ("TAKEOFF", "OFFBOARD", "LAND") or not self._on_floor()):
            target, vel_ff, yaw_target = self._target(t, dt)
            self.state = step(self.state, target[None, :], None if vel_ff is None else vel_ff[None, :],
                              self.quad_params, dt)
            dyaw = float(wrap_angle(yaw_target - self.yaw_rad))
            self.yaw_rad = float(wrap_angle(self.yaw_rad + np.clip(dyaw, -1, 1) * min(
                abs(dyaw), self.cfg.max_yaw_rate_rad_s * dt)))
        elif not self.armed and not self._on_floor():  # motors off in the air: it falls
            vel = self.vel_world_m_s.copy()
            vel[2] -= _GRAVITY_M_S2 * dt
            self.state = QuadState(self.state.pos_m + vel[None, :] * dt, vel[None, :])
        else:  # parked on the floor
            self.state = QuadState.at_rest(np.array([*self.pos_world_m[:2], self.floor_z_m]))
        self._ground_contact(t)
        if self._collide is not None and self._collide(prev, self.pos_world_m.copy()):
            self.crash(t, "collision with the world")
            return
        self._update_landed(t)

    def _fall_after_crash(self, dt: float) -> None:
        if self._on_floor():
            self.state = QuadState.at_rest(np.array([*self.pos_world_m[:2], self.floor_z_m]))
            self.landed_state = "ON_GROUND"
            return
        vel = self.vel_world_m_s.copy()
        vel[2] -= _GRAVITY_M_S2 * dt
        pos = self.state.pos_m[0] + vel * dt
        if pos[2] <= self.floor_z_m:
            pos[2], vel[:] = self.floor_z_m, 0.0
        self.state = QuadState(pos[None, :], vel[None, :])

    def _ground_contact(self, t: float) -> None:
        pos, vel = self.state.pos_m[0], self.state.vel_m_s[0]
        if pos[2] >= self.floor_z_m:
            return
        impact_m_s = -float(vel[2])
        pos[2] = self.floor_z_m
        vel[:] = 0.0
        if impact_m_s > self.cfg.crash_speed_m_s:
            self.crash(t, f"hit the floor at {impact_m_s:.1f} m/s")

    def _update_landed(self, t: float) -> None:
        on_floor = self._on_floor() and float(np.linalg.norm(self.vel_world_m_s)) < 0.3
        if not on_floor:
            self._touchdown_since_s = None
            if self.armed:
                self._has_flown = True
            new = {"TAKEOFF": "TAKING_OFF", "LAND": "LANDING"}.get(self.mode, "IN_AIR")
        else:
            new = "ON_GROUND"
            if self.armed and self._has_flown:
                if self._touchdown_since_s is None:
                    self._touchdown_since_s = t
                    self._event(t, "touchdown", "Landing detected", severity=6)
                elif t - self._touchdown_since_s >= self.cfg.land_disarm_s:
                    self.disarm(t, reason="auto-disarm after landing (COM_DISARM_LAND)")
        if new != self.landed_state:
            self.landed_state = new
