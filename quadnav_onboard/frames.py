"""Reference frames and rotations.

Conventions (all lengths in metres, angles in radians):

* **world**: x forward along the first path segment, y left, z up (an ENU-like, right-handed
  frame fixed to the lab or the simulated world).
* **body**: FLU (x forward, y left, z up), origin at the vehicle's centre.
* **heading** frame: the body frame with roll and pitch removed (rotation about world z by yaw only).
  The planner's state and the motion primitives live in this frame.
* **NED / FRD**: PX4's local frame (x north, y east, z down) and body frame (forward, right,
  down). They are used only at the vehicle boundary (MAVLink); nothing else should touch them.

We identify world x with PX4's north and world y with west, so ``world -> NED`` is a rotation of
pi about the x axis: ``(x, y, z) -> (x, -y, -z)``. The same map takes FLU to FRD.

Quaternions are ``(w, x, y, z)``, Hamilton convention, active rotation body -> parent frame.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "body_to_world",
    "flu_to_frd",
    "frd_to_flu",
    "pixel_slopes",
    "quat_from_rotmat",
    "quat_from_yaw",
    "quat_multiply",
    "quat_to_rotmat",
    "quat_to_yaw",
    "quat_world_to_ned",
    "rotmat_yaw",
    "world_to_body",
    "wrap_angle",
    "yaw_flu_to_frd",
    "yaw_frd_to_flu",
]

_FLIP = np.array([1.0, -1.0, -1.0])


def pixel_slopes(
    width: int, height: int, hfov_deg: float, vfov_deg: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Body-frame slopes of a pinhole camera's pixel centres looking along body +x: ``ty`` (width,)
    = y/x (column 0 left, +), ``tz`` (height,) = z/x (row 0 up, +). The ray through pixel (i, j)
    is ``(1, ty[j], tz[i])``, so a hit's parameter is its z-depth."""
    ty = np.tan(np.radians(hfov_deg) / 2) * (1.0 - 2.0 * (np.arange(width) + 0.5) / width)
    tz = np.tan(np.radians(vfov_deg) / 2) * (1.0 - 2.0 * (np.arange(height) + 0.5) / height)
    return ty, tz


