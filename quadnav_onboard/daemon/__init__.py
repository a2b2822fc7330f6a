"""The flight daemon ``quadnav-onboard``: sensors -> state -> policy -> primitive -> setpoints -> vehicle,
with a safety supervisor that can cut in at every arrow. See docs/daemon.md.

Modules: :mod:`config` (the frozen flight config), :mod:`supervisor` (StopReason, ExitCode, checks),
:mod:`mission` (the step's one-vehicle geometry and the setpoint trajectories), :mod:`stepper` (the
planner step of :mod:`quadnav_onboard.step` with N = 1), :mod:`state` (the flight's phase and stop
request), :mod:`loops` (the sensor, streamer and supervisor tasks), :mod:`planner` (the mission
task), :mod:`preflight`, :mod:`ladder` (the stop response), :mod:`summary`, :mod:`app` (the
lifecycle that composes them), :mod:`hardware` and :mod:`dryrun` (wiring), :mod:`testing` (fakes
for tests).
"""

from quadnav_onboard.daemon.app import FlightDaemon
from quadnav_onboard.daemon.config import FlightConfig, default_sim_config, load_flight_config
from quadnav_onboard.daemon.summary import FlightSummary
from quadnav_onboard.daemon.supervisor import ExitCode, StopReason

__all__ = [
    "ExitCode",
    "FlightConfig",
    "FlightDaemon",
    "FlightSummary",
    "StopReason",
    "default_sim_config",
    "load_flight_config",
]
