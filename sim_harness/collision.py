"""Collision checking: the quad as a sphere against the world's obstacles, floor and ceiling.

Based on the exact Euclidean signed distance to each shape (negative inside). A sphere of radius
r at p collides when ``clearance_m(p) < r``. Along an executed trajectory the check is continuous:
each segment of the trail is walked by conservative advancement (the signed distance is
1-Lipschitz, so no surface can be nearer than ``clearance - r`` to a point whose clearance is
known); the step never drops below ``tol_m``, so a contact shallower than ``tol_m`` may be missed,
but no wall thicker than ``tol_m`` can be tunnelled through, however fast the quad moves.

Numba-compiled (``cache=True``), vectorised over N vehicles.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav_onboard.jit import CAN_CACHE
from sim_harness.world import World

__all__ = ["DEFAULT_TOL_M", "clearance_m", "collides", "sweep_collides"]

DEFAULT_TOL_M = 0.01
"""Smallest advancement step (m) along a trail: contacts shallower than this may be missed."""

PARALLEL_MIN_POINTS = 20_000
"""Batches of at least this many points (trail points) use numba's thread pool."""


_JIT = {"cache": CAN_CACHE, "nogil": True, "error_model": "numpy"}


@numba.njit(**_JIT)
def _sdf(px, py, pz, kind, center, rot, half, bound_r, floor_z, ceiling_z, far):  # pragma: no cover
    """Signed distance (m) from a world point to the nearest solid; capped at ``far``."""
    best = min(far, pz - floor_z, ceiling_z - pz)
    for m in range(kind.shape[0]):
        wx, wy, wz = px - center[m, 0], py - center[m, 1], pz - center[m, 2]
        if math.sqrt(wx * wx + wy * wy + wz * wz) - bound_r[m] >= best:
            continue  # even the bounding sphere is no nearer than the best so far
        q = rot[m]
        lx = q[0, 0] * wx + q[1, 0] * wy + q[2, 0] * wz
        ly = q[0, 1] * wx + q[1, 1] * wy + q[2, 1] * wz
        lz = q[0, 2] * wx + q[1, 2] * wy + q[2, 2] * wz
        k = kind[m]
        if k == 1:
            d = math.sqrt(lx * lx + ly * ly + lz * lz) - half[m, 0]
        else:
            if k == 0:
                qx, qy = abs(lx) - half[m, 0], abs(ly) - half[m, 1]
            else:  # cylinder: (radial, axial) as a 2-D box
                qx, qy = math.sqrt(lx * lx + ly * ly) - half[m, 0], -np.inf
            qz = abs(lz) - half[m, 2]
            ox, oy, oz = max(qx, 0.0), max(qy, 0.0), max(qz, 0.0)
            d = math.sqrt(ox * ox + oy * oy + oz * oz) + min(max(qx, qy, qz), 0.0)
        best = min(best, d)
    return best


@numba.njit(parallel=True, **_JIT)
def _clearance_parallel(pts, kind, center, rot, half, bound_r, floor_z, ceiling_z, out):  # pragma: no cover
    for n in numba.prange(pts.shape[0]):
        out[n] = _sdf(pts[n, 0], pts[n, 1], pts[n, 2], kind, center, rot, half, bound_r, floor_z,
                      ceiling_z, 1e9)


@numba.njit(**_JIT)
def _clearance_serial(pts, kind, center, rot, half, bound_r, floor_z, ceiling_z, out):  # pragma: no cover
    for n in range(pts.shape[0]):
        out[n] = _sdf(pts[n, 0], pts[n, 1], pts[n, 2], kind, center, rot, half, bound_r, floor_z,
                      ceiling_z, 1e9)


@numba.njit(parallel=True, **_JIT)
def _sweep_parallel(trail, radius, tol, kind, center, rot, half, bound_r, floor_z, ceiling_z,
                    out):  # pragma: no cover
    for n in numba.prange(trail.shape[1]):
        out[n] = _sweep_one(trail, n, radius, tol, kind, center, rot, half, bound_r, floor_z, ceiling_z)


