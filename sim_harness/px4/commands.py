"""What the emulated PX4 does with each MAVLink message it receives.

Commands (COMMAND_LONG / COMMAND_INT) are answered with COMMAND_ACK; parameters are NaN-safe
(MAVSDK sends NaN for "unset"). Unknown commands get ``MAV_RESULT_UNSUPPORTED`` so a client never
waits for a timeout. Setpoints and vision estimates arrive in NED and are converted to the world
frame with :mod:`quadnav_onboard.frames`.
"""

from __future__ import annotations

import math
import struct
from typing import TYPE_CHECKING, Any

import numpy as np

from quadnav_onboard.frames import frd_to_flu, yaw_frd_to_flu
from quadnav_onboard.logs import get_logger
from sim_harness.px4 import telemetry as tm
from sim_harness.px4.mavlink_io import MavlinkLink
from sim_harness.px4.mavlink_io import mavlink2 as m
from sim_harness.px4.modes import ModeError, decode_custom_mode, decode_mode_params
from sim_harness.px4.vehicle import CommandResult, Setpoint

if TYPE_CHECKING:
    from sim_harness.px4.emulator import Px4Emulator

__all__ = ["FORCE_MAGIC", "CommandHandler"]

log = get_logger(__name__)

FORCE_MAGIC = 21196.0
"""param2 of MAV_CMD_COMPONENT_ARM_DISARM that forces arm/disarm (PX4 and ArduPilot)."""

_POS_IGNORE = 0b111
_VEL_IGNORE = 0b111 << 3
_YAW_IGNORE = 1 << 10
_SUPPORTED_FRAMES = (m.MAV_FRAME_LOCAL_NED,)

_NAMES_BY_ID = {
    m.MAVLINK_MSG_ID_HEARTBEAT: "HEARTBEAT",
    m.MAVLINK_MSG_ID_LOCAL_POSITION_NED: "LOCAL_POSITION_NED",
    m.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: "ATTITUDE_QUATERNION",
    m.MAVLINK_MSG_ID_ODOMETRY: "ODOMETRY",
    m.MAVLINK_MSG_ID_SYS_STATUS: "SYS_STATUS",
    m.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: "EXTENDED_SYS_STATE",
    m.MAVLINK_MSG_ID_HOME_POSITION: "HOME_POSITION",
    m.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: "GLOBAL_POSITION_INT",
}


_INT_TYPES = (m.MAV_PARAM_TYPE_INT8, m.MAV_PARAM_TYPE_INT16, m.MAV_PARAM_TYPE_INT32,
              m.MAV_PARAM_TYPE_UINT8, m.MAV_PARAM_TYPE_UINT16, m.MAV_PARAM_TYPE_UINT32)


def _wire_value(value: float, ptype: int) -> float:
    """PARAM_VALUE.param_value as PX4 sends it: an integer parameter's bytes in the float field
    (MAVLink's bytewise encoding, which MAVSDK expects from PX4), a float as itself."""
    if ptype in _INT_TYPES:
        return float(struct.unpack("<f", struct.pack("<i", int(value)))[0])
    return float(value)


def _from_wire(wire: float, ptype: int) -> float:
    """The value of a PARAM_SET.param_value for a parameter of type ``ptype`` (bytewise ints)."""
    if ptype in _INT_TYPES:
        return float(struct.unpack("<i", struct.pack("<f", wire))[0])
    return float(wire)


def _finite(x: float) -> bool:
    return x is not None and isinstance(x, (int, float)) and math.isfinite(x)


