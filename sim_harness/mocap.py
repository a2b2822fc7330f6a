"""Simulated motion capture: the vehicle's true pose at 100-120 Hz with noise, latency and dropouts.

Implements :class:`quadnav_onboard.sources.OdometrySource`. Two backends:

* ``"sim"``: samples ``pose_fn`` on a ``rate_hz`` grid of the monotonic clock.
* ``"motioncapture-mock"``: the `motioncapture` library's ``mock`` backend runs the frame loop
  (``waitForNextFrame``, its fixed 100 Hz) and every pose passes through the library's rigid-body
  path (its mock serves static bodies, so each frame's true pose is handed to a fresh mock
  connection and read back as ``RigidBody``: float32 positions, its quaternion type). The real
  library code runs; only the network backend differs from a lab (Vicon, OptiTrack, ...).

A sample taken at t is delivered at t + ``latency_s``. A slow consumer gets the newest due sample
(older ones are dropped and counted, never queued without bound). ``pause()``/``resume()``
simulate losing the tracking (occluded markers).
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any, Generic, Literal, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.frames import quat_from_yaw, quat_multiply
from quadnav_onboard.sources.base import OdometrySample

__all__ = ["MOCK_RATE_HZ", "PoseLike", "SimMocap"]

MOCK_RATE_HZ = 100.0
"""Frame rate of the motioncapture library's mock backend (fixed in the library)."""


class PoseLike(Protocol):
    """What ``pose_fn`` returns (e.g. :class:`sim_harness.px4.TruePose`)."""

    pos_world_m: NDArray[np.float64]
    quat_world_body: NDArray[np.float64]


