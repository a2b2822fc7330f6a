"""Synthetic D435 depth by analytic ray casting (numba-compiled, batched over poses).

The camera sits at the body origin and looks along body +x (FLU body: y left, z up). Image row 0
is the top (up), column 0 the left. Pixel (i, j) looks along the body direction
``(1, ty[j], tz[i])``, with ``ty``/``tz`` spanning ``±tan(fov/2)`` at the pixel centres, so the ray
parameter at a hit *is* the z-depth: distance along the optical axis, as a D435 reports it. Depth
is 0 (no return) where nothing is hit, or the hit is nearer than ``min_range_m`` (a D435's min-Z)
or farther than ``max_range_m``.

Shapes: boxes (any rotation, slab test in the box frame), spheres, capped cylinders on any axis,
and the floor and ceiling planes. Per pose, an obstacle whose bounding sphere lies behind the
camera or beyond range is skipped, and the others are cast only over the pixel rectangle that
their bounding sphere projects to (frustum and screen-space culling). Kernels are compiled with
``numba`` (``cache=True``: the JIT cost, ~seconds, is paid once per checkout) and run in
parallel over poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav_onboard.camera import D435_HFOV_DEG, D435_MAX_RANGE_M, D435_MIN_RANGE_M, D435_VFOV_DEG
from quadnav_onboard.frames import pixel_slopes, quat_to_rotmat, rotmat_yaw
from quadnav_onboard.jit import CAN_CACHE
from quadnav_onboard.preprocess import OUT_SIZE, DepthInputs, PreprocessConfig, depth_inputs_mm
from sim_harness.noise import DepthNoise, apply_depth_noise
from sim_harness.world import Geometry, World

__all__ = [
    "NETWORK_32",
    "CameraModel",
    "D435_424x240",
    "D435_848x480",
    "cast_depth_m",
    "render_depth_m",
    "render_frame_mm",
    "render_input_frames_mm",
    "render_inputs",
    "render_network_inputs",
]


@dataclass(frozen=True)
class CameraModel:
    """A pinhole depth camera (D435 depth stream by default)."""

    __pydantic_config__ = {"extra": "forbid"}  # config files: unknown keys are errors

    width: int
    """Image width (pixels)."""
    height: int
    """Image height (pixels)."""
    hfov_deg: float = D435_HFOV_DEG
    """Horizontal field of view (deg), D435 depth: 87."""
    vfov_deg: float = D435_VFOV_DEG
    """Vertical field of view (deg), D435 depth: 58."""
    min_range_m: float = D435_MIN_RANGE_M
    """Nearest depth (m) reported; nearer hits read 0 like a D435 below its min-Z."""
    max_range_m: float = D435_MAX_RANGE_M
    """Farthest depth (m) reported; farther hits read 0."""

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"camera size must be positive, got {self.width}x{self.height}")
        if not (0 < self.hfov_deg < 180 and 0 < self.vfov_deg < 180):
            raise ValueError(f"fields of view must be in (0, 180) deg, got {self.hfov_deg}, {self.vfov_deg}")
        if not 0 <= self.min_range_m < self.max_range_m:
            raise ValueError(
                f"need 0 <= min_range_m < max_range_m, got {self.min_range_m}, {self.max_range_m}"
            )

    def ray_slopes(self, supersample: int = 1) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Body-frame slopes of the pixel centres: ``ty`` (W*s,) = y/x (left +), ``tz`` (H*s,) = z/x (up +).

        ``supersample`` s casts s x s rays per pixel, on a regular grid inside it."""
        return pixel_slopes(self.width * supersample, self.height * supersample, self.hfov_deg, self.vfov_deg)


D435_848x480 = CameraModel(848, 480)
D435_424x240 = CameraModel(424, 240)
NETWORK_32 = CameraModel(OUT_SIZE, OUT_SIZE)
"""The D435 field of view sampled directly at the network's 32x32 (the training path)."""

PARALLEL_MIN_POSES = 64
"""Batches of at least this many poses are cast on numba's thread pool, smaller ones serially."""


