"""The vehicle's true state, shared between the sim's processes through one shared-memory block.

The process that owns the vehicle's state (today the emulated PX4; a bridge reading a PX4 SITL's
simulated state over MAVLink could write the same block) writes it at its physics rate; the sim
camera and the sim mocap read it, each in its own process, and render or measure from it. A
sequence lock makes every read consistent without blocking the writer: the writer makes the
counter odd, writes, makes it even again; a reader retries while the counter is odd or changed.

Layout (float64): ``[seq, t_mono_s, pos(3), vel(3), quat(4), crashed, armed]``, world frame
(x forward, y left, z up), quaternion (w, x, y, z) body FLU -> world. ``t_mono_s`` is the
writer's ``time.monotonic()``, which on Linux is one clock for every process of the machine.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from multiprocessing import resource_tracker, shared_memory

import numpy as np
from numpy.typing import NDArray

__all__ = ["TruthBlock", "TruthState"]

_N = 14
_SEQ, _T, _POS, _VEL, _QUAT, _CRASHED, _ARMED = 0, 1, slice(2, 5), slice(5, 8), slice(8, 12), 12, 13


@dataclass(frozen=True)
class TruthState:
    """One consistent read of the block."""

    pos_world_m: NDArray[np.float64]
    """Position (m), shape (3,)."""
    vel_world_m_s: NDArray[np.float64]
    """Velocity (m/s), shape (3,)."""
    quat_world_body: NDArray[np.float64]
    """Attitude (w, x, y, z), body FLU -> world, shape (4,)."""
    t_mono_s: float
    """When the writer last wrote (monotonic s); NaN before the first write."""
    crashed: bool
    """The vehicle hit an obstacle (the sim's ground truth)."""
    armed: bool


class TruthBlock:
    """``TruthBlock.create()`` in the process that cleans up; ``TruthBlock.attach(name)`` elsewhere."""

    def __init__(self, shm: shared_memory.SharedMemory, owner: bool) -> None:
        self._shm = shm
        self._owner = owner
        self._a: NDArray[np.float64] = np.ndarray((_N,), dtype=np.float64, buffer=shm.buf)
        self.name = shm.name

    @classmethod
    def create(cls) -> TruthBlock:
        shm = shared_memory.SharedMemory(create=True, size=_N * 8)
        block = cls(shm, owner=True)
        block._a[:] = 0.0
        block._a[_T] = np.nan
        block._a[_QUAT] = (1.0, 0.0, 0.0, 0.0)
        return block

    @classmethod
    def attach(cls, name: str) -> TruthBlock:
        shm = shared_memory.SharedMemory(name=name)
        # Python < 3.13 registers an attached block with the resource tracker, which would unlink
        # it when this process exits; the creator owns its lifetime.
        with contextlib.suppress(Exception):  # not registered on this Python: nothing to undo
            resource_tracker.unregister(shm._name, "shared_memory")  # type: ignore[attr-defined]
        return cls(shm, owner=False)

    def write(
        self,
        pos_world_m: NDArray[np.float64],
        vel_world_m_s: NDArray[np.float64],
        quat_world_body: NDArray[np.float64],
        t_mono_s: float,
        crashed: bool,
        armed: bool,
    ) -> None:
        """Publish the state (one writer only)."""
        a = self._a
        seq = a[_SEQ]
        a[_SEQ] = seq + 1.0  # odd: a write is under way
        a[_T] = t_mono_s
        a[_POS] = pos_world_m
        a[_VEL] = vel_world_m_s
        a[_QUAT] = quat_world_body
        a[_CRASHED] = 1.0 if crashed else 0.0
        a[_ARMED] = 1.0 if armed else 0.0
        a[_SEQ] = seq + 2.0

    def read(self, timeout_s: float = 0.01) -> TruthState:
        """A consistent copy; raises TimeoutError if the writer holds the block longer than
        ``timeout_s`` (it never does unless it died mid-write)."""
        a = self._a
        deadline = time.monotonic() + timeout_s
        while True:
            seq = a[_SEQ]
            copy = a.copy()
            if seq % 2.0 == 0.0 and a[_SEQ] == seq:
                return TruthState(
                    pos_world_m=copy[_POS],
                    vel_world_m_s=copy[_VEL],
                    quat_world_body=copy[_QUAT],
                    t_mono_s=float(copy[_T]),
                    crashed=bool(copy[_CRASHED]),
                    armed=bool(copy[_ARMED]),
                )
            if time.monotonic() > deadline:
                raise TimeoutError(f"truth block {self.name}: writer stuck mid-write")

    def close(self) -> None:
        """Detach; the creator also removes the block."""
        del self._a
        self._shm.close()
        if self._owner:
            with contextlib.suppress(FileNotFoundError):
                self._shm.unlink()