@numba.njit(**_JIT)
def _sweep_serial(trail, radius, tol, kind, center, rot, half, bound_r, floor_z, ceiling_z,
                  out):  # pragma: no cover
    for n in range(trail.shape[1]):
        out[n] = _sweep_one(trail, n, radius, tol, kind, center, rot, half, bound_r, floor_z, ceiling_z)


@numba.njit(**_JIT)
def _sweep_one(trail, n, radius, tol, kind, center, rot, half, bound_r, floor_z,
               ceiling_z):  # pragma: no cover
    """Whether vehicle n's sphere touches a solid along its trail (conservative advancement)."""
    n_pts = trail.shape[0]
    for k in range(max(n_pts - 1, 1)):
        ax, ay, az = trail[k, n, 0], trail[k, n, 1], trail[k, n, 2]
        if n_pts == 1:
            dx = dy = dz = 0.0
        else:
            dx, dy, dz = trail[k + 1, n, 0] - ax, trail[k + 1, n, 1] - ay, trail[k + 1, n, 2] - az
        seg = math.sqrt(dx * dx + dy * dy + dz * dz)
        s = 0.0
        while True:
            f = s / seg if seg > 0.0 else 0.0
            c = _sdf(ax + f * dx, ay + f * dy, az + f * dz, kind, center, rot, half, bound_r,
                     floor_z, ceiling_z, 1e9)
            if c < radius:
                return True
            if s >= seg:
                break
            s = min(seg, s + max(c - radius, tol))
    return False


def _geom_args(world: World) -> tuple:
    g = world.geometry
    return g.kind, g.center_m, g.rot_m, g.half_m, g.bound_r_m, g.floor_z_m, g.ceiling_z_m


def clearance_m(world: World, pos_world_m: ArrayLike) -> NDArray[np.float64]:
    """Signed distance (m) from each point (world, shape (N, 3) or (3,)) to the nearest solid.

    Negative inside an obstacle, below the floor or above the ceiling. Shape (N,) or ().
    """
    p = np.asarray(pos_world_m, dtype=np.float64)
    pts = np.ascontiguousarray(p.reshape(-1, 3))
    out = np.empty(pts.shape[0])
    # numba's thread pool only pays off for big batches (waking it costs ~ms on a loaded machine)
    (_clearance_parallel if pts.shape[0] >= PARALLEL_MIN_POINTS else _clearance_serial)(
        pts, *_geom_args(world), out)
    return out.reshape(p.shape[:-1])


def collides(world: World, pos_world_m: ArrayLike, radius_m: float) -> NDArray[np.bool_]:
    """Whether a sphere of ``radius_m`` at each position (world, (N, 3)) touches a solid; (N,) bool."""
    return clearance_m(world, pos_world_m) < radius_m


def sweep_collides(world: World, trail_m: ArrayLike, radius_m: float,
                   tol_m: float = DEFAULT_TOL_M) -> NDArray[np.bool_]:
    """Whether a sphere of ``radius_m`` moving along each trail touches a solid anywhere on it.

    ``trail_m`` (K, N, 3): K positions (world, m) of N vehicles, joined by straight segments (e.g.
    the ``trail`` from :func:`sim_harness.quad.track`, start included). Returns (N,) bool.
    """
    trail = np.ascontiguousarray(np.asarray(trail_m, dtype=np.float64))
    if trail.ndim != 3 or trail.shape[2] != 3 or trail.shape[0] < 1:
        raise ValueError(f"trail must have shape (K>=1, N, 3), got {trail.shape}")
    if not tol_m > 0:
        raise ValueError(f"tol_m must be positive, got {tol_m}")
    out = np.empty(trail.shape[1], dtype=np.bool_)
    kernel = _sweep_parallel if trail.shape[0] * trail.shape[1] >= PARALLEL_MIN_POINTS else _sweep_serial
    kernel(trail, float(radius_m), float(tol_m), *_geom_args(world), out)
    return out