_JIT = {"cache": CAN_CACHE, "nogil": True, "fastmath": False, "error_model": "numpy"}


@numba.njit(**_JIT)
def _hit_t(kind: int, o0: float, o1: float, o2: float, d0: float, d1: float, d2: float,
           h0: float, h1: float, h2: float) -> float:  # pragma: no cover - compiled
    """Ray parameter of the first hit (inf if none; 0 if the origin is inside); local frame."""
    if kind == 1:  # sphere
        a = d0 * d0 + d1 * d1 + d2 * d2
        b = o0 * d0 + o1 * d1 + o2 * d2
        c = o0 * o0 + o1 * o1 + o2 * o2 - h0 * h0
        disc = b * b - a * c
        if disc < 0.0:
            return np.inf
        sq = math.sqrt(disc)
        tn, tf = (-b - sq) / a, (-b + sq) / a
    else:
        # z slab (box and cylinder)
        if d2 != 0.0:
            t1, t2 = (-h2 - o2) / d2, (h2 - o2) / d2
            tn, tf = min(t1, t2), max(t1, t2)
        elif abs(o2) <= h2:
            tn, tf = -np.inf, np.inf
        else:
            return np.inf
        if kind == 0:  # box: x and y slabs
            if d0 != 0.0:
                t1, t2 = (-h0 - o0) / d0, (h0 - o0) / d0
                tn, tf = max(tn, min(t1, t2)), min(tf, max(t1, t2))
            elif abs(o0) > h0:
                return np.inf
            if d1 != 0.0:
                t1, t2 = (-h1 - o1) / d1, (h1 - o1) / d1
                tn, tf = max(tn, min(t1, t2)), min(tf, max(t1, t2))
            elif abs(o1) > h1:
                return np.inf
        else:  # cylinder about local z: infinite-cylinder interval
            a = d0 * d0 + d1 * d1
            b = o0 * d0 + o1 * d1
            c = o0 * o0 + o1 * o1 - h0 * h0
            if a == 0.0:
                if c > 0.0:
                    return np.inf
            else:
                disc = b * b - a * c
                if disc < 0.0:
                    return np.inf
                sq = math.sqrt(disc)
                tn, tf = max(tn, (-b - sq) / a), min(tf, (-b + sq) / a)
    if tn > tf or tf <= 0.0:
        return np.inf
    return max(tn, 0.0)


@numba.njit(**_JIT)
def _slope_range(c_fwd: float, c_side: float, r: float, t0: float, dt: float,
                 n: int) -> tuple[int, int]:  # pragma: no cover - compiled
    """Index range [lo, hi) of a regular slope grid ``t0 + k*dt`` (dt < 0) that can see a bounding
    circle (centre ``(c_fwd, c_side)``, radius r) in the camera's (forward, side) plane."""
    dist2 = c_fwd * c_fwd + c_side * c_side
    if dist2 <= r * r:
        return 0, n
    phi = math.atan2(c_side, c_fwd)
    delta = math.asin(r / math.sqrt(dist2))
    lo_ang, hi_ang = phi - delta, phi + delta
    half_pi = 0.5 * math.pi
    if lo_ang >= half_pi or hi_ang <= -half_pi:
        return 0, 0
    k_lo, k_hi = 0, n
    if hi_ang < half_pi:  # largest slope -> smallest index
        k_lo = max(0, math.floor((math.tan(hi_ang) - t0) / dt))
    if lo_ang > -half_pi:
        k_hi = min(n, math.ceil((math.tan(lo_ang) - t0) / dt) + 1)
    return k_lo, k_hi


@numba.njit(**_JIT)
def _index_range(s_lo: float, s_hi: float, t0: float, dt: float,
                 n: int) -> tuple[int, int]:  # pragma: no cover - compiled
    """Index range [lo, hi) of the regular slope grid ``t0 + k*dt`` (dt < 0) covering [s_lo, s_hi]."""
    k_lo = max(0, math.floor((s_hi - t0) / dt))
    k_hi = min(n, math.ceil((s_lo - t0) / dt) + 1)
    return k_lo, k_hi