def wrap_angle(angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Wrap an angle (rad) to [-pi, pi)."""
    a = np.asarray(angle_rad, dtype=np.float64)
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def rotmat_yaw(yaw_rad: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix about +z by ``yaw_rad`` (heading -> world). Shape (..., 3, 3)."""
    yaw = np.asarray(yaw_rad, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    zero, one = np.zeros_like(yaw), np.ones_like(yaw)
    return np.stack(
        [
            np.stack([c, -s, zero], axis=-1),
            np.stack([s, c, zero], axis=-1),
            np.stack([zero, zero, one], axis=-1),
        ],
        axis=-2,
    )


def world_to_body(vec_world: ArrayLike, yaw_rad: ArrayLike) -> NDArray[np.float64]:
    """Rotate a world-frame vector (m, shape (..., 3)) into the heading/body frame of yaw ``yaw_rad``.

    Only yaw is removed: this is the heading frame used by the planner's state and primitives.
    For a full attitude use :func:`quat_to_rotmat` and its transpose.
    """
    v = np.asarray(vec_world, dtype=np.float64)
    yaw = np.asarray(yaw_rad, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    x, y = v[..., 0], v[..., 1]
    return np.stack([c * x + s * y, -s * x + c * y, v[..., 2]], axis=-1)


def body_to_world(vec_body: ArrayLike, yaw_rad: ArrayLike) -> NDArray[np.float64]:
    """Rotate a heading/body-frame vector (m, shape (..., 3)) into the world frame. Inverse of
    :func:`world_to_body`."""
    v = np.asarray(vec_body, dtype=np.float64)
    yaw = np.asarray(yaw_rad, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    x, y = v[..., 0], v[..., 1]
    return np.stack([c * x - s * y, s * x + c * y, v[..., 2]], axis=-1)


def flu_to_frd(vec_world: ArrayLike) -> NDArray[np.float64]:
    """(x, y, z) -> (x, -y, -z): a world vector or position (x forward, y left, z up), shape
    (..., 3), to PX4's local frame as this project aligns it (x forward = north, y right = east,
    z down), or a body vector FLU to FRD. Not an ENU-to-NED swap: x stays x."""
    return np.asarray(vec_world, dtype=np.float64) * _FLIP


def frd_to_flu(vec_ned: ArrayLike) -> NDArray[np.float64]:
    """(x, y, z) -> (x, -y, -z): a PX4 local-frame vector or position (x north, y east, z down),
    shape (..., 3), to the world frame (x forward, y left, z up), or a body vector FRD to FLU."""
    return np.asarray(vec_ned, dtype=np.float64) * _FLIP


def yaw_flu_to_frd(yaw_world_rad: ArrayLike) -> NDArray[np.float64]:
    """World yaw (CCW about +z up, 0 = +x) to PX4 yaw (CW about +z down, 0 = north = +x)."""
    return wrap_angle(-np.asarray(yaw_world_rad, dtype=np.float64))


def yaw_frd_to_flu(yaw_ned_rad: ArrayLike) -> NDArray[np.float64]:
    """PX4 yaw (rad, NED) to world yaw (rad). Its own inverse, written out for readability."""
    return wrap_angle(-np.asarray(yaw_ned_rad, dtype=np.float64))


def quat_multiply(q1: ArrayLike, q2: ArrayLike) -> NDArray[np.float64]:
    """Hamilton product ``q1 * q2`` of (w, x, y, z) quaternions, shape (..., 4)."""
    a = np.asarray(q1, dtype=np.float64)
    b = np.asarray(q2, dtype=np.float64)
    w1, x1, y1, z1 = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    w2, x2, y2, z2 = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def quat_from_yaw(yaw_rad: ArrayLike) -> NDArray[np.float64]:
    """Quaternion (w, x, y, z) of a pure rotation about +z by ``yaw_rad``."""
    half = 0.5 * np.asarray(yaw_rad, dtype=np.float64)
    zero = np.zeros_like(half)
    return np.stack([np.cos(half), zero, zero, np.sin(half)], axis=-1)


def quat_to_rotmat(q: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix (child -> parent) of a (w, x, y, z) quaternion; normalises first."""
    qa = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(qa, axis=-1, keepdims=True)
    if np.any(norm < 1e-9) or not np.all(np.isfinite(norm)):
        raise ValueError(f"quaternion {qa.tolist()} has zero or non-finite norm")
    w, x, y, z = np.moveaxis(qa / norm, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def quat_from_rotmat(r: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (child -> parent), shape (3, 3).

    Inverse of :func:`quat_to_rotmat` (Shepperd's method: numerically safe for every rotation).
    """
    m = np.asarray(r, dtype=np.float64)
    if m.shape != (3, 3) or not np.allclose(m @ m.T, np.eye(3), atol=1e-6) or np.linalg.det(m) <= 0:
        raise ValueError(f"not a rotation matrix: {m.tolist()}")
    tr = np.trace(m)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = np.array([0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s])
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = np.array([(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s])
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = np.array([(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = np.array([(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def quat_to_yaw(q: ArrayLike) -> NDArray[np.float64]:
    """Yaw (rad) of a (w, x, y, z) quaternion: heading of the body x axis in the parent frame."""
    qa = np.asarray(q, dtype=np.float64)
    w, x, y, z = qa[..., 0], qa[..., 1], qa[..., 2], qa[..., 3]
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


# q_ned_from_world: rotation of pi about x.
_Q_FLIP = np.array([0.0, 1.0, 0.0, 0.0])


def quat_world_to_ned(q_world_body_flu: ArrayLike) -> NDArray[np.float64]:
    """Attitude of an FLU body in the world frame -> attitude of its FRD body in NED.

    ``q_ned_frd = q_flip * q_world_flu * q_flip^-1`` where q_flip is pi about x; the map is its own
    inverse, so it also converts NED/FRD attitudes back to world/FLU.
    """
    q = np.asarray(q_world_body_flu, dtype=np.float64)
    q_inv = _Q_FLIP * np.array([1.0, -1.0, -1.0, -1.0])
    return quat_multiply(quat_multiply(_Q_FLIP, q), q_inv)
