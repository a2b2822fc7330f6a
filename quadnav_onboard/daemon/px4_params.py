"""PX4's parameters that a flight depends on: which to read, and what each value means.

Pure: :func:`parameter_rules` says what to read for a flight configuration and
:func:`judge_parameters` turns the values read (over MAVLink, in preflight) into findings. A
finding of severity ``REQUIRED`` refuses the flight with the list of parameters to set; ``ADVICE``
is logged as a warning. The values and their reasons are those of docs/hardware.md, section
"PX4 parameters" (PX4 v1.16 SITL defaults measured over MAVLink).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Literal

from quadnav_onboard.daemon.config import FlightConfig

__all__ = ["ParamFinding", "ParamRule", "Severity", "judge_parameters", "parameter_rules"]

ParamKind = Literal["int", "float"]


class Severity(enum.Enum):
    """What a wrong value does to the flight."""

    REQUIRED = "required"
    """The flight is refused until the parameter is set."""
    ADVICE = "advice"
    """A warning in preflight's log; the flight goes on."""


@dataclass(frozen=True)
class ParamRule:
    """One parameter: its type on the wire, the values that are fine, and why."""

    name: str
    kind: ParamKind
    ok: Callable[[float], bool]
    want: str
    """The values that are fine, in words (goes into the refusal or the warning)."""
    severity: Severity


@dataclass(frozen=True)
class ParamFinding:
    """A parameter whose value (or absence) is not what the flight wants."""

    name: str
    value: float | None
    """The value read; None when PX4 did not answer for it."""
    want: str
    severity: Severity

    def __str__(self) -> str:
        got = "not read" if self.value is None else f"{self.value:g}"
        return f"{self.name}={got} (want {self.want})"


def _bits(mask: int) -> Callable[[float], bool]:
    return lambda v: (int(v) & mask) == mask


def parameter_rules(cfg: FlightConfig) -> list[ParamRule]:
    """The parameters read for ``cfg``: the failsafe ones always; the external-vision ones
    required only when mocap is forwarded to PX4's estimator (else advice)."""
    vision = cfg.odometry.kind == "mocap" and cfg.odometry.forward_to_px4
    ev = Severity.REQUIRED if vision else Severity.ADVICE
    return [
        ParamRule("COM_OF_LOSS_T", "float", lambda v: 0.0 < v <= 1.0,
                  "0 < s <= 1.0: offboard loss found within a second (PX4 default 1.0)", Severity.REQUIRED),
        ParamRule("COM_OBL_RC_ACT", "int", lambda v: int(v) in (0, 1, 2, 3, 4, 5),
                  "0-5: a flying failsafe (0 Position, 4 Land, 5 Hold), never 6 Terminate or 7 Disarm",
                  Severity.REQUIRED),
        ParamRule("COM_RC_IN_MODE", "int", lambda v: int(v) in (0, 2, 3),
                  "0, 2 or 3: a safety pilot's RC can take over (4 disables manual control; "
                  "1 is joystick only, SITL's default)", Severity.ADVICE),
        ParamRule("COM_DISARM_LAND", "float", lambda v: v > 0.0,
                  "> 0 s: PX4 disarms by itself after touchdown (else the daemon disarms)", Severity.ADVICE),
        ParamRule("EKF2_EV_CTRL", "int", _bits(0b1011),
                  "bits 0, 1 and 3 (horizontal and vertical position, yaw): fuse the forwarded mocap",
                  ev),
        ParamRule("EKF2_HGT_REF", "int", lambda v: int(v) == 3,
                  "3 (vision): the forwarded mocap is the height reference; otherwise the ground is "
                  "not z = 0 (the daemon flies relative to the take-off ground)", ev),
    ]


def judge_parameters(rules: list[ParamRule], values: Mapping[str, float | None]) -> list[ParamFinding]:
    """Findings for the values read (a missing or non-finite value is a finding of its rule)."""
    found = []
    for r in rules:
        v = values.get(r.name)
        if v is None or not math.isfinite(v) or not r.ok(v):
            found.append(ParamFinding(r.name, v, r.want, r.severity))
    return found