@numba.njit(**_JIT)
def _screen_rect(cx, cy, cz, br, mm, kind, h0, h1, h2, ty, tz, dty, dtz):  # pragma: no cover - compiled
    """Pixel rectangle [i0, i1) x [j0, j1) that can see an obstacle (centre (cx, cy, cz) in the
    camera frame, bounding radius br, body axes in its frame mm), and a lower bound on its z-depth.

    From the slopes of its oriented bounding box's 8 corners when all are in front of the camera
    (exact for a convex hull), else from its bounding sphere's cone."""
    ok = kind != 1
    sy_lo, sy_hi, sz_lo, sz_hi, z_obb = np.inf, -np.inf, np.inf, -np.inf, np.inf
    if ok:
        for corner in range(8):
            e0 = h0 if corner & 1 else -h0
            e1 = h1 if corner & 2 else -h1
            e2 = h2 if corner & 4 else -h2
            px = cx + mm[0, 0] * e0 + mm[1, 0] * e1 + mm[2, 0] * e2
            if px < 1e-6:
                ok = False
                break
            sy = (cy + mm[0, 1] * e0 + mm[1, 1] * e1 + mm[2, 1] * e2) / px
            sz = (cz + mm[0, 2] * e0 + mm[1, 2] * e1 + mm[2, 2] * e2) / px
            z_obb = min(z_obb, px)
            sy_lo, sy_hi = min(sy_lo, sy), max(sy_hi, sy)
            sz_lo, sz_hi = min(sz_lo, sz), max(sz_hi, sz)
    if ok:
        j0, j1 = _index_range(sy_lo, sy_hi, ty[0], dty, ty.shape[0])
        i0, i1 = _index_range(sz_lo, sz_hi, tz[0], dtz, tz.shape[0])
        return i0, i1, j0, j1, max(cx - br, z_obb)
    j0, j1 = _slope_range(cx, cy, br, ty[0], dty, ty.shape[0])
    i0, i1 = _slope_range(cx, cz, br, tz[0], dtz, tz.shape[0])
    return i0, i1, j0, j1, cx - br


@numba.njit(**_JIT)
def _cast_planes(n, r_lo, r_hi, oz, r, ty, tz, floor_z, ceiling_z, out):  # pragma: no cover - compiled
    """Rows [r_lo, r_hi) of image n: ray parameter of the floor or ceiling hit (inf: none, 0: outside)."""
    for i in range(r_lo, r_hi):
        for j in range(out.shape[2]):
            dz = r[2, 0] + ty[j] * r[2, 1] + tz[i] * r[2, 2]
            t = np.inf
            if oz <= floor_z or oz >= ceiling_z:
                t = 0.0
            elif dz < 0.0:
                t = (floor_z - oz) / dz
            elif dz > 0.0:
                t = (ceiling_z - oz) / dz
            out[n, i, j] = t