class SimMocap:
    """``async with SimMocap(emu.true_pose) as mocap: async for s in mocap.samples(): ...``"""

    def __init__(
        self,
        pose_fn: Callable[[], PoseLike],
        rate_hz: float = 120.0,
        noise_m: float = 0.0,
        latency_s: float = 0.0,
        dropout: float = 0.0,
        seed: int = 0,
        noise_rad: float = 0.0,
        backend: Literal["sim", "motioncapture-mock"] = "sim",
        body_name: str = "quad",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        for name, value, ok in (
            ("rate_hz", rate_hz, rate_hz > 0),
            ("noise_m", noise_m, noise_m >= 0),
            ("latency_s", latency_s, latency_s >= 0),
            ("dropout", dropout, 0 <= dropout < 1),
            ("noise_rad", noise_rad, noise_rad >= 0),
        ):
            if not (math.isfinite(value) and ok):
                raise ValueError(f"SimMocap: bad {name}={value!r}")
        if backend not in ("sim", "motioncapture-mock"):
            raise ValueError(f"SimMocap: backend must be 'sim' or 'motioncapture-mock', got {backend!r}")
        self.pose_fn = pose_fn
        self.rate_hz = MOCK_RATE_HZ if backend == "motioncapture-mock" else float(rate_hz)
        self.noise_m = float(noise_m)
        self.noise_rad = float(noise_rad)
        self.latency_s = float(latency_s)
        self.dropout = float(dropout)
        self.backend = backend
        self.body_name = body_name
        self._rng = np.random.default_rng(seed)
        self._clock = clock
        self._paused_until = -math.inf
        self._pacer: Any = None
        self.taken = 0
        """Samples taken (before dropout)."""
        self.dropped = 0
        """Samples lost: random dropout, pause, or superseded while the consumer was slow."""

    async def __aenter__(self) -> SimMocap:
        if self.backend == "motioncapture-mock":
            import motioncapture

            self._motioncapture = motioncapture
            self._pacer = motioncapture.connect("mock", {"rigid_bodies": f"{self.body_name}(0,0,0,1,0,0,0)"})
        return self

    async def __aexit__(self, *exc: object) -> None:
        self._pacer = None

    def pause(self, duration_s: float = math.inf) -> None:
        """Lose tracking for ``duration_s`` seconds (until :meth:`resume` by default)."""
        self._paused_until = self._clock() + duration_s

    def resume(self) -> None:
        self._paused_until = -math.inf

    # --- one sample ----------------------------------------------------------------------------
    def _measure(self, pose: PoseLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        pos = np.asarray(pose.pos_world_m, dtype=np.float64).copy()
        quat = np.asarray(pose.quat_world_body, dtype=np.float64).copy()
        if self.backend == "motioncapture-mock":
            pos, quat = self._through_library(pos, quat)
        if self.noise_m > 0:
            pos = pos + self._rng.normal(0.0, self.noise_m, 3)
        if self.noise_rad > 0:
            quat = quat_multiply(quat_from_yaw(self._rng.normal(0.0, self.noise_rad)), quat)
        return pos, quat

    def _through_library(
        self,
        pos: NDArray[np.float64],
        q: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        numbers = ",".join(f"{float(v):.9g}" for v in (*pos, *q))
        spec = {"rigid_bodies": f"{self.body_name}({numbers})"}
        bodies = self._motioncapture.connect("mock", spec).rigidBodies
        if self.body_name not in bodies:
            raise RuntimeError(f"motioncapture mock did not parse rigid body {self.body_name!r} ({numbers})")
        body = bodies[self.body_name]
        r = body.rotation
        return np.asarray(body.position, dtype=np.float64), np.array([r.w, r.x, r.y, r.z], dtype=np.float64)

    async def _wait_tick(self, t_tick: float) -> None:
        if self._pacer is not None:
            await asyncio.to_thread(self._pacer.waitForNextFrame)
        else:
            await asyncio.sleep(max(0.0, t_tick - self._clock()))

    # --- the stream ----------------------------------------------------------------------------
    def samples(self) -> AsyncIterator[OdometrySample]:
        """Samples as they arrive. Cancelling a wait (e.g. ``asyncio.timeout`` around ``anext``)
        leaves the stream usable: its state lives here, not in a generator frame."""
        self._t0 = self._clock()
        self._k = 0
        self._pending: deque[tuple[float, NDArray[np.float64], NDArray[np.float64]]] = deque(
            maxlen=max(2, math.ceil(self.latency_s * self.rate_hz) + 2)
        )
        return _Stream(self._next_sample)

    async def _next_sample(self) -> OdometrySample:
        period = 1.0 / self.rate_hz
        pending = self._pending
        now = self._clock()
        if self._t0 + self._k * period < now - period:
            # The consumer was away for ticks: a real feed would have newer samples than these by
            # now. Drop them and measure afresh (delivered latency_s from now), so what arrives is
            # never older than latency_s.
            self.dropped += len(pending)
            pending.clear()
            self._k = math.floor((now - self._t0) / period)
        while True:
            t_release = pending[0][0] if pending else math.inf
            t_tick = self._t0 + self._k * period
            if t_release <= t_tick:
                await asyncio.sleep(max(0.0, t_release - self._clock()))
                now = self._clock()
                while len(pending) > 1 and pending[1][0] <= now:  # consumer was slow: newest wins
                    pending.popleft()
                    self.dropped += 1
                _, pos, quat = pending.popleft()
                return OdometrySample(pos_world_m=pos, quat_world_body=quat, t_arrival_mono_s=now)
            await self._wait_tick(t_tick)
            now = self._clock()
            self._k = max(self._k + 1, math.floor((now - self._t0) / period) + 1)  # skip missed ticks
            self.taken += 1
            if now < self._paused_until or self._rng.random() < self.dropout:
                self.dropped += 1
                continue
            pos, quat = self._measure(self.pose_fn())
            if len(pending) == pending.maxlen:
                self.dropped += 1
            pending.append((now + self.latency_s, pos, quat))


T = TypeVar("T")


class _Stream(Generic[T]):
    """An async iterator over repeated awaits of ``next_fn`` (cancellation-safe, unlike a generator)."""

    def __init__(self, next_fn: Callable[[], Awaitable[T]]) -> None:
        self._next = next_fn

    def __aiter__(self) -> _Stream[T]:
        return self

    async def __anext__(self) -> T:
        return await self._next()

    async def aclose(self) -> None:
        """Nothing to release; present so callers can treat it like an async generator."""
