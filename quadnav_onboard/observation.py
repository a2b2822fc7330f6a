"""The planner's observation history: the last k depth inputs and the last k relative positions.

The paper feeds one depth image and one relative position (k = 1). Our history options stack the
last ``depth_history`` 32x32 depth inputs and the last ``position_history`` relative positions,
oldest first, exactly as :class:`quadnav_onboard.network.DQN` expects: the flight's one-vehicle
view of :func:`quadnav_onboard.step.push_history`, which the training env pushes for N at once.

Depth inputs are float32 (32, 32) in [0, 1] (see :mod:`quadnav_onboard.preprocess`); relative
positions are ``setpoint - quad`` in the heading frame (x fwd, y left, z up), metres, shape (3,).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav_onboard.preprocess import OUT_SIZE as INPUT_SIZE
from quadnav_onboard.step import push_history

__all__ = ["ObservationHistory"]


class ObservationHistory:
    """Fixed-length rings of depth inputs and relative positions (no unbounded growth).

    ``reset`` fills every slot with the first observation (so the network never sees zeros that no
    sensor produced); ``push`` drops the oldest and appends the newest; ``arrays`` returns copies,
    oldest first: depth (k_d, 32, 32) float32 and rel (k_p, 3) float32. ``version`` counts resets
    and pushes, so a result computed from :meth:`depth_with` can tell whether it is still current.
    """

    def __init__(self, depth_history: int = 1, position_history: int = 1) -> None:
        if int(depth_history) < 1 or int(position_history) < 1:
            raise ValueError(
                f"history lengths must be >= 1, got depth_history={depth_history}, "
                f"position_history={position_history}"
            )
        self.depth_history = int(depth_history)
        self.position_history = int(position_history)
        self._depth = np.ones((self.depth_history, INPUT_SIZE, INPUT_SIZE), dtype=np.float32)
        self._rel = np.zeros((self.position_history, 3), dtype=np.float32)
        self._ready = False
        self.version = 0
        """Incremented by every :meth:`reset` and :meth:`push`."""

    @property
    def ready(self) -> bool:
        """True once :meth:`reset` has been called."""
        return self._ready

    @staticmethod
    def _check_depth(depth_input: ArrayLike) -> NDArray[np.float32]:
        d = np.asarray(depth_input, dtype=np.float32)
        if d.shape != (INPUT_SIZE, INPUT_SIZE):
            raise ValueError(f"depth input must have shape (32, 32), got {d.shape}")
        if not np.all(np.isfinite(d)):
            raise ValueError("observation contains NaN or Inf")
        return d

    @classmethod
    def _check(cls, depth_input: ArrayLike, rel_pos_body_m: ArrayLike) -> tuple[NDArray[np.float32], NDArray]:
        d = cls._check_depth(depth_input)
        r = np.asarray(rel_pos_body_m, dtype=np.float32)
        if r.shape != (3,):
            raise ValueError(f"relative position must have shape (3,), got {r.shape}")
        if not np.all(np.isfinite(r)):
            raise ValueError("observation contains NaN or Inf")
        return d, r

    def reset(self, depth_input: ArrayLike, rel_pos_body_m: ArrayLike) -> None:
        """Start a new episode/flight: every slot holds this first observation."""
        d, r = self._check(depth_input, rel_pos_body_m)
        self._depth[:] = d
        self._rel[:] = r
        self._ready = True
        self.version += 1

    def push(self, depth_input: ArrayLike, rel_pos_body_m: ArrayLike) -> None:
        """Append the newest observation, dropping the oldest. Calls :meth:`reset` if not ready."""
        if not self._ready:
            self.reset(depth_input, rel_pos_body_m)
            return
        d, r = self._check(depth_input, rel_pos_body_m)
        self._depth = push_history(self._depth[None], d[None])[0]
        self._rel = push_history(self._rel[None], r[None])[0]
        self.version += 1

    def copy(self) -> ObservationHistory:
        """An independent copy (same contents and version)."""
        other = ObservationHistory(self.depth_history, self.position_history)
        other._depth[:], other._rel[:] = self._depth, self._rel
        other._ready, other.version = self._ready, self.version
        return other

    def depth_with(self, depth_input: ArrayLike) -> NDArray[np.float32]:
        """The depth stack (k_d, 32, 32) that ``push(depth_input, ...)`` would make, oldest first,
        without pushing: the last k_d - 1 inputs and this one (every slot this one if not ready)."""
        d = self._check_depth(depth_input)
        if not self._ready:
            return np.repeat(d[None], self.depth_history, axis=0)
        return np.concatenate([self._depth[1:], d[None]])

    def arrays(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Copies, oldest first: depth (k_d, 32, 32) float32 in [0, 1], rel (k_p, 3) float32 (m)."""
        if not self._ready:
            raise RuntimeError("ObservationHistory.arrays() before reset()")
        return self._depth.copy(), self._rel.copy()

    def rel_array(self) -> NDArray[np.float32]:
        """A copy of the relative positions alone, oldest first: (k_p, 3) float32 (m)."""
        if not self._ready:
            raise RuntimeError("ObservationHistory.rel_array() before reset()")
        return self._rel.copy()