@numba.njit(**_JIT)
def _cast_item(n, r_lo, r_hi, origins, rots, ty, tz, dty, dtz, kind, center, orot, half, bound_r,
               floor_z, ceiling_z, max_t, out):  # pragma: no cover - compiled
    """Rows [r_lo, r_hi) of image n: the ray parameter (= z-depth) of the nearest hit, inf if none."""
    ox, oy, oz = origins[n, 0], origins[n, 1], origins[n, 2]
    r = rots[n]
    _cast_planes(n, r_lo, r_hi, oz, r, ty, tz, floor_z, ceiling_z, out)
    # obstacles nearest first, so that pixels already nearer than an obstacle can skip it
    near = np.empty(kind.shape[0])
    for m in range(kind.shape[0]):
        near[m] = (r[0, 0] * (center[m, 0] - ox) + r[1, 0] * (center[m, 1] - oy)
                   + r[2, 0] * (center[m, 2] - oz) - bound_r[m])
    mm = np.empty((3, 3))  # per obstacle: the body axes in the obstacle frame, q.T @ r
    for m in np.argsort(near):
        wx, wy, wz = center[m, 0] - ox, center[m, 1] - oy, center[m, 2] - oz
        cx = r[0, 0] * wx + r[1, 0] * wy + r[2, 0] * wz  # centre in the camera (body) frame
        cy = r[0, 1] * wx + r[1, 1] * wy + r[2, 1] * wz
        cz = r[0, 2] * wx + r[1, 2] * wy + r[2, 2] * wz
        if cx < -bound_r[m] or cx - bound_r[m] > max_t:
            continue
        q = orot[m]
        for a in range(3):
            for b in range(3):
                mm[a, b] = q[0, a] * r[0, b] + q[1, a] * r[1, b] + q[2, a] * r[2, b]
        k, h0, h1, h2 = kind[m], half[m, 0], half[m, 1], half[m, 2]
        i0, i1, j0, j1, z_near = _screen_rect(cx, cy, cz, bound_r[m], mm, k, h0, h1, h2, ty, tz, dty, dtz)
        i0, i1 = max(i0, r_lo), min(i1, r_hi)
        if i0 >= i1 or j0 >= j1:
            continue
        # ray origin in the obstacle frame; ray directions from the body-axis images in mm
        lo0 = -(q[0, 0] * wx + q[1, 0] * wy + q[2, 0] * wz)
        lo1 = -(q[0, 1] * wx + q[1, 1] * wy + q[2, 1] * wz)
        lo2 = -(q[0, 2] * wx + q[1, 2] * wy + q[2, 2] * wz)
        for i in range(i0, i1):
            b0 = mm[0, 0] + tz[i] * mm[0, 2]
            b1 = mm[1, 0] + tz[i] * mm[1, 2]
            b2 = mm[2, 0] + tz[i] * mm[2, 2]
            for j in range(j0, j1):
                if out[n, i, j] <= z_near:
                    continue
                t = _hit_t(k, lo0, lo1, lo2, b0 + ty[j] * mm[0, 1], b1 + ty[j] * mm[1, 1],
                           b2 + ty[j] * mm[2, 1], h0, h1, h2)
                if t < out[n, i, j]:
                    out[n, i, j] = t


@numba.njit(parallel=True, **_JIT)
def _cast_parallel(
    origins, rots, ty, tz, kind, center, orot, half, bound_r, floor_z, ceiling_z, max_t, n_band, out
):  # pragma: no cover - compiled
    """Cast out (N, H, W): work items (pose, band of rows), ``n_band`` bands per image, in parallel."""
    n_pose, n_row, n_col = out.shape
    dty = ty[1] - ty[0] if n_col > 1 else -1.0
    dtz = tz[1] - tz[0] if n_row > 1 else -1.0
    for item in numba.prange(n_pose * n_band):
        n, band = item // n_band, item % n_band
        _cast_item(n, band * n_row // n_band, (band + 1) * n_row // n_band, origins, rots, ty, tz, dty,
                   dtz, kind, center, orot, half, bound_r, floor_z, ceiling_z, max_t, out)


@numba.njit(**_JIT)
def _cast_serial(
    origins, rots, ty, tz, kind, center, orot, half, bound_r, floor_z, ceiling_z, max_t, n_band, out
):  # pragma: no cover - compiled
    """As :func:`_cast_parallel` on the calling thread only (no thread-pool wake-ups)."""
    n_pose, n_row, n_col = out.shape
    dty = ty[1] - ty[0] if n_col > 1 else -1.0
    dtz = tz[1] - tz[0] if n_row > 1 else -1.0
    for n in range(n_pose):
        _cast_item(n, 0, n_row, origins, rots, ty, tz, dty, dtz, kind, center, orot, half, bound_r,
                   floor_z, ceiling_z, max_t, out)


@numba.njit(**_JIT)
def _to_mm(t, min_r, max_r, out):  # pragma: no cover - compiled
    """Ray parameters (H, W) -> uint16 depth (mm, rounded) with 0 outside [min_r, max_r]."""
    for i in range(t.shape[0]):
        for j in range(t.shape[1]):
            v = t[i, j]
            out[i, j] = np.uint16(v * 1000.0 + 0.5) if min_r <= v <= max_r and v < 65.535 else 0


