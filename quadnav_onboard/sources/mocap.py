"""Odometry from a motion-capture system through the ``motioncapture`` library.

Any system the library supports (optitrack, vicon, qualisys, vrpn, mock, ...) by
``odometry.system_type``, the server at ``odometry.host`` and the vehicle's rigid body by name.
Mocap frames differ from ours (OptiTrack streams y-up), so a configured rotation ``R_wm``
(``rotation_world_from_mocap``) and translation ``t_w`` map them into the world frame:
``p_world = R_wm p_mocap + t_w``. The rigid body is assumed to have been created with the vehicle
level and facing world +x, so its attitude maps as ``R_world_body = R_wm R_mocap_rb R_wm^T``.
``waitForNextFrame`` blocks, so it runs on one dedicated thread; each sample is stamped on arrival.
A frame without the body (occluded) or with NaN is skipped: the feed goes stale and the supervisor
acts.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.frames import quat_from_rotmat, quat_multiply
from quadnav_onboard.sources.base import OdometrySample

__all__ = ["MocapError", "MocapOdometrySource", "MocapTransform"]


class MocapError(RuntimeError):
    """The mocap system cannot be reached (the message names system type and host)."""


class MocapTransform:
    """The configured map from the mocap frame into the world frame (pure)."""

    def __init__(
        self, rotation_world_from_mocap: Sequence[Sequence[float]], translation_world_m: Sequence[float]
    ):
        self.r_wm = np.asarray(rotation_world_from_mocap, dtype=np.float64)
        self.q_wm = quat_from_rotmat(self.r_wm)
        self.q_mw = self.q_wm * np.array([1.0, -1.0, -1.0, -1.0])
        self.t_w = np.asarray(translation_world_m, dtype=np.float64)

    def apply(
        self, pos_mocap_m: NDArray[np.float64], quat_mocap_body: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(position m, quaternion w,x,y,z) in the mocap frame -> the world frame."""
        pos = self.r_wm @ np.asarray(pos_mocap_m, dtype=np.float64) + self.t_w
        q = quat_multiply(quat_multiply(self.q_wm, np.asarray(quat_mocap_body, dtype=np.float64)), self.q_mw)
        return pos, q / np.linalg.norm(q)


class MocapOdometrySource:
    """:class:`~quadnav_onboard.sources.base.OdometrySource` over ``motioncapture``."""

    def __init__(
        self,
        system_type: str,
        host: str,
        rigid_body: str,
        transform: MocapTransform,
        *,
        connect_args: dict[str, Any] | None = None,
    ) -> None:
        self.system_type, self.host, self.rigid_body = system_type, host, rigid_body
        self.transform = transform
        self._connect_args = connect_args if connect_args is not None else {"hostname": host}
        self._mc: Any = None
        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mocap")
        self.skipped = 0
        """Frames without a usable pose of the rigid body."""

    def _connect(self) -> Any:
        import motioncapture

        try:
            return motioncapture.connect(self.system_type, self._connect_args)
        except Exception as exc:
            raise MocapError(
                f"odometry: cannot connect to {self.system_type} at {self.host!r}: {exc}"
            ) from exc

    async def __aenter__(self) -> MocapOdometrySource:
        loop = asyncio.get_running_loop()
        self._mc = await loop.run_in_executor(self._thread, self._connect)
        return self

    async def __aexit__(self, *exc: object) -> None:
        self._mc = None
        self._thread.shutdown(wait=False, cancel_futures=True)

    def _next(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        self._mc.waitForNextFrame()
        body = self._mc.rigidBodies.get(self.rigid_body)
        if body is None:
            return None
        r = body.rotation
        pos = np.asarray(body.position, dtype=np.float64)
        q = np.array([r.w, r.x, r.y, r.z], dtype=np.float64)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(q))) or np.linalg.norm(q) < 0.5:
            return None
        return pos, q

    async def samples(self) -> AsyncIterator[OdometrySample]:
        loop = asyncio.get_running_loop()
        while True:
            got = await loop.run_in_executor(self._thread, self._next)
            t = time.monotonic()
            if got is None:
                self.skipped += 1
                continue
            pos, q = self.transform.apply(*got)
            yield OdometrySample(pos, q, t)