class CommandHandler:
    """Dispatches received messages to the vehicle; owned by the emulator thread."""

    def __init__(self, emulator: Px4Emulator) -> None:
        self.emu = emulator
        self.intervals_s: dict[str, float] = {}
        """Message intervals (s) set by SET_MESSAGE_INTERVAL; <= 0 disables a stream."""
        cfg = emulator.config
        self.params: dict[str, tuple[float, int]] = {
            "MIS_TAKEOFF_ALT": (cfg.takeoff_alt_m, m.MAV_PARAM_TYPE_REAL32),
            "COM_OF_LOSS_T": (cfg.com_of_loss_t_s, m.MAV_PARAM_TYPE_REAL32),
            # PX4 COM_OBL_RC_ACT: 0 Position, 1 Altitude, 2 Manual, 3 Return, 4 Land, 5 Hold.
            "COM_OBL_RC_ACT": ({"px4": 0.0, "hold": 5.0, "land": 4.0}[cfg.offboard_loss_action],
                               m.MAV_PARAM_TYPE_INT32),
            "MPC_LAND_SPEED": (cfg.land_speed_m_s, m.MAV_PARAM_TYPE_REAL32),
            "COM_DISARM_LAND": (cfg.land_disarm_s, m.MAV_PARAM_TYPE_REAL32),
            "SYS_HITL": (0.0, m.MAV_PARAM_TYPE_INT32),
            "MAV_SYS_ID": (float(cfg.system_id), m.MAV_PARAM_TYPE_INT32),
            "EKF2_EV_CTRL": (15.0 if cfg.vision_only else 0.0, m.MAV_PARAM_TYPE_INT32),
            # PX4 EKF2_HGT_REF: 0 baro, 1 GPS (SITL's default), 2 range, 3 vision.
            "EKF2_HGT_REF": (3.0 if cfg.vision_only else 1.0, m.MAV_PARAM_TYPE_INT32),
            "COM_RC_IN_MODE": (float(cfg.rc_in_mode), m.MAV_PARAM_TYPE_INT32),
            "COM_FAIL_ACT_T": (cfg.failsafe_delay_s, m.MAV_PARAM_TYPE_REAL32),
            "COM_OBC_LOSS_T": (cfg.companion_loss_s, m.MAV_PARAM_TYPE_REAL32),
        }

    # --- dispatch ------------------------------------------------------------------------------
    def handle(self, msg: Any, link: MavlinkLink, t: float) -> None:
        kind = msg.get_type()
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._command(msg, link, t)
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._setpoint(msg, t)
        elif kind in ("VISION_POSITION_ESTIMATE", "ATT_POS_MOCAP") or (
            kind == "ODOMETRY" and msg.get_srcComponent() != m.MAV_COMP_ID_AUTOPILOT1
        ):
            self.emu.vehicle.on_vision(t)
        elif kind == "SET_MODE":
            self._set_mode_packed(msg.custom_mode, t)  # legacy message: no COMMAND_ACK
        elif kind in ("PARAM_REQUEST_READ", "PARAM_REQUEST_LIST", "PARAM_SET"):
            self._param(msg, link, t)
        elif kind == "HEARTBEAT" and msg.type == m.MAV_TYPE_ONBOARD_CONTROLLER:
            self.emu.vehicle.on_companion_heartbeat(t)
        elif kind == "TIMESYNC" and msg.tc1 == 0:
            self.emu.send(m.MAVLink_timesync_message(int(t * 1e9), msg.ts1), t, link)

    def _set_mode_packed(self, custom_mode: int, t: float) -> CommandResult:
        try:
            return self._switch(decode_custom_mode(custom_mode), t)
        except ModeError as exc:
            return CommandResult(False, str(exc), unsupported=True)

    def _switch(self, mode: str, t: float) -> CommandResult:
        if self.emu.faults.mode_denied(mode):
            self.emu.vehicle.events.append((t, "mode_denied", f"switch to {mode} denied by fault injection"))
            return CommandResult(False, f"switch to {mode} denied (fault)")
        return self.emu.vehicle.set_mode(t, mode)

    # --- commands ------------------------------------------------------------------------------
    def _ack(self, msg: Any, link: MavlinkLink, t: float, result: CommandResult | int) -> None:
        if isinstance(result, CommandResult):
            code = (m.MAV_RESULT_ACCEPTED if result.accepted
                    else m.MAV_RESULT_UNSUPPORTED if result.unsupported else m.MAV_RESULT_DENIED)
        else:
            code = result
        ack = m.MAVLink_command_ack_message(
            msg.command, code, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        )
        self.emu.send(ack, t, link)

    def _command(self, msg: Any, link: MavlinkLink, t: float) -> None:
        if msg.target_system not in (0, self.emu.config.system_id):
            return
        cmd = msg.command
        v = self.emu.vehicle
        p = [msg.param1, msg.param2, msg.param3, msg.param4]
        if cmd == m.MAV_CMD_COMPONENT_ARM_DISARM:
            force = _finite(p[1]) and abs(p[1] - FORCE_MAGIC) < 0.5
            if not _finite(p[0]) or p[0] not in (0.0, 1.0):
                result: CommandResult | int = m.MAV_RESULT_DENIED
            else:
                result = v.arm(t, force) if p[0] == 1.0 else v.disarm(t, force)
        elif cmd == m.MAV_CMD_DO_SET_MODE:
            result = self._do_set_mode(p, t)
        elif cmd == m.MAV_CMD_NAV_TAKEOFF:
            z = msg.z if msg.get_type() == "COMMAND_INT" else msg.param7
            alt = float(z) - self.emu.config.home_amsl_m - v.floor_z_m if _finite(z) else None
            result = (self._switch("TAKEOFF", t) if self.emu.faults.mode_denied("TAKEOFF")
                      else v.takeoff(t, alt))
        elif cmd == m.MAV_CMD_NAV_LAND:
            result = self._switch("LAND", t) if self.emu.faults.mode_denied("LAND") else v.land(t)
        elif cmd == m.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self._set_interval(p[0], p[1])
        elif cmd in (m.MAV_CMD_REQUEST_MESSAGE, m.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES):
            msg_id = p[0] if cmd == m.MAV_CMD_REQUEST_MESSAGE else m.MAVLINK_MSG_ID_AUTOPILOT_VERSION
            reply = self._requested_message(msg_id, t)
            self._ack(msg, link, t, m.MAV_RESULT_UNSUPPORTED if reply is None else m.MAV_RESULT_ACCEPTED)
            if reply is not None:  # the message follows its ACK, as PX4 does
                self.emu.send(reply, t, link)
            return
        else:
            log.debug("px4_emulator_unsupported_command", command=cmd)
            result = m.MAV_RESULT_UNSUPPORTED
        self._ack(msg, link, t, result)

    def _do_set_mode(self, p: list[float], t: float) -> CommandResult:
        base = int(p[0]) if _finite(p[0]) else 0
        if not base & m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return CommandResult(False, "DO_SET_MODE without custom mode", unsupported=True)
        try:
            mode = decode_mode_params(p[1], p[2])
        except ModeError as exc:
            return CommandResult(False, str(exc), unsupported=True)
        if mode == "LAND" and not self.emu.faults.mode_denied("LAND"):
            return self.emu.vehicle.land(t)
        return self._switch(mode, t)

    def _set_interval(self, msg_id: float, interval_us: float) -> int:
        if not (_finite(msg_id) and _finite(interval_us)):
            return m.MAV_RESULT_DENIED
        name = _NAMES_BY_ID.get(int(msg_id))
        if name is None:
            return m.MAV_RESULT_ACCEPTED  # PX4 accepts and ignores streams it does not have
        if interval_us == 0:
            self.intervals_s.pop(name, None)
        elif interval_us < 0:
            self.intervals_s[name] = -1.0
        else:
            self.intervals_s[name] = max(interval_us * 1e-6, 1.0 / 250.0)
        return m.MAV_RESULT_ACCEPTED

    def _requested_message(self, msg_id: float, t: float) -> Any | None:
        if not _finite(msg_id):
            return None
        snap = self.emu.snapshot(t)
        builders = {
            m.MAVLINK_MSG_ID_AUTOPILOT_VERSION: lambda: tm.autopilot_version(self.emu.config.system_id),
            m.MAVLINK_MSG_ID_HOME_POSITION: lambda: tm.home_position(snap, self.emu.config),
            m.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: lambda: tm.extended_sys_state(snap),
            m.MAVLINK_MSG_ID_SYS_STATUS: lambda: tm.sys_status(snap),
            m.MAVLINK_MSG_ID_HEARTBEAT: lambda: tm.heartbeat(snap),
        }
        build = builders.get(int(msg_id))
        return None if build is None else build()

    # --- setpoints and parameters ----------------------------------------------------------------
    def _setpoint(self, msg: Any, t: float) -> None:
        if msg.target_system not in (0, self.emu.config.system_id):
            return
        if msg.coordinate_frame not in _SUPPORTED_FRAMES:
            self.emu.vehicle.events.append((t, "setpoint_rejected", f"frame {msg.coordinate_frame}"))
            return
        mask = msg.type_mask
        pos_ned = np.array([msg.x, msg.y, msg.z], dtype=np.float64)
        vel_ned = np.array([msg.vx, msg.vy, msg.vz], dtype=np.float64)
        pos = (frd_to_flu(pos_ned) - self.emu.local_offset_world_m
               if not mask & _POS_IGNORE and np.all(np.isfinite(pos_ned)) else None)
        vel = frd_to_flu(vel_ned) if not mask & _VEL_IGNORE and np.all(np.isfinite(vel_ned)) else None
        yaw = float(yaw_frd_to_flu(msg.yaw)) if not mask & _YAW_IGNORE and _finite(msg.yaw) else None
        if pos is None and vel is None:
            return  # PX4 needs position or velocity for the offboard position controller
        self.emu.vehicle.on_setpoint(Setpoint(pos, vel, yaw, t))

    def _param_value(self, name: str, index: int, link: MavlinkLink, t: float) -> None:
        value, ptype = self.params[name]
        wire = _wire_value(value, ptype)
        msg = m.MAVLink_param_value_message(name.encode(), wire, ptype, len(self.params), index)
        self.emu.send(msg, t, link)

    def _param(self, msg: Any, link: MavlinkLink, t: float) -> None:
        names = list(self.params)
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            for i, name in enumerate(names):
                self._param_value(name, i, link, t)
            return
        name = msg.param_id.decode() if isinstance(msg.param_id, bytes) else str(msg.param_id)
        name = name.rstrip("\x00")
        if kind == "PARAM_REQUEST_READ" and not name and 0 <= msg.param_index < len(names):
            name = names[msg.param_index]
        if name not in self.params:
            log.debug("px4_emulator_unknown_param", name=name)
            return  # PX4 stays silent for unknown parameters; MAVSDK times out on its side
        if kind == "PARAM_SET" and _finite(msg.param_value):
            ptype = self.params[name][1]
            self.params[name] = (_from_wire(float(msg.param_value), ptype), ptype)
            if name == "MIS_TAKEOFF_ALT":
                self.emu.vehicle.takeoff_alt_m = float(msg.param_value)
        self._param_value(name, names.index(name), link, t)
