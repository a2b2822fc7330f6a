"""A depth safety filter on the motion primitives (beyond the paper).

The paper's agent crashes when it moves sideways or vertically into obstacles that have left the
camera's field of view: it has no memory of what it saw. The shield gives the planner that memory
and a veto. Each decision's 32x32 depth input is back-projected into 3-D points (the D435
pinhole model at the input's depth) and kept, in the world frame, for the last ``memory_steps``
decisions. That input is, by default, the *nearest* surface in each cell of the frame
(``depth_pooling``), not the network's area-averaged input, placed on the ray of the pixel that
saw it (on the cell's centre ray a slanted face would come out nearer than it is), and each point
has a "shadow" point ``shadow_m`` behind it along its ray (the unseen back of what was seen),
forgotten once a view from elsewhere sees through it (``carve_shadows``). Before the DQN's
arg-max, every primitive is sampled along its commanded Bézier curve (plus a short look-ahead at
its end velocity, the overshoot of stopping after it) and its clearance is the least distance
from those samples to any remembered point. A primitive is *allowed* when its clearance is at
least ``clearance_m`` (the quad's radius plus a margin for tracking error). When none is
allowed, the ones with the largest clearance are: the shield degrades to "least bad", never to
"no answer".

Everything here is a pure function of its inputs (numpy, plus numba kernels for the distance
search, the tracking prediction and the views' free space), shared by the simulator (batched
over N vehicles) and the flight daemon (N = 1), so what is trained is what flies. Frames: world
x forward, y left, z up (m); the heading frame is the world rotated by the heading yaw; depth
inputs are float32 (32, 32) in [0, 1] (depth / max range, see :mod:`quadnav_onboard.preprocess`),
row 0 up, column 0 left.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Annotated

import numba
import numpy as np
import pydantic
from numpy.typing import ArrayLike, NDArray

from quadnav_onboard.config import CONFIG_DICT, parse_config
from quadnav_onboard.frames import body_to_world, pixel_slopes, world_to_body
from quadnav_onboard.jit import CAN_CACHE, kernel_array
from quadnav_onboard.path import RoughPath
from quadnav_onboard.preprocess import OUT_SIZE
from quadnav_onboard.primitives import PrimitiveSet, bezier_control_points, bezier_position, bezier_velocity

__all__ = [
    "LOOKAHEADS",
    "PointMemory",
    "ShieldConfig",
    "allowed_actions",
    "band_clearance",
    "band_path",
    "depth_points_heading",
    "fence_clearance",
    "points_per_view",
    "primitive_clearance",
    "primitive_samples",
    "primitive_seen_free",
    "shield_at_scale",
    "shield_config_from_meta",
    "shield_verdict",
    "view_points_heading",
    "within_known_space",
]

INPUT_SIZE = OUT_SIZE


_OffsetM = Annotated[float, pydantic.Field(ge=-1, le=1)]
_CoordM = Annotated[float, pydantic.Field(ge=-10_000, le=10_000)]


LOOKAHEADS = ("velocity", "stop")
"""What ``ShieldConfig.lookahead`` may be."""


@dataclass(frozen=True)
class ShieldConfig:
    """The depth safety filter; off by default (the paper has none). Each numeric field's range is
    in its docstring; a config file outside it is refused (:mod:`quadnav_onboard.config`)."""

    __pydantic_config__ = CONFIG_DICT

    enabled: bool = False
    """Veto primitives whose swept path comes closer than ``clearance_m`` to a seen obstacle."""
    clearance_m: Annotated[float, pydantic.Field(gt=0, le=5)] = 0.5
    """Least allowed distance (m) from the primitive's predicted path to any remembered depth point
    (the quad's 0.3 m radius plus a margin for depth noise and what the prediction misses).
    Range: (0, 5], below ``search_radius_m``."""
    memory_steps: Annotated[int, pydantic.Field(ge=1, le=64)] = 4
    """Decisions whose depth points are remembered (the current one included), counted at the
    primitive scale the model was trained with. Flown with shorter primitives, the filter keeps
    proportionally more decisions, so it remembers the same distance of travel
    (:func:`shield_at_scale`): 4 at 1 m is 8 at 0.5 m. Range: [1, 64]."""
    samples: Annotated[int, pydantic.Field(ge=1, le=64)] = 8
    """Points sampled along each primitive (its start excluded). Range: [1, 64]."""
    lookahead_s: Annotated[float, pydantic.Field(ge=0, le=5)] = 0.3
    """Extra time (s) at the primitive's end velocity checked past its end (stopping overshoot),
    with ``lookahead = "velocity"``. Range: [0, 5]."""
    lookahead: str = "velocity"
    """What is checked past the primitive's end. ``"velocity"``: one more point ``lookahead_s``
    further on at the end velocity. ``"stop"``: the stop that can always follow, a primitive of
    zero displacement starting at this one's end velocity (so the next decision can hover), flown
    through the same tracking model and sampled as the primitive is: every allowed primitive
    leaves the vehicle a way to stop ``clearance_m`` from everything the filter knows of. A stop
    overshoots the end by about 4/27 of one step's travel plus the tracking lag, instead of
    ``lookahead_s`` of it; docs/results.md ("How much of the cap is physics") has its figures."""
    min_travel_m: Annotated[float, pydantic.Field(ge=0, le=5)] = 0.3
    """A decision taken less than this far (m) from a remembered one (the nearest such) replaces it
    instead of pushing the oldest out: hovering in place, or going back and forth between two
    places, does not forget what was seen on the way. Range: [0, 5]."""
    track_omega_rad_s: Annotated[float, pydantic.Field(gt=0, le=100)] = 6.0
    """Natural frequency (rad/s) of the position loop assumed when predicting the flown path. This
    is the daemon's model of PX4, kept apart from the simulated vehicle (``sim_harness.quad``) on
    purpose; with these defaults the two agree within 3 cm (tests/test_shield.py). Range: (0, 100]."""
    track_accel_m_s2: Annotated[float, pydantic.Field(gt=0, le=50)] = 4.0
    """Acceleration limit (m/s^2) of that position loop (PX4's MPC_ACC_HOR_MAX-like). Range: (0, 50]."""
    track_dt_s: Annotated[float, pydantic.Field(gt=0, le=1)] = 0.05
    """Largest integration step (s) of the prediction (the step divides the primitive evenly
    between the samples: 1/24 s for 1 s primitives and 8 samples). Range: (0, 1]."""
    require_seen: bool = False
    """Also veto primitives that fly into space no remembered view saw to be free (beside or below
    the camera's field of view, behind obstacles). Safer in principle, but the planner then often
    hovers in place until the step limit (docs/results.md); off by default."""
    seen_level_tol_m: Annotated[float, pydantic.Field(ge=0, le=10)] | None = None
    """Without ``require_seen``: samples more than this (m) above or below the vehicle must still
    lie in space a view saw free (climbs and descents into the unseen floor or ceiling); None = off.
    Range: [0, 10] or None."""
    seen_margin_m: Annotated[float, pydantic.Field(ge=0, le=5)] = 0.3
    """A sample counts as seen free when it lies this far (m) in front of the measured depth.
    Range: [0, 5]."""
    near_m: Annotated[float, pydantic.Field(ge=0, le=5)] = 0.4
    """Samples within this distance (m) of the vehicle's current position count as free. Range: [0, 5]."""
    hfov_deg: Annotated[float, pydantic.Field(gt=0, lt=180)] = 87.0
    """Horizontal field of view (deg) of the depth camera the inputs come from (D435). Range: (0, 180)."""
    vfov_deg: Annotated[float, pydantic.Field(gt=0, lt=180)] = 58.0
    """Vertical field of view (deg) of the depth camera. Range: (0, 180)."""
    max_range_m: Annotated[float, pydantic.Field(gt=0, le=65)] = 10.0
    """Depth (m) of an input value of 1.0 (the preprocessing's max range): 'nothing seen'. Range: (0, 65]."""
    search_radius_m: Annotated[float, pydantic.Field(gt=0, le=20)] = 1.5
    """Clearances are capped at this distance (m); points farther from every sample are ignored.
    Range: (0, 20]."""
    depth_pooling: str = "min"
    """How the filter's 32x32 depth comes from the camera frame: ``"min"``, the nearest surface in
    each cell (a pole thinner than a cell, or an edge, keeps its true depth), or ``"mean"``, the
    network's own area-averaged input (edges blend with the background behind them)."""
    shadow_m: Annotated[float, pydantic.Field(ge=0, le=5)] = 0.3
    """Each remembered point also stands for what lies behind it: a second point this far (m)
    further along its ray, so the unseen back of a pipe or the far side of a trunk counts as solid
    when the vehicle moves round or over it. 0 = the seen surfaces only.
    Range: [0, 5], below ``search_radius_m``."""
    carve_shadows: bool = True
    """Forget a shadow point once another remembered view saw through it (it lies in that view's
    field of view, ``seen_margin_m`` or more in front of the nearest surface measured there): the
    space behind a surface is unknown only until a view from elsewhere looks into it. Without this,
    the shadows of a face seen at a slant stick out past the obstacle's far edge, into space
    the vehicle has since seen to be free, and close the way round it."""
    known_floor: bool = True
    """Also keep ``clearance_m`` from the floor plane when its height is known (the sim: each
    world's floor; the daemon: world z = 0, which is the ground the vehicle stood on at take-off or
    the configured ground, never the estimator's origin: ``safety.ground_reference``).
    The camera cannot see the floor below the vehicle; descents onto it were what crashed."""
    camera_offset_m: tuple[_OffsetM, _OffsetM, _OffsetM] = (0.0, 0.0, 0.0)
    """Where the depth camera sits relative to the odometry's body origin, in the heading frame
    (m: forward, left, up). The sim's camera is at the origin; a D435 on a real airframe is
    typically ~0.1 m forward. Remembered points and views are placed from the camera, not the
    body origin (the network itself was trained with the camera at the origin).
    Range: [-1, 1] m per axis."""
    fence_min_m: tuple[_CoordM, _CoordM, _CoordM] | None = None
    """Lowest corner (world, m, each in [-10 000, 10 000]) of the known room: the box the vehicle's
    centre must stay in (a flight's geofence, intersected with a lab's walls less ``clearance_m``:
    :meth:`with_room`). Known space, as the floor is: whether or not a view ever saw its faces, no
    primitive whose predicted flown path (look-ahead included) comes nearer than
    ``fence_margin_m`` to leaving the box is allowed. None (with ``fence_max_m``): no room known."""
    fence_max_m: tuple[_CoordM, _CoordM, _CoordM] | None = None
    """Highest corner (world, m, each in [-10 000, 10 000], above ``fence_min_m`` on every axis)
    of the known room; None together with ``fence_min_m``."""
    fence_margin_m: Annotated[float, pydantic.Field(ge=0, le=5)] = 0.1
    """How far (m) inside the known room's faces the predicted path must stay (the position loop's
    tracking error beyond the prediction). Range: [0, 5], below ``clearance_m``."""
    band_waypoints_m: tuple[tuple[_CoordM, _CoordM, _CoordM], ...] | None = None
    """The rough path (world, m, each coordinate in [-10 000, 10 000], >= 2 waypoints) whose
    deviation band is known space, as the room is: a flight stops when the vehicle gets farther
    than ``band_half_width_m`` from it (``safety.max_deviation_m``), so no primitive whose predicted
    flown path (look-ahead included) comes nearer than ``band_margin_m`` to leaving the band is
    allowed (:meth:`with_band`). None (with ``band_half_width_m``): no band."""
    band_half_width_m: Annotated[float, pydantic.Field(gt=0, le=50)] | None = None
    """Half-width (m) of that band: the flight's deviation limit. Range: (0, 50], above
    ``band_margin_m``; None together with ``band_waypoints_m``."""
    band_margin_m: Annotated[float, pydantic.Field(ge=0, le=5)] = 0.1
    """How far (m) inside the band's edge the predicted path must stay (tracking error beyond the
    prediction). Range: [0, 5], below ``band_half_width_m``."""

    def __post_init__(self) -> None:
        if not self.clearance_m > 0 or not self.search_radius_m > self.clearance_m:
            raise ValueError(
                f"need 0 < clearance_m < search_radius_m, got clearance_m {self.clearance_m!r} and "
                f"search_radius_m {self.search_radius_m!r}"
            )
        if self.memory_steps < 1 or self.samples < 1 or self.lookahead_s < 0:
            raise ValueError("need memory_steps >= 1, samples >= 1 and lookahead_s >= 0")
        if not (0 < self.hfov_deg < 180 and 0 < self.vfov_deg < 180):
            raise ValueError("fields of view must be in (0, 180) deg")
        if self.lookahead not in LOOKAHEADS:
            raise ValueError(f"lookahead must be 'velocity' or 'stop', got {self.lookahead!r}")
        if self.depth_pooling not in ("min", "mean"):
            raise ValueError(f"depth_pooling must be 'min' or 'mean', got {self.depth_pooling!r}")
        if not (0 <= self.shadow_m < self.search_radius_m):
            raise ValueError(
                f"need 0 <= shadow_m < search_radius_m, got shadow_m {self.shadow_m!r} and "
                f"search_radius_m {self.search_radius_m!r}"
            )
        if len(self.camera_offset_m) != 3 or not all(math.isfinite(v) for v in self.camera_offset_m):
            raise ValueError(f"camera_offset_m must be 3 finite numbers, got {self.camera_offset_m!r}")
        lo, hi = self.fence_min_m, self.fence_max_m
        if (lo is None) != (hi is None):
            raise ValueError(f"give both fence_min_m and fence_max_m or neither, got {lo!r} and {hi!r}")
        if lo is not None and hi is not None:
            if len(lo) != 3 or len(hi) != 3 or not all(math.isfinite(v) for v in (*lo, *hi)):
                raise ValueError(f"fence_min_m and fence_max_m must be 3 finite numbers, got {lo!r}, {hi!r}")
            if not all(a < b for a, b in zip(lo, hi, strict=True)):
                raise ValueError(f"fence_min_m {list(lo)} must be below fence_max_m {list(hi)} on every axis")
        self._check_band()
        if not 0 <= self.fence_margin_m < self.clearance_m:
            raise ValueError(
                f"need 0 <= fence_margin_m < clearance_m, got fence_margin_m {self.fence_margin_m!r} and "
                f"clearance_m {self.clearance_m!r}"
            )

    def _check_band(self) -> None:
        pts, half = self.band_waypoints_m, self.band_half_width_m
        if (pts is None) != (half is None):
            raise ValueError(
                f"give both band_waypoints_m and band_half_width_m or neither, got {pts!r} and {half!r}"
            )
        if pts is not None and half is not None:
            finite = all(math.isfinite(v) for p in pts for v in p)
            if len(pts) < 2 or any(len(p) != 3 for p in pts) or not finite:
                raise ValueError(f"band_waypoints_m must be >= 2 points of 3 finite numbers, got {pts!r}")
            band_path(pts)  # a path as the mission's: consecutive waypoints distinct
            if not 0 <= self.band_margin_m < half:
                raise ValueError(
                    f"need 0 <= band_margin_m < band_half_width_m, got band_margin_m {self.band_margin_m!r} "
                    f"and band_half_width_m {half!r}"
                )

    def with_band(self, waypoints_m: ArrayLike | None, half_width_m: float | None) -> ShieldConfig:
        """This filter keeping the predicted path within ``half_width_m`` (less ``band_margin_m``)
        of the polyline ``waypoints_m`` (world, m, (W, 3)): a flight's deviation limit as known
        space (None, None: unchanged)."""
        if waypoints_m is None or half_width_m is None:
            return self
        pts = np.asarray(waypoints_m, dtype=np.float64).reshape(-1, 3)
        return replace(
            self,
            band_waypoints_m=tuple(tuple(float(v) for v in p) for p in pts),
            band_half_width_m=float(half_width_m),
        )

    def with_fence(self, min_m: ArrayLike | None, max_m: ArrayLike | None) -> ShieldConfig:
        """This filter with the box ``min_m`` .. ``max_m`` (world, m) where the vehicle's centre may
        be (a geofence) intersected into the known room (None, None: unchanged)."""
        if min_m is None or max_m is None:
            return self
        lo = np.asarray(min_m, dtype=np.float64)
        hi = np.asarray(max_m, dtype=np.float64)
        if not np.all(lo < hi):
            raise ValueError(f"fence {lo.tolist()} .. {hi.tolist()}: lower corner not below the upper")
        if self.fence_min_m is not None and self.fence_max_m is not None:
            lo = np.maximum(lo, self.fence_min_m)
            hi = np.minimum(hi, self.fence_max_m)
        return replace(self, fence_min_m=tuple(float(v) for v in lo), fence_max_m=tuple(float(v) for v in hi))

    def with_room(self, min_m: ArrayLike | None, max_m: ArrayLike | None) -> ShieldConfig:
        """This filter knowing solid faces (walls, a ceiling) at the box ``min_m`` .. ``max_m``
        (world, m, the space inside them): the centre keeps ``clearance_m`` from them, as from a
        seen surface (None, None: unchanged)."""
        if min_m is None or max_m is None:
            return self
        inset = self.clearance_m - self.fence_margin_m
        return self.with_fence(np.asarray(min_m, dtype=np.float64) + inset,
                               np.asarray(max_m, dtype=np.float64) - inset)


def shield_at_scale(cfg: ShieldConfig, trained_scale_m: float, flown_scale_m: float) -> ShieldConfig:
    """``cfg`` (written for primitives of ``trained_scale_m``) for primitives of ``flown_scale_m``.

    An obstacle leaves the field of view after a given distance of sideways or vertical travel,
    not after a given number of decisions: with half-length primitives the memory keeps twice the
    decisions (rounded up). Distances, times and angles stay as they are.
    """
    if not (trained_scale_m > 0 and flown_scale_m > 0):
        raise ValueError(f"primitive scales must be > 0, got {trained_scale_m} and {flown_scale_m}")
    steps = max(1, math.ceil(cfg.memory_steps * trained_scale_m / flown_scale_m - 1e-9))
    return cfg if steps == cfg.memory_steps else replace(cfg, memory_steps=steps)


def shield_config_from_meta(meta: dict, source: str = "checkpoint.meta.shield") -> ShieldConfig:
    """The shield a checkpoint was trained and evaluated with (``meta["shield"]``; off if absent)."""
    raw = meta.get("shield")
    return ShieldConfig() if raw is None else parse_config(ShieldConfig, raw, source=source)


def _pixel_rays(cfg: ShieldConfig) -> NDArray[np.float64]:
    """Heading-frame rays (1024, 3) through the input's pixel centres, x component 1 (the same
    pinhole geometry the simulator renders the inputs with)."""
    ty, tz = pixel_slopes(INPUT_SIZE, INPUT_SIZE, cfg.hfov_deg, cfg.vfov_deg)
    rays = np.empty((INPUT_SIZE, INPUT_SIZE, 3))
    rays[..., 0] = 1.0
    rays[..., 1] = ty[None, :]
    rays[..., 2] = tz[:, None]
    return rays.reshape(-1, 3)


def depth_points_heading(
    depth_input: ArrayLike, cfg: ShieldConfig = ShieldConfig(), at: ArrayLike | None = None
) -> NDArray[np.float32]:
    """Back-project inputs (..., 32, 32) to heading-frame points (..., 1024, 3), metres, relative
    to the camera; pixels that saw nothing (value >= 0.999) are NaN.

    Each point lies on the ray through its cell's centre, or, given ``at`` (..., 32, 32, 2), on the
    ray through the place in the cell where its depth was seen (row, column offsets from the
    centre in input pixels: :attr:`quadnav_onboard.preprocess.DepthInputs.near_at`). A cell's
    nearest depth put on the centre ray of a slanted face is nearer than the face there."""
    d = np.asarray(depth_input, dtype=np.float32)
    flat = d.reshape(*d.shape[:-2], INPUT_SIZE * INPUT_SIZE)
    z = (flat * np.float32(cfg.max_range_m))[..., None]
    rays = _pixel_rays(cfg).astype(np.float32)
    if at is not None:
        off = np.asarray(at, dtype=np.float32).reshape(*d.shape[:-2], INPUT_SIZE * INPUT_SIZE, 2)
        step = _pixel_step(cfg)  # slope per input pixel, (row -> z, column -> y)
        rays = np.broadcast_to(rays, (*off.shape[:-1], 3)).copy()
        rays[..., 1] -= off[..., 1] * step[1]
        rays[..., 2] -= off[..., 0] * step[0]
    pts = z * rays
    return np.where((flat >= np.float32(0.999))[..., None], np.float32(np.nan), pts).astype(np.float32)


def _pixel_step(cfg: ShieldConfig) -> NDArray[np.float32]:
    """How much a ray's slope falls per input pixel down (z/x) and to the right (y/x)."""
    return np.array([2.0 * math.tan(math.radians(cfg.vfov_deg) / 2) / INPUT_SIZE,
                     2.0 * math.tan(math.radians(cfg.hfov_deg) / 2) / INPUT_SIZE], dtype=np.float32)


def points_per_view(cfg: ShieldConfig) -> int:
    """Points a view leaves in the memory: one per input pixel, two with shadows."""
    return INPUT_SIZE * INPUT_SIZE * (2 if cfg.shadow_m > 0 else 1)


def view_points_heading(
    depth_input: ArrayLike, cfg: ShieldConfig = ShieldConfig(), at: ArrayLike | None = None
) -> NDArray[np.float32]:
    """What a view leaves in the memory, heading frame relative to the camera: the surface points
    of :func:`depth_points_heading` (placed by ``at``, if given), then (``shadow_m`` > 0) each
    one moved ``shadow_m`` further along its ray; shape (..., points_per_view, 3)."""
    pts = depth_points_heading(depth_input, cfg, at)
    if cfg.shadow_m <= 0:
        return pts
    rng = np.linalg.norm(pts, axis=-1, keepdims=True)
    return np.concatenate([pts, pts * ((rng + np.float32(cfg.shadow_m)) / rng)], axis=-2)


class PointMemory:
    """What N vehicles saw at their last ``memory_steps`` decisions (a ring per vehicle).

    ``points``: float32 (N, memory_steps * points_per_view, 3), world frame, m, NaN where nothing
    is remembered (the obstacles, and their shadows). ``depth_m``: float32 (N, memory_steps, 32,
    32) z-depth (m) of each remembered view, ``pose``: (N, memory_steps, 4) camera position
    (world, m) and heading yaw (rad) of each view, NaN for empty slots (the space seen to be
    free). The newest view is last.
    """

    def __init__(self, n: int, cfg: ShieldConfig = ShieldConfig()) -> None:
        self.cfg = cfg
        k = cfg.memory_steps
        self.points = np.full((n, k * points_per_view(cfg), 3), np.nan, dtype=np.float32)
        self.depth_m = np.zeros((n, k, INPUT_SIZE, INPUT_SIZE), dtype=np.float32)
        self.pose = np.full((n, k, 4), np.nan)

    def copy(self) -> PointMemory:
        """An independent copy (the flight daemon never mutates a memory another thread may read)."""
        new = PointMemory.__new__(PointMemory)
        new.cfg = self.cfg
        new.points, new.depth_m, new.pose = self.points.copy(), self.depth_m.copy(), self.pose.copy()
        return new

    def clear(self, ids: ArrayLike | None = None) -> None:
        """Forget everything (of vehicles ``ids``, default all): a new episode or flight."""
        sel = slice(None) if ids is None else np.asarray(ids)
        self.points[sel] = np.nan
        self.pose[sel] = np.nan

    def add(self, ids: ArrayLike, depth_input: ArrayLike, pos_world_m: ArrayLike, yaw_rad: ArrayLike,
            at: ArrayLike | None = None) -> None:
        """Remember inputs (M, 32, 32) seen by vehicles ``ids`` (M,) at body position
        ``pos_world_m`` (M, 3) and heading ``yaw_rad`` (M,); the camera is ``camera_offset_m`` from
        there. ``at`` (M, 32, 32, 2): where in each cell its depth was seen
        (:func:`depth_points_heading`; None: on the cell's centre ray). The oldest view is
        dropped, unless the camera is within ``min_travel_m`` of a remembered view: then the
        nearest such view is dropped (a vehicle going back and forth between two places keeps
        both views and what it saw before them). With ``carve_shadows``, the shadows that the new
        view saw through, and the new view's shadows that a remembered view saw through, are
        forgotten."""
        ids = np.asarray(ids)
        pos = np.asarray(pos_world_m, dtype=np.float64)
        yaw = np.asarray(yaw_rad, dtype=np.float64)
        depth = np.asarray(depth_input, dtype=np.float32)
        offset = np.broadcast_to(np.asarray(self.cfg.camera_offset_m, dtype=np.float64), pos.shape)
        pos = pos + body_to_world(offset, yaw)  # the camera's position
        pts_w = body_to_world(view_points_heading(depth, self.cfg, at).astype(np.float64), yaw[:, None])
        pts_w += pos[:, None, :]
        k = points_per_view(self.cfg)
        mem, dep, pose = self.points[ids], self.depth_m[ids], self.pose[ids]
        dist = np.linalg.norm(pos[:, None, :] - pose[..., :3], axis=-1)  # (M, K), NaN: empty slot
        dist = np.where(np.isnan(dist), np.inf, dist)
        near = dist.argmin(axis=-1)
        drop = np.where(dist[np.arange(len(near)), near] < self.cfg.min_travel_m, near, 0)  # (M,)
        for r in np.unique(drop):  # slots after the dropped one move down one
            rows = drop == r
            mem[rows, r * k : -k] = mem[rows, (r + 1) * k :]
            dep[rows, r:-1] = dep[rows, r + 1 :]
            pose[rows, r:-1] = pose[rows, r + 1 :]
        mem[:, -k:] = pts_w
        dep[:, -1] = depth * np.float32(self.cfg.max_range_m)
        pose[:, -1, :3] = pos
        pose[:, -1, 3] = yaw
        if self.cfg.shadow_m > 0 and self.cfg.carve_shadows:
            mem, dep = kernel_array(mem, np.float32), kernel_array(dep, np.float32)
            pose = kernel_array(pose, np.float64)
            _carve_shadows(mem, dep, pose, k, INPUT_SIZE * INPUT_SIZE,
                           math.tan(math.radians(self.cfg.hfov_deg) / 2),
                           math.tan(math.radians(self.cfg.vfov_deg) / 2), self.cfg.seen_margin_m)
        self.points[ids], self.depth_m[ids], self.pose[ids] = mem, dep, pose


@numba.njit(cache=CAN_CACHE, nogil=True)
def _seen_free_by(
    depth_m: NDArray, pose: NDArray, i: int, f: int, x: float, y: float, z: float,
    tan_h: float, tan_v: float, margin: float,
) -> bool:  # pragma: no cover
    """Whether vehicle ``i``'s view ``f`` saw the world point (x, y, z) to be free: in its field
    of view and ``margin`` or more in front of the nearest surface it measured in that cell."""
    res = depth_m.shape[2]
    c, sn = math.cos(pose[i, f, 3]), math.sin(pose[i, f, 3])
    wx, wy, wz = x - pose[i, f, 0], y - pose[i, f, 1], z - pose[i, f, 2]
    fx = c * wx + sn * wy
    if fx <= 0.0:
        return False
    ty = (-sn * wx + c * wy) / fx
    tz = wz / fx
    if abs(ty) >= tan_h or abs(tz) >= tan_v:
        return False
    col = min(res - 1, int((1.0 - ty / tan_h) * 0.5 * res))
    row = min(res - 1, int((1.0 - tz / tan_v) * 0.5 * res))
    return fx + margin <= depth_m[i, f, row, col]


@numba.njit(cache=CAN_CACHE, nogil=True)
def _see_through(
    points: NDArray, depth_m: NDArray, pose: NDArray, i: int, lo: int, hi: int, f: int,
    tan_h: float, tan_v: float, margin: float,
) -> None:  # pragma: no cover
    """Vehicle ``i``'s points ``lo`` .. ``hi`` that view ``f`` saw through become NaN."""
    for q in range(lo, hi):
        x = points[i, q, 0]
        if x == x and _seen_free_by(depth_m, pose, i, f, x, points[i, q, 1], points[i, q, 2],
                                    tan_h, tan_v, margin):
            points[i, q, 0] = np.nan
            points[i, q, 1] = np.nan
            points[i, q, 2] = np.nan


@numba.njit(cache=CAN_CACHE, nogil=True)
def _carve_shadows(
    points: NDArray, depth_m: NDArray, pose: NDArray, per_view: int, n_surface: int,
    tan_h: float, tan_v: float, margin: float,
) -> None:  # pragma: no cover
    """After a view was added as the newest (last) slot: the older views' shadow points that it saw
    through, and its own shadow points that an older view saw through, become NaN. Each pair of
    views is compared once, when the later one arrives. A slot holds ``per_view`` points, the
    first ``n_surface`` of them surfaces, the rest their shadows."""
    n, k = pose.shape[0], pose.shape[1]
    new = k - 1
    for i in range(n):
        if pose[i, new, 0] != pose[i, new, 0]:
            continue
        for f in range(new):
            if pose[i, f, 0] != pose[i, f, 0]:
                continue  # empty slot
            _see_through(points, depth_m, pose, i, f * per_view + n_surface, (f + 1) * per_view, new,
                         tan_h, tan_v, margin)
            _see_through(points, depth_m, pose, i, new * per_view + n_surface, (new + 1) * per_view, f,
                         tan_h, tan_v, margin)


def primitive_samples(
    prims: PrimitiveSet,
    start_world_m: ArrayLike,
    start_vel_world_m_s: ArrayLike,
    yaw_rad: ArrayLike,
    cfg: ShieldConfig = ShieldConfig(),
    pos_world_m: ArrayLike | None = None,
    vel_world_m_s: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """World points (N, n_actions, samples + 1, 3) along every primitive of N vehicles.

    Each primitive starts at ``start_world_m`` (N, 3) (the previous commanded end point) with
    ``start_vel_world_m_s`` (N, 3), in the heading frame of ``yaw_rad`` (N,), exactly as it will
    be commanded. With the vehicle's ``pos_world_m`` and ``vel_world_m_s`` (N, 3) the samples are
    where a position controller (critically damped, ``track_omega_rad_s``, acceleration limited to
    ``track_accel_m_s2``) following the primitive will *be*, not where it is told to be: sharp
    reversals overshoot. Past the end come the look-ahead's points (``cfg.lookahead``): one
    ``lookahead_s`` further on at the end velocity, or the ``samples`` points of the stop that
    would follow (shape then (N, n_actions, 2 * samples, 3)).
    """
    start = np.asarray(start_world_m, dtype=np.float64)
    yaw = np.asarray(yaw_rad, dtype=np.float64)
    n, a = start.shape[0], prims.n_actions
    v0_h = world_to_body(np.asarray(start_vel_world_m_s, dtype=np.float64), yaw)  # (N, 3)
    ctrl = prims.control_points(np.broadcast_to(np.arange(a), (n, a)), v0_h[:, None, :])  # (N, A, 4, 3)
    per = max(1, int(np.ceil(prims.duration_s / cfg.track_dt_s / cfg.samples)))
    k_total = per * cfg.samples
    u = (np.arange(1, k_total + 1) / k_total)[:, None, None]  # (K, 1, 1)
    cmd_h = np.moveaxis(bezier_position(ctrl[None], u), 0, 2)  # (N, A, K, 3)
    vcmd_h = np.moveaxis(bezier_velocity(ctrl[None], u, prims.duration_s), 0, 2)
    if cfg.lookahead == "stop":  # then the stop from the end velocity: zero displacement, one step
        stop = bezier_control_points(np.zeros((a, 3)), prims.end_velocity_m_s(np.arange(a)), prims.duration_s)
        u_stop = u[:, :, 0]  # (K, 1): against (A, 4, 3) gives (K, A, 3)
        stop_pos = np.moveaxis(bezier_position(stop, u_stop), 0, 1)[None]  # (1, A, K, 3)
        stop_vel = np.moveaxis(bezier_velocity(stop, u_stop, prims.duration_s), 0, 1)[None]
        cmd_h = np.concatenate([cmd_h, cmd_h[:, :, -1:] + stop_pos], axis=2)
        vcmd_h = np.concatenate([vcmd_h, np.broadcast_to(stop_vel, vcmd_h.shape)], axis=2)
    cmd = start[:, None, None, :] + body_to_world(cmd_h, yaw[:, None, None])
    if pos_world_m is None:
        along = cmd[:, :, per - 1 :: per]
        v_end = body_to_world(np.broadcast_to(prims.end_velocity_m_s(np.arange(a)), (n, a, 3)), yaw[:, None])
    else:
        along, v_end = _predict_tracking(
            np.asarray(pos_world_m, dtype=np.float64),
            np.zeros(start.shape) if vel_world_m_s is None else np.asarray(vel_world_m_s, dtype=np.float64),
            cmd,
            body_to_world(vcmd_h, yaw[:, None, None]),
            prims.duration_s / k_total,
            per,
            cfg,
        )
    if cfg.lookahead == "stop":
        return along
    tail = along[:, :, -1] + v_end * cfg.lookahead_s
    return np.concatenate([along, tail[:, :, None]], axis=2)


def _predict_tracking(
    pos: NDArray, vel: NDArray, cmd: NDArray, vcmd: NDArray, dt: float, every: int, cfg: ShieldConfig
) -> tuple[NDArray, NDArray]:
    """Positions (N, A, K / every, 3) and final velocity (N, A, 3) of a critically damped,
    acceleration-limited position loop following ``cmd``/``vcmd`` (N, A, K, 3) from (N, 3)."""
    n, a, k = cmd.shape[:3]
    out = np.empty((n, a, k // every, 3))
    v_end = np.empty((n, a, 3))
    _track(
        kernel_array(pos, np.float64),
        kernel_array(vel, np.float64),
        kernel_array(cmd, np.float64),
        kernel_array(vcmd, np.float64),
        float(dt),
        int(every),
        float(cfg.track_omega_rad_s),
        float(cfg.track_accel_m_s2),
        out,
        v_end,
    )
    return out, v_end


@numba.njit(cache=CAN_CACHE, nogil=True)
def _track(
    pos: NDArray, vel: NDArray, cmd: NDArray, vcmd: NDArray, dt: float, every: int, w: float, amax: float,
    out: NDArray, v_end: NDArray,
) -> None:  # pragma: no cover
    n, a, k = cmd.shape[0], cmd.shape[1], cmd.shape[2]
    acc = np.empty(3)
    for i in range(n):
        for j in range(a):
            p0, p1, p2 = pos[i, 0], pos[i, 1], pos[i, 2]
            v0, v1, v2 = vel[i, 0], vel[i, 1], vel[i, 2]
            for q in range(k):
                acc[0] = w * w * (cmd[i, j, q, 0] - p0) + 2.0 * w * (vcmd[i, j, q, 0] - v0)
                acc[1] = w * w * (cmd[i, j, q, 1] - p1) + 2.0 * w * (vcmd[i, j, q, 1] - v1)
                acc[2] = w * w * (cmd[i, j, q, 2] - p2) + 2.0 * w * (vcmd[i, j, q, 2] - v2)
                norm = math.sqrt(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2])
                scale = min(1.0, amax / max(norm, 1e-12))
                v0 += acc[0] * scale * dt
                v1 += acc[1] * scale * dt
                v2 += acc[2] * scale * dt
                p0 += v0 * dt
                p1 += v1 * dt
                p2 += v2 * dt
                if (q + 1) % every == 0:
                    r = (q + 1) // every - 1
                    out[i, j, r, 0], out[i, j, r, 1], out[i, j, r, 2] = p0, p1, p2
            v_end[i, j, 0], v_end[i, j, 1], v_end[i, j, 2] = v0, v1, v2


@numba.njit(cache=CAN_CACHE, nogil=True)
def _min_distance(samples: NDArray, points: NDArray, cap: float, out: NDArray) -> None:  # pragma: no cover
    n, a, s = samples.shape[0], samples.shape[1], samples.shape[2]
    p = points.shape[1]
    for i in range(n):
        lo0 = lo1 = lo2 = np.inf
        hi0 = hi1 = hi2 = -np.inf
        for j in range(a):
            for k in range(s):
                lo0 = min(lo0, samples[i, j, k, 0])
                hi0 = max(hi0, samples[i, j, k, 0])
                lo1 = min(lo1, samples[i, j, k, 1])
                hi1 = max(hi1, samples[i, j, k, 1])
                lo2 = min(lo2, samples[i, j, k, 2])
                hi2 = max(hi2, samples[i, j, k, 2])
            out[i, j] = cap * cap
        for q in range(p):
            x, y, z = points[i, q, 0], points[i, q, 1], points[i, q, 2]
            if not (x >= lo0 - cap and x <= hi0 + cap):  # also skips NaN
                continue
            if not (lo1 - cap <= y <= hi1 + cap and lo2 - cap <= z <= hi2 + cap):
                continue
            for j in range(a):
                best = out[i, j]
                for k in range(s):
                    dx = samples[i, j, k, 0] - x
                    dy = samples[i, j, k, 1] - y
                    dz = samples[i, j, k, 2] - z
                    d2 = dx * dx + dy * dy + dz * dz
                    if d2 < best:
                        best = d2
                out[i, j] = best
        for j in range(a):
            out[i, j] = math.sqrt(out[i, j])


def primitive_clearance(
    samples_world_m: ArrayLike, points_world_m: ArrayLike, cfg: ShieldConfig = ShieldConfig()
) -> NDArray[np.float64]:
    """Least distance (m, capped at ``search_radius_m``) from each primitive's samples
    (N, A, S, 3) to the points (N, P, 3) (NaN rows ignored); shape (N, A)."""
    s = kernel_array(samples_world_m, np.float64)
    p = kernel_array(points_world_m, np.float32)
    out = np.empty(s.shape[:2], dtype=np.float64)
    _min_distance(s, p, float(cfg.search_radius_m), out)
    return out


@numba.njit(cache=CAN_CACHE, nogil=True)
def _seen_free(
    samples: NDArray, depth_m: NDArray, pose: NDArray, pos: NDArray, tan_h: float, tan_v: float,
    margin: float, near: float, level_tol: float, out: NDArray,
) -> None:  # pragma: no cover
    n, a, s = samples.shape[0], samples.shape[1], samples.shape[2]
    k = depth_m.shape[1]
    for i in range(n):
        for j in range(a):
            ok = True
            for q in range(s):
                x, y, z = samples[i, j, q, 0], samples[i, j, q, 1], samples[i, j, q, 2]
                dx0, dy0, dz0 = x - pos[i, 0], y - pos[i, 1], z - pos[i, 2]
                if dx0 * dx0 + dy0 * dy0 + dz0 * dz0 <= near * near:
                    continue  # where the vehicle is now is free
                if abs(dz0) <= level_tol:
                    continue  # only climbs and descents must be seen (level_tol = inf: none)
                seen = False
                for f in range(k):
                    if pose[i, f, 0] != pose[i, f, 0]:
                        continue  # empty slot
                    if _seen_free_by(depth_m, pose, i, f, x, y, z, tan_h, tan_v, margin):
                        seen = True
                        break
                if not seen:
                    ok = False
                    break
            out[i, j] = ok


def primitive_seen_free(
    samples_world_m: ArrayLike,
    view_depth_m: ArrayLike,
    view_pose: ArrayLike,
    pos_world_m: ArrayLike,
    cfg: ShieldConfig = ShieldConfig(),
) -> NDArray[np.bool_]:
    """(N, A): every sample of the primitive lies where some remembered view saw free space (in its
    field of view, ``seen_margin_m`` in front of what it measured), or within ``near_m`` of where
    the vehicle is now. Unknown space (beside or below the camera, behind an obstacle) is not free.
    ``view_depth_m`` (N, K, 32, 32) and ``view_pose`` (N, K, 4) are a :class:`PointMemory`'s."""
    s = kernel_array(samples_world_m, np.float64)
    out = np.empty(s.shape[:2], dtype=np.bool_)
    _seen_free(
        s,
        kernel_array(view_depth_m, np.float32),
        kernel_array(view_pose, np.float64),
        kernel_array(pos_world_m, np.float64),
        math.tan(math.radians(cfg.hfov_deg) / 2),
        math.tan(math.radians(cfg.vfov_deg) / 2),
        cfg.seen_margin_m,
        cfg.near_m,
        -1.0 if cfg.require_seen else (math.inf if cfg.seen_level_tol_m is None else cfg.seen_level_tol_m),
        out,
    )
    return out


def allowed_actions(
    clearance_m: ArrayLike, cfg: ShieldConfig = ShieldConfig(), seen_free: ArrayLike | None = None
) -> NDArray[np.bool_]:
    """Primitives (N, A) whose clearance is at least ``clearance_m`` (and, with ``seen_free``,
    whose path was seen to be free); where none is, the ones of largest clearance (least bad).
    All allowed when the shield is disabled."""
    c = np.asarray(clearance_m, dtype=np.float64)
    if not cfg.enabled:
        return np.ones(c.shape, dtype=bool)
    ok = c >= cfg.clearance_m
    if seen_free is not None:
        ok &= np.asarray(seen_free, dtype=bool)
    none = ~ok.any(axis=-1, keepdims=True)
    best = c >= c.max(axis=-1, keepdims=True) - 1e-9
    return np.where(none, best, ok)


def fence_clearance(
    samples_world_m: ArrayLike, fence_min_m: ArrayLike, fence_max_m: ArrayLike
) -> NDArray[np.float64]:
    """Least distance (m) from each primitive's samples (N, A, S, 3) to the faces of the box
    ``fence_min_m`` .. ``fence_max_m`` ((3,) or (N, 3), world), measured inwards: negative for a
    primitive with a sample outside (by how far); shape (N, A)."""
    s = np.asarray(samples_world_m, dtype=np.float64)
    lo = np.asarray(fence_min_m, dtype=np.float64).reshape(-1, 1, 1, 3)
    hi = np.asarray(fence_max_m, dtype=np.float64).reshape(-1, 1, 1, 3)
    return np.minimum(s - lo, hi - s).min(axis=(-1, -2))


def band_clearance(samples_world_m: ArrayLike, path: RoughPath, half_width_m: float) -> NDArray[np.float64]:
    """Least distance (m) from each primitive's samples (N, A, S, 3) to the edge of the band of
    ``half_width_m`` round ``path`` (the distance the supervisor's deviation stop measures,
    :meth:`~quadnav_onboard.path.RoughPath.deviation_m`), measured inwards: negative for a
    primitive with a sample outside (by how far); shape (N, A)."""
    return half_width_m - path.deviation_m(samples_world_m).max(axis=-1)


@functools.lru_cache(maxsize=256)  # a training env holds one band per world
def band_path(waypoints_m: tuple[tuple[float, float, float], ...]) -> RoughPath:
    """The band's rough path, built once per filter config (its waypoints are a config value)."""
    try:
        return RoughPath(np.asarray(waypoints_m, dtype=np.float64))
    except ValueError as exc:
        raise ValueError(f"band_waypoints_m: {exc}") from None


def within_known_space(
    clearance_m: NDArray[np.float64], samples_world_m: NDArray, cfg: ShieldConfig,
    fence_min_m: ArrayLike | None = None, fence_max_m: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """``clearance_m`` (N, A) of the primitives' samples (N, A, S, 3), lowered below
    ``cfg.clearance_m`` for each one that comes within ``fence_margin_m`` of leaving the known room
    (``fence_min_m``/``fence_max_m``, default the config's) or within ``band_margin_m`` of leaving
    the config's deviation band: those are vetoed as if near a wall (see :func:`shield_verdict`)."""
    clearance = clearance_m
    if fence_min_m is None or fence_max_m is None:
        fence_min_m, fence_max_m = cfg.fence_min_m, cfg.fence_max_m
    if fence_min_m is not None and fence_max_m is not None:
        inside = fence_clearance(samples_world_m, fence_min_m, fence_max_m)  # less than the margin: vetoed
        clearance = np.minimum(clearance, np.maximum(cfg.clearance_m + inside - cfg.fence_margin_m, 0.0))
    if cfg.band_waypoints_m is not None and cfg.band_half_width_m is not None:
        inside = band_clearance(samples_world_m, band_path(cfg.band_waypoints_m), cfg.band_half_width_m)
        clearance = np.minimum(clearance, np.maximum(cfg.clearance_m + inside - cfg.band_margin_m, 0.0))
    return clearance


def shield_verdict(
    prims: PrimitiveSet,
    points_world_m: ArrayLike,
    view_depth_m: ArrayLike,
    view_pose: ArrayLike,
    start_world_m: ArrayLike,
    start_vel_world_m_s: ArrayLike,
    yaw_rad: ArrayLike,
    pos_world_m: ArrayLike,
    vel_world_m_s: ArrayLike,
    cfg: ShieldConfig = ShieldConfig(),
    floor_z_m: ArrayLike | None = None,
    fence_min_m: ArrayLike | None = None,
    fence_max_m: ArrayLike | None = None,
) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """The whole check for N vehicles, as the env and the flight daemon both run it: the allowed
    primitives (N, A) and their clearances (m, (N, A)). ``points_world_m``, ``view_depth_m`` and
    ``view_pose`` are a :class:`PointMemory`'s arrays (rows of these N vehicles), the view of this
    decision already added; ``floor_z_m`` (N,) the floor's height under each vehicle (NaN or None:
    unknown; used with ``known_floor``); ``fence_min_m``/``fence_max_m`` ((3,) or (N, 3)) the known
    room of each vehicle (default: the config's ``fence_min_m``/``fence_max_m``; none: no room): a
    primitive whose samples come within ``fence_margin_m`` of its faces gets a clearance below
    ``clearance_m`` (vetoed; the least bad keep the most room), and so does one that comes within
    ``band_margin_m`` of leaving the config's deviation band (``band_waypoints_m``,
    ``band_half_width_m``); the rest as in :func:`primitive_samples`."""
    samples = primitive_samples(
        prims, start_world_m, start_vel_world_m_s, yaw_rad, cfg,
        pos_world_m=pos_world_m, vel_world_m_s=vel_world_m_s,
    )
    clearance = primitive_clearance(samples, points_world_m, cfg)
    if cfg.known_floor and floor_z_m is not None:
        floor = np.broadcast_to(np.asarray(floor_z_m, dtype=np.float64), clearance.shape[:1])[:, None]
        above = np.maximum(samples[..., 2].min(axis=-1) - floor, 0.0)  # NaN: floor unknown
        clearance = np.fmin(clearance, above)  # fmin keeps clearance where above is NaN
    clearance = within_known_space(clearance, samples, cfg, fence_min_m, fence_max_m)
    seen = None
    if cfg.require_seen or cfg.seen_level_tol_m is not None:
        seen = primitive_seen_free(samples, view_depth_m, view_pose, pos_world_m, cfg)
    return allowed_actions(clearance, cfg, seen), clearance