@numba.njit(**_JIT)
def _to_depth(t, min_r, max_r, out):  # pragma: no cover - compiled
    """Ray parameters (N, H, W) -> float32 depth with 0 outside [min_r, max_r]."""
    for n in range(t.shape[0]):
        for i in range(t.shape[1]):
            for j in range(t.shape[2]):
                v = t[n, i, j]
                out[n, i, j] = v if min_r <= v <= max_r else 0.0


@numba.njit(**_JIT)
def _to_mm_batch(t, min_r, max_r, out):  # pragma: no cover - compiled
    """Ray parameters (N, H, W) -> uint16 depth frames (mm, rounded), 0 outside [min_r, max_r]."""
    for n in range(t.shape[0]):
        _to_mm(t[n], min_r, max_r, out[n])


def _poses(pos_world_m: ArrayLike,
           rot: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    pos = np.ascontiguousarray(np.atleast_2d(np.asarray(pos_world_m, dtype=np.float64)))
    if pos.ndim != 2 or pos.shape[1] != 3 or not np.all(np.isfinite(pos)):
        raise ValueError(f"positions must be finite with shape (N, 3), got shape {pos.shape}")
    rot = np.ascontiguousarray(np.broadcast_to(rot, (pos.shape[0], 3, 3)), dtype=np.float64)
    return pos, rot


def cast_depth_m(geometry: Geometry, pos_world_m: ArrayLike, rot_world_body: ArrayLike, camera: CameraModel,
                 supersample: int = 1, parallel: bool | None = None) -> NDArray[np.float64]:
    """Raw ray cast: z-depth (m) of the nearest surface, inf where nothing is hit, 0 inside a solid.

    ``pos_world_m`` (N, 3), ``rot_world_body`` (N, 3, 3) body->world; returns (N, H*s, W*s) float64.
    ``parallel``: use numba's thread pool (default: for N >= ``PARALLEL_MIN_POSES``). Smaller
    batches and single frames are cast on the calling thread (GIL released): on a loaded machine,
    waking the pool costs milliseconds, more than it saves.
    """
    pos, rot = _poses(pos_world_m, np.asarray(rot_world_body, dtype=np.float64))
    ty, tz = camera.ray_slopes(supersample)
    out = np.empty((pos.shape[0], tz.size, ty.size))
    if parallel is None:
        parallel = pos.shape[0] >= PARALLEL_MIN_POSES
    # few poses in parallel: split each image into bands of rows so that all threads work
    threads = numba.get_num_threads()
    n_band = 1 if pos.shape[0] >= 4 * threads or not parallel else min(tz.size, 4 * threads)
    g = geometry
    (_cast_parallel if parallel else _cast_serial)(pos, rot, ty, tz, g.kind, g.center_m, g.rot_m, g.half_m,
                                                   g.bound_r_m, g.floor_z_m, g.ceiling_z_m,
                                                   camera.max_range_m, n_band, out)
    return out


def _yaw_rot(pos_world_m: ArrayLike, yaw_rad: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    pos = np.atleast_2d(np.asarray(pos_world_m, dtype=np.float64))
    yaw = np.broadcast_to(np.asarray(yaw_rad, dtype=np.float64), (pos.shape[0],))
    return pos, rotmat_yaw(yaw)


def render_depth_m(world: World, pos_world_m: ArrayLike, yaw_rad: ArrayLike,
                   camera: CameraModel = D435_424x240) -> NDArray[np.float32]:
    """Noise-free depth images (z-depth, m; 0 = no return) at level attitude, shape (N, H, W) float32.

    ``pos_world_m`` (N, 3) camera/body positions (world), ``yaw_rad`` (N,) headings (world yaw).
    """
    pos, rot = _yaw_rot(pos_world_m, yaw_rad)
    t = cast_depth_m(world.geometry, pos, rot, camera)
    out = np.empty(t.shape, dtype=np.float32)
    _to_depth(t, camera.min_range_m, camera.max_range_m, out)
    return out


def render_network_inputs(world: World, pos_world_m: ArrayLike, yaw_rad: ArrayLike,
                          preprocess: PreprocessConfig = PreprocessConfig(), *,
                          camera: CameraModel = D435_424x240, supersample: int = 2) -> NDArray[np.float32]:
    """The training path: network inputs (N, 32, 32) float32 in [0, 1], level attitude.

    Casts ``supersample``² rays per output pixel with ``camera``'s field of view and range rules
    into one frame and preprocesses it with the flight's code (:func:`render_inputs`); it matches
    ``preprocess_depth_mm(render_frame_mm(...))`` of a full-resolution frame closely
    (tests/test_render_paths.py).
    """
    mean = render_inputs(world, pos_world_m, yaw_rad, preprocess, camera=camera, supersample=supersample).mean
    assert mean is not None
    return mean


def render_inputs(world: World, pos_world_m: ArrayLike, yaw_rad: ArrayLike,
                  preprocess: PreprocessConfig = PreprocessConfig(), *, camera: CameraModel = D435_424x240,
                  supersample: int = 2, nearest: bool = False
                  ) -> DepthInputs:
    """Network inputs (as :func:`render_network_inputs`) and, with ``nearest``, the depth safety
    filter's view of the same frame and where in each cell it saw its surface (:class:`DepthInputs`).

    The sim camera renders a (32 s) x (32 s) uint16 depth frame with ``camera``'s field of view and
    range rules, and the frame goes through the flight's own preprocessing,
    :func:`quadnav_onboard.preprocess.depth_inputs_mm` (range rules, cell means, the 3x3 median
    and the nearest surface per cell): what training sees is computed by the code that flies."""
    frames = render_input_frames_mm(world, pos_world_m, yaw_rad, camera=camera, supersample=supersample)
    out = depth_inputs_mm(frames, preprocess, nearest=nearest)
    assert out.mean is not None
    return out


def render_input_frames_mm(world: World, pos_world_m: ArrayLike, yaw_rad: ArrayLike, *,
                           camera: CameraModel = D435_424x240, supersample: int = 2) -> NDArray[np.uint16]:
    """The sim camera's frames that :func:`render_inputs` preprocesses: uint16 depth (mm, 0 = no
    return), (N, 32 s, 32 s), ``camera``'s field of view and range rules, level attitude."""
    if supersample < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    cam = CameraModel(OUT_SIZE * supersample, OUT_SIZE * supersample, camera.hfov_deg, camera.vfov_deg,
                      camera.min_range_m, camera.max_range_m)
    pos, rot = _yaw_rot(pos_world_m, yaw_rad)
    t = cast_depth_m(world.geometry, pos, rot, cam)
    frames = np.empty(t.shape, dtype=np.uint16)
    _to_mm_batch(t, camera.min_range_m, camera.max_range_m, frames)
    return frames


def render_frame_mm(world: World, pos_world_m: ArrayLike, quat_world_body: ArrayLike,
                    camera: CameraModel = D435_424x240, noise: DepthNoise | None = None,
                    rng: np.random.Generator | None = None) -> NDArray[np.uint16]:
    """One full camera frame as a D435 delivers it: uint16 depth in mm, shape (H, W), 0 = invalid.

    ``pos_world_m`` (3,) and ``quat_world_body`` (w, x, y, z) give the full body pose (roll and
    pitch included). With ``noise`` the D435-like noise model is applied using ``rng`` (required).
    """
    rot = quat_to_rotmat(np.asarray(quat_world_body, dtype=np.float64))
    t = cast_depth_m(world.geometry, np.asarray(pos_world_m, dtype=np.float64).reshape(1, 3), rot, camera)
    if noise is None:
        frame = np.empty(t.shape[1:], dtype=np.uint16)
        _to_mm(t[0], camera.min_range_m, camera.max_range_m, frame)
        return frame
    if rng is None:
        raise ValueError("render_frame_mm: a noise model needs an rng (numpy.random.Generator)")
    depth = np.empty(t.shape, dtype=np.float32)
    _to_depth(t, camera.min_range_m, camera.max_range_m, depth)
    depth_m = apply_depth_noise(depth[0], noise, rng, max_range_m=camera.max_range_m)
    return np.rint(np.clip(depth_m, 0.0, 65.535) * 1000.0).astype(np.uint16)
