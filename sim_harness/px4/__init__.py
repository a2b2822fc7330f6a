"""An emulated PX4 on real MAVLink 2 over UDP (see :mod:`sim_harness.px4.emulator`)."""

from sim_harness.px4.config import EmulatorConfig
from sim_harness.px4.emulator import Px4Emulator
from sim_harness.px4.faults import Faults
from sim_harness.px4.ports import free_udp_port
from sim_harness.px4.telemetry import TruePose

__all__ = ["EmulatorConfig", "Faults", "Px4Emulator", "TruePose", "free_udp_port"]
