"""The flight's phase and its stop request: one object, owned by the daemon, read by every task.

:class:`FlightState` is the only place the phase and the flags that follow it (``streaming``,
``supervising``, ``flying``, ``in_mission``) change, each through a named method, and the only
place a stop is recorded (:meth:`FlightState.request_stop`, the first :class:`StopReason` wins).
The tasks read it; none of them keeps a copy.
"""

from __future__ import annotations

import asyncio
import enum
import time
from dataclasses import dataclass

from quadnav_onboard.daemon.recording import SafeRecorder
from quadnav_onboard.daemon.supervisor import StopReason
from quadnav_onboard.logs import get_logger

__all__ = ["FlightState", "Phase", "StopRequest"]

log = get_logger("quadnav.daemon")


class Phase(str, enum.Enum):
    """Where the lifecycle is, in the order it runs (the value is the name in logs and records)."""

    STARTUP = "startup"
    CONNECT = "connect"
    PREFLIGHT = "preflight"
    WAIT_FOR_GO = "wait_for_go"
    TAKEOFF = "takeoff"
    MISSION = "mission"
    STOP = "stop"

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class StopRequest:
    """Why the flight stops: the reason decides the response, the detail is for people only."""

    reason: StopReason
    detail: str
    t_threshold_mono_s: float | None = None
    """When a stale input crossed its limit (monotonic s): the hold's reaction time is timed from
    it; None for any other stop."""


class FlightState:
    """The phase, the commanding flags and the stop request of one flight.

    ``streaming``: the setpoint streamer sends the active trajectory. ``supervising``: the
    supervisor's in-flight checks may stop the flight (from arming on). ``flying``: arming was
    commanded (or the pilot armed), so the stop ladder has a vehicle to answer for.
    ``in_mission``: the planner is stepping."""

    def __init__(self, recorder: SafeRecorder) -> None:
        self._recorder = recorder
        self.phase = Phase.STARTUP
        self.streaming = False
        self.supervising = False
        self.flying = False
        self.in_mission = False
        self.stop: StopRequest | None = None
        """The first stop requested; None while the flight goes on."""
        self.stopped = asyncio.Event()
        """Set by the first stop request: the lifecycle wakes and runs the ladder."""

    @property
    def stop_reason(self) -> StopReason | None:
        return None if self.stop is None else self.stop.reason

    # --- transitions -----------------------------------------------------------------------------

    def enter(self, phase: Phase) -> None:
        """The lifecycle moved on to ``phase``."""
        self.phase = phase
        if phase is Phase.MISSION:
            self.in_mission = True

    def start_streaming(self) -> None:
        """The setpoint streamer starts (or resumes) sending; refused once a stop is requested."""
        if self.stop is None:
            self.streaming = True

    def pause_streaming(self) -> None:
        """The setpoint streamer stops sending (it keeps its trajectory)."""
        self.streaming = False

    def arming(self) -> None:
        """Arming is commanded now (or the pilot armed): from here on the ladder answers for the
        vehicle."""
        self.flying = True

    def airborne(self) -> None:
        """Armed and in OFFBOARD: the supervisor's in-flight checks run from now."""
        self.supervising = True

    def stopping(self) -> None:
        """The stop ladder takes over: nothing streams or supervises any more."""
        self.phase = Phase.STOP
        self.streaming = False
        self.supervising = False

    # --- the stop --------------------------------------------------------------------------------

    def request_stop(self, reason: StopReason, detail: str, t_threshold_mono_s: float | None = None) -> bool:
        """Record the first stop and wake the lifecycle; True for that first one. A later request
        is logged only. Streaming stops at once: the ladder takes over."""
        if self.stop is not None:
            log.info("stop_ignored", reason=reason.value, detail=detail, stopping_for=self.stop.reason.value)
            return False
        self.stop = StopRequest(reason, detail, t_threshold_mono_s)
        self.streaming = False
        phase = self.phase.value
        log.warning("stop", reason=reason.value, detail=detail, phase=phase, exit_code=int(reason.exit_code))
        self._recorder.event(time.monotonic(), "stop", detail, reason=reason.value, phase=phase)
        self.stopped.set()
        return True
