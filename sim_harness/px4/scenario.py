"""Fault scenarios from YAML, applied to an emulator's :class:`~sim_harness.px4.faults.Faults`.

    # faults.yaml: times in seconds from the emulator's start
    faults:
      - {kind: drop_link, at_s: 20.0, duration_s: 1.5}
      - {kind: delay_link, at_s: 5.0, duration_s: 3.0, delay_s: 0.3}
      - {kind: freeze_position, at_s: 12.0, duration_s: 1.0}
      - {kind: deny_mode, mode: OFFBOARD}
      - {kind: crash, at_s: 30.0}

A bad file raises :class:`quadnav_onboard.config.ConfigError` naming the file, the key and value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import pydantic

from quadnav_onboard.config import ConfigError, load_yaml_config
from sim_harness.px4.faults import Faults
from sim_harness.px4.modes import MODE_NAMES

__all__ = ["FaultSpec", "Scenario", "apply_scenario", "load_scenario"]


@dataclass(frozen=True)
class FaultSpec:
    """One scheduled fault."""

    __pydantic_config__ = {"extra": "forbid"}  # config files: unknown keys are errors

    kind: Literal["drop_link", "delay_link", "freeze_position", "deny_mode", "crash"]
    """What goes wrong."""
    at_s: Annotated[float, pydantic.Field(ge=0, allow_inf_nan=False)] = 0.0
    """When it starts (s after the emulator starts)."""
    duration_s: Annotated[float, pydantic.Field(gt=0)] = math.inf
    """How long it lasts (s); windows only (drop/delay/freeze)."""
    delay_s: Annotated[float, pydantic.Field(gt=0, allow_inf_nan=False)] = 0.3
    """One-way extra latency (s) for ``delay_link``."""
    mode: str | None = None
    """The refused mode for ``deny_mode`` (e.g. OFFBOARD, LAND, HOLD, TAKEOFF)."""


@dataclass(frozen=True)
class Scenario:
    """A list of faults."""

    __pydantic_config__ = {"extra": "forbid"}  # config files: unknown keys are errors

    faults: tuple[FaultSpec, ...] = ()
    """The faults, in any order."""


def load_scenario(path: str | Path) -> Scenario:
    scenario = load_yaml_config(Scenario, path)
    for i, f in enumerate(scenario.faults):
        if f.kind == "deny_mode" and f.mode not in MODE_NAMES:
            raise ConfigError(f"{path}: key 'faults.{i}.mode': bad value {f.mode!r}: "
                              f"expected one of {sorted(MODE_NAMES)}")
    return scenario


def apply_scenario(faults: Faults, scenario: Scenario, elapsed_s: float = 0.0) -> None:
    """Schedule every fault; ``elapsed_s`` is how long the emulator has already run."""
    for f in scenario.faults:
        start = max(0.0, f.at_s - elapsed_s)
        if f.kind == "drop_link":
            faults.drop_link(start, f.duration_s)
        elif f.kind == "delay_link":
            faults.delay_link(start, f.duration_s, f.delay_s)
        elif f.kind == "freeze_position":
            faults.freeze_position(start, f.duration_s)
        elif f.kind == "deny_mode":
            faults.deny_mode(str(f.mode))
        else:
            faults.crash_at(start)
