"""Latest-value holders, bounded latency statistics (no unbounded queues anywhere) and the
flight's run figures that the summary reports."""

from __future__ import annotations

import asyncio
import math
from collections import deque
from collections.abc import Iterable
from typing import TYPE_CHECKING, Generic, TypeVar

import numpy as np

if TYPE_CHECKING:
    from quadnav_onboard.daemon.decide import DecisionPath

__all__ = ["LatencyStats", "Latest", "RunStats"]

T = TypeVar("T")


class Latest(Generic[T]):
    """Holds the newest value only (latest wins); ``wait_newer`` waits for a value after ``seq``."""

    def __init__(self) -> None:
        self.value: T | None = None
        self.seq = 0
        self._cond = asyncio.Event()

    def set(self, value: T) -> None:
        self.value = value
        self.seq += 1
        self._cond.set()
        self._cond = asyncio.Event()

    async def wait_newer(self, seq: int) -> T:
        """Return the value once ``self.seq > seq`` (callers wrap this in ``asyncio.timeout``)."""
        while self.seq <= seq:
            await self._cond.wait()
        assert self.value is not None
        return self.value


class LatencyStats:
    """A bounded window of durations (s) with percentiles in ms."""

    def __init__(self, maxlen: int = 20_000) -> None:
        self._values: deque[float] = deque(maxlen=maxlen)

    def add(self, seconds: float) -> None:
        self._values.append(float(seconds))

    def extend(self, values: Iterable[float]) -> None:
        self._values.extend(float(v) for v in values)

    def __len__(self) -> int:
        return len(self._values)

    def percentile_ms(self, q: float) -> float:
        """The q-th percentile (0..100) in ms; NaN when empty."""
        if not self._values:
            return math.nan
        return float(np.percentile(np.fromiter(self._values, float), q) * 1e3)

    def summary(self) -> dict[str, float]:
        """{"n", "p50_ms", "p99_ms", "max_ms"} (NaN when empty)."""
        return {
            "n": float(len(self._values)),
            "p50_ms": self.percentile_ms(50),
            "p99_ms": self.percentile_ms(99),
            "max_ms": self.percentile_ms(100),
        }


class RunStats:
    """Bounded timing figures of one flight (seconds in, ms out)."""

    def __init__(self) -> None:
        self.decision_latency = LatencyStats()
        """Decision start (newest frame taken) -> first setpoint of the new primitive sent."""
        self.inference = LatencyStats()
        """The step's DQN work from the step boundary: the head, plus any wait for, or run of, the
        newest frame's preparation."""
        self.frame_age = LatencyStats()
        """Age of the depth frame a decision used, at the step boundary (sensor latency, not
        decision latency)."""
        self.decision_paths: dict[DecisionPath, int] = {"prepared": 0, "waited": 0, "full": 0}
        """How each decision got its prepared frame (see ``decide.DecisionPath``)."""
        self.setpoint_interval = LatencyStats()
        """Time between consecutive setpoints sent."""
        self.hold_reaction_s: float | None = None
        """Stale-input threshold crossing -> hold command issued (None if no such stop)."""
        self.depth_frames = 0
        self.depth_frames_prepared = 0
        """Frames preprocessed and run through the depth lane (on arrival or at a step)."""
        self.depth_frames_checked = 0
        """Frames only checked, too early before a step boundary to be used (``prepare_within_s``)."""
        self.odometry_samples = 0
        self.setpoints = 0
        self.vision_forwards = 0
        """Vision estimates forwarded to PX4."""
        self.vision_forward_failures = 0
        """Vision forwards that failed (the link refused or could not send them)."""
        self.warmup_s: float | None = None
        """Preflight's test decisions: compiling (or loading from cache) every kernel and the
        network's first call, before anything arms."""
        self.ready_s: float | None = None
        """Daemon start -> READY (preflight passed)."""
        self.kernels_compiled_in_flight: dict[str, list[str]] = {}
        """Kernels that compiled a new signature after arming, and those signatures (none expected)."""
        self.stops_deferred_for_link = 0
        """Stops found while the link was quiet, held until the link's verdict."""
        self.ground: dict[str, object] = {}
        """The ground frame flown (``GroundFrame.describe``)."""
        self.odometry: dict[str, float | None] = {}
        """The odometry stream measured in preflight and the stale limit sized from it."""
        self.px4_parameters: dict[str, object] = {}
        """PX4's parameters read in preflight: {"values": {name: value}, "required": [...],
        "advice": [...]} (the findings, as text)."""
        self.offboard_start_attempts = 1
        """Tries the switch to OFFBOARD took (more than 1: PX4 refused the first)."""
        self.landing: dict[str, object] = {}
        """How the flight ended on the ground after the ladder's land: {"landed": bool, "disarm":
        "auto" | "commanded" | "still_armed", "waited_s": s}; empty when it did not land."""

    def count_decision(self, path: DecisionPath, frame_age_s: float) -> None:
        self.decision_paths[path] += 1
        self.frame_age.add(frame_age_s)
