"""A synthetic D435 depth camera: renders the world from the vehicle's true pose.

Implements :class:`quadnav_onboard.sources.DepthSource`, so the daemon uses it exactly like the
UVC RealSense. Frames are captured on a fixed ``fps`` grid of the monotonic clock; a consumer that
falls behind gets the *next* frame captured after it asks (latest wins: missed frames are never
queued, they show up as gaps in ``seq``). Rendering runs in a worker thread so the event loop
stays free. Noise (optional) uses a ``numpy.random.Generator`` seeded from ``seed``.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import AsyncIterator, Callable
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.sources.base import DepthFrame
from sim_harness.mocap import _Stream
from sim_harness.render import CameraModel, D435_424x240, render_frame_mm

if TYPE_CHECKING:
    from sim_harness.noise import DepthNoise
    from sim_harness.world import World

__all__ = ["PoseLike", "SimDepthCamera"]


class PoseLike(Protocol):
    """What ``pose_fn`` returns (e.g. :class:`sim_harness.px4.TruePose`)."""

    pos_world_m: NDArray[np.float64]
    quat_world_body: NDArray[np.float64]


class SimDepthCamera:
    """``async with SimDepthCamera(world, emu.true_pose) as cam: async for f in cam.frames(): ...``

    The camera sits at the body origin looking along body x (FLU), like the paper's forward D435.
    """

    def __init__(
        self,
        world: World,
        pose_fn: Callable[[], PoseLike],
        camera: CameraModel = D435_424x240,
        fps: float = 30.0,
        noise: DepthNoise | None = None,
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not (math.isfinite(fps) and fps > 0):
            raise ValueError(f"SimDepthCamera: fps must be a positive number, got {fps!r}")
        self.world = world
        self.pose_fn = pose_fn
        self.camera = camera
        self.fps = float(fps)
        self.noise = noise
        self._rng = np.random.default_rng(seed)
        self._clock = clock
        self._t0: float | None = None
        self._seq = 0
        self.frames_rendered = 0
        """How many frames were captured so far."""

    async def __aenter__(self) -> SimDepthCamera:
        self._t0 = self._clock()
        self._seq = 0
        return self

    async def __aexit__(self, *exc: object) -> None:
        self._t0 = None

    def render(self, pose: PoseLike) -> NDArray[np.uint16]:
        """One uint16 depth frame (mm, 0 = invalid), shape (H, W), at ``pose`` (blocking)."""
        return render_frame_mm(
            self.world,
            pose.pos_world_m,
            pose.quat_world_body,
            self.camera,
            noise=self.noise,
            rng=self._rng if self.noise is not None else None,
        )

    def frames(self) -> AsyncIterator[DepthFrame]:
        """Frames on the ``fps`` grid; each is captured after the consumer asked for it.

        Cancelling a wait (``asyncio.timeout`` around ``anext``) leaves the stream usable."""
        if self._t0 is None:
            raise RuntimeError("SimDepthCamera.frames() outside 'async with'")
        return _Stream(self._next_frame)

    async def _next_frame(self) -> DepthFrame:
        assert self._t0 is not None
        period = 1.0 / self.fps
        now = self._clock()
        k = max(self._seq, math.floor((now - self._t0) / period) + 1)  # next tick not yet past
        t_capture = self._t0 + k * period
        await asyncio.sleep(max(0.0, t_capture - self._clock()))
        pose = self.pose_fn()
        depth_mm = await asyncio.to_thread(self.render, pose)
        self._seq = k + 1
        self.frames_rendered += 1
        return DepthFrame(depth_mm=depth_mm, t_capture_mono_s=t_capture, seq=k)
