"""Kinematic quadrotor that tracks position setpoints like PX4's position controller.

A critically damped second-order response (natural frequency ``omega_rad_s``) towards a position
setpoint with velocity feed-forward, with acceleration and speed limits, integrated with
semi-implicit Euler at ``dt_s``. Vectorised over N vehicles: positions and velocities are world
frame (x fwd, y left, z up), metres and m/s, shape (N, 3). Yaw is not modelled here: the vehicle
holds the path heading, which the caller tracks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["QuadParams", "QuadState", "step", "track"]


@dataclass(frozen=True)
class QuadParams:
    """Tracking dynamics of the simulated quad."""

    __pydantic_config__ = {"extra": "forbid"}  # config files: unknown keys are errors

    omega_rad_s: float = 6.0
    """Natural frequency (rad/s) of the critically damped position loop (PX4-like: ~1 s settle)."""
    max_speed_m_s: float = 3.0
    """Speed limit (m/s), like PX4's MPC_XY_VEL_MAX."""
    max_accel_m_s2: float = 4.0
    """Acceleration limit (m/s^2), like PX4's MPC_ACC_HOR_MAX."""
    radius_m: float = 0.3
    """Collision radius (m): a DJI F330-class frame with propellers."""
    dt_s: float = 0.05
    """Integration step (s)."""


@dataclass
class QuadState:
    """Positions (m) and velocities (m/s), world frame, shape (N, 3)."""

    pos_m: NDArray[np.float64]
    vel_m_s: NDArray[np.float64]

    @classmethod
    def at_rest(cls, pos_m: NDArray[np.float64]) -> QuadState:
        p = np.atleast_2d(np.asarray(pos_m, dtype=np.float64)).copy()
        return cls(p, np.zeros_like(p))

    def copy(self) -> QuadState:
        return QuadState(self.pos_m.copy(), self.vel_m_s.copy())


def _clip_norm(v: NDArray[np.float64], limit: float) -> NDArray[np.float64]:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v * np.minimum(1.0, limit / np.maximum(n, 1e-12))


def step(
    state: QuadState,
    target_pos_m: NDArray[np.float64],
    target_vel_m_s: NDArray[np.float64] | None,
    params: QuadParams,
    dt_s: float | None = None,
) -> QuadState:
    """Advance every vehicle by one integration step towards its setpoint (pure: returns new state)."""
    dt = params.dt_s if dt_s is None else dt_s
    w = params.omega_rad_s
    v_ff = np.zeros_like(state.vel_m_s) if target_vel_m_s is None else target_vel_m_s
    acc = w * w * (target_pos_m - state.pos_m) + 2.0 * w * (v_ff - state.vel_m_s)
    acc = _clip_norm(acc, params.max_accel_m_s2)
    vel = _clip_norm(state.vel_m_s + acc * dt, params.max_speed_m_s)
    return QuadState(state.pos_m + vel * dt, vel)


def track(
    state: QuadState,
    targets_pos_m: NDArray[np.float64],
    targets_vel_m_s: NDArray[np.float64],
    params: QuadParams,
) -> tuple[QuadState, NDArray[np.float64]]:
    """Follow a sampled setpoint trajectory, shape (K, N, 3) for K integration steps.

    Returns the final state and the executed positions (K + 1, N, 3), the start included, so the
    caller can check collisions along the whole trajectory.
    """
    trail = np.empty((targets_pos_m.shape[0] + 1, *state.pos_m.shape))
    trail[0] = state.pos_m
    for k in range(targets_pos_m.shape[0]):
        state = step(state, targets_pos_m[k], targets_vel_m_s[k], params)
        trail[k + 1] = state.pos_m
    return state, trail
