"""PX4 custom flight modes and their MAVLink encoding.

PX4 puts its own mode in HEARTBEAT.custom_mode as ``main_mode << 16 | sub_mode << 24`` (see PX4's
``px4_custom_mode.h``) and sets ``MAV_MODE_FLAG_CUSTOM_MODE_ENABLED`` in ``base_mode``. A mode
switch arrives as ``MAV_CMD_DO_SET_MODE`` with param1 = base mode, param2 = main mode,
param3 = sub mode (or as the legacy SET_MODE message with the packed custom mode).

Modes are named by the strings MAVSDK's ``FlightMode`` uses for them: "HOLD" is PX4's
AUTO.LOITER, "TAKEOFF" AUTO.TAKEOFF, "LAND" AUTO.LAND, "RTL" AUTO.RTL, "MISSION" AUTO.MISSION.
"""

from __future__ import annotations

__all__ = [
    "AUTO_SUB_MODES",
    "MAIN_MODES",
    "MODE_NAMES",
    "ModeError",
    "decode_custom_mode",
    "decode_mode_params",
    "encode_custom_mode",
]

MAIN_MODES: dict[str, int] = {
    "MANUAL": 1,
    "ALTCTL": 2,
    "POSCTL": 3,
    "AUTO": 4,
    "ACRO": 5,
    "OFFBOARD": 6,
    "STABILIZED": 7,
    "RATTITUDE": 8,
}
"""PX4 ``PX4_CUSTOM_MAIN_MODE_*`` values."""

AUTO_SUB_MODES: dict[str, int] = {
    "READY": 1,
    "TAKEOFF": 2,
    "HOLD": 3,  # AUTO_LOITER
    "MISSION": 4,
    "RTL": 5,
    "LAND": 6,
    "FOLLOW_TARGET": 8,
    "PRECLAND": 9,
}
"""PX4 ``PX4_CUSTOM_SUB_MODE_AUTO_*`` values, keyed by the flight-mode name."""

_BY_PAIR: dict[tuple[int, int], str] = {(v, 0): k for k, v in MAIN_MODES.items() if k != "AUTO"}
_BY_PAIR.update({(MAIN_MODES["AUTO"], v): k for k, v in AUTO_SUB_MODES.items()})

MODE_NAMES: frozenset[str] = frozenset(_BY_PAIR.values())
"""Every mode name the emulator can report."""


class ModeError(ValueError):
    """A mode name or custom-mode value that PX4 does not define."""


def encode_custom_mode(mode: str) -> int:
    """HEARTBEAT.custom_mode (uint32) of a mode name, e.g. ``"OFFBOARD" -> 6 << 16``."""
    if mode in AUTO_SUB_MODES:
        return (MAIN_MODES["AUTO"] << 16) | (AUTO_SUB_MODES[mode] << 24)
    if mode in MAIN_MODES and mode != "AUTO":
        return MAIN_MODES[mode] << 16
    raise ModeError(f"unknown PX4 mode {mode!r}; known: {sorted(MODE_NAMES)}")


def decode_custom_mode(custom_mode: int) -> str:
    """Mode name of a packed HEARTBEAT.custom_mode; raises ModeError for unknown values."""
    main = (int(custom_mode) >> 16) & 0xFF
    sub = (int(custom_mode) >> 24) & 0xFF
    return decode_mode_params(main, sub)


def decode_mode_params(main_mode: float, sub_mode: float) -> str:
    """Mode name of DO_SET_MODE's param2 (main) and param3 (sub); NaN or junk -> ModeError."""
    try:
        main, sub = int(main_mode), int(sub_mode) if sub_mode == sub_mode else 0
    except (TypeError, ValueError, OverflowError) as exc:
        raise ModeError(f"bad mode parameters main={main_mode!r} sub={sub_mode!r}") from exc
    if main != MAIN_MODES["AUTO"]:
        sub = 0
    try:
        return _BY_PAIR[(main, sub)]
    except KeyError:
        raise ModeError(f"unknown PX4 mode main={main} sub={sub}") from None
