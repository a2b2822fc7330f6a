"""Does a world leave a route that keeps the depth safety filter's margins?

The filter (:mod:`quadnav_onboard.shield`) vetoes every primitive that comes within
``clearance_m`` of a seen surface, within ``fence_margin_m`` of leaving the known room (a lab's
walls and the flight's geofence) or within ``band_margin_m`` of the flight's deviation limit; the
supervisor also stops a flight that leaves the altitude band. A world whose free space, shrunk by
those margins, does not connect the path's start to its goal cannot be flown to the goal behind the
filter by any planner. A lab written as a world file (docs/hardware.md) is worth this check before
its first rehearsal.

The check is a flood fill of a voxel grid (6-neighbour) over the margin field: each cell's least
slack over the limits (metres a centre there could move towards the nearest limit before breaking
its margin). ``spare_m`` is the widest slack a route keeps all the way (the route's bottleneck,
found by bisection to the grid's resolution). It is a necessary condition, not a sufficient one:
the vehicle flies a lattice of primitives with a stopping look-ahead, not any curve, so a route
with a few centimetres to spare may still be unflyable by primitives.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.path import RoughPath
from quadnav_onboard.shield import ShieldConfig
from sim_harness.collision import clearance_m
from sim_harness.world import World

__all__ = ["LIMITS", "RouteReport", "margin_field", "route_report"]

LIMITS = ("clearance", "room", "deviation", "altitude")
"""The margins the check keeps, by name: ``clearance`` from every solid (obstacles and walls),
``room`` inside the filter's known room, ``deviation`` inside the deviation band round the path,
``altitude`` inside the flight's altitude band."""

MAX_CELLS = 6_000_000
"""The grid is coarsened until it has at most this many cells (a 60 m paper world at 5 cm)."""


@dataclasses.dataclass(frozen=True)
class RouteReport:
    """What the check found for one world."""

    world: str
    route: bool
    """A route from the start to the goal ball keeps every margin."""
    spare_m: float
    """The widest slack (m) a route keeps beyond every margin, to ``grid_m``; 0 without a route."""
    closed_by: tuple[str, ...]
    """Without a route: the limits (of :data:`LIMITS`) each of which, lifted alone, opens one
    (``clearance`` lifted: the centre may come as close to a surface as it likes, not through it)."""
    start_ok: bool
    """The path's start itself keeps every margin."""
    grid_m: float
    """The voxel size the fill used."""

    def to_dict(self) -> dict[str, Any]:
        return {**dataclasses.asdict(self), "closed_by": list(self.closed_by)}

    def describe(self) -> str:
        if self.route:
            return f"{self.world}: a route keeps the filter's margins with {self.spare_m:.2f} m to spare"
        if not self.start_ok:
            return f"{self.world}: no route: the path's start itself breaks a margin of the filter"
        opens = (
            "; lifting any one of " + ", ".join(self.closed_by) + " alone would open one"
            if self.closed_by else "; no single limit lifted alone opens one"
        )
        return f"{self.world}: no route keeps the filter's margins (grid {self.grid_m:.3f} m){opens}"


def _grid(world: World, shield: ShieldConfig, grid_m: float) -> tuple[NDArray, float, tuple[int, int, int]]:
    """Cell centres (n, 3) of the box the route can be in, the voxel size used, the grid's shape."""
    pts = world.path.waypoints_m
    reach = max(3.0, shield.band_half_width_m or 0.0)  # the band may be lifted (closed_by)
    lo = pts.min(axis=0) - reach
    hi = pts.max(axis=0) + reach
    if shield.fence_min_m is not None and shield.fence_max_m is not None:
        lo = np.maximum(lo, np.asarray(shield.fence_min_m))
        hi = np.minimum(hi, np.asarray(shield.fence_max_m))
    if world.floor_z_m is not None:
        lo[2] = max(lo[2], world.floor_z_m)
    if world.ceiling_z_m is not None:
        hi[2] = min(hi[2], world.ceiling_z_m)
    hi = np.maximum(hi, lo)
    volume = float(np.prod(hi - lo + grid_m))
    g = max(grid_m, (volume / MAX_CELLS) ** (1.0 / 3.0))
    axes = [np.arange(lo[d], hi[d] + 1e-9, g) for d in range(3)]
    shape = (len(axes[0]), len(axes[1]), len(axes[2]))
    cells = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return cells, g, shape


def margin_field(
    world: World,
    shield: ShieldConfig,
    altitude_m: tuple[float, float] | None = None,
    grid_m: float = 0.025,
) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.float64], float, tuple[int, int, int]]:
    """Per limit of :data:`LIMITS` the slack (m) of every cell, the cells (n, 3), the voxel size and
    the grid's shape. A limit the filter does not know (no room, no band, no altitude band) has an
    infinite slack. ``solid`` (not a limit) is the distance to the nearest solid itself: no route
    goes through a wall, whatever is lifted."""
    cells, g, shape = _grid(world, shield, grid_m)
    inf = np.full(cells.shape[0], np.inf)
    slack = {name: inf for name in LIMITS}
    solid = clearance_m(world, cells)
    slack["clearance"] = solid - shield.clearance_m
    slack["solid"] = solid
    if shield.fence_min_m is not None and shield.fence_max_m is not None:
        inside = np.minimum(cells - np.asarray(shield.fence_min_m), np.asarray(shield.fence_max_m) - cells)
        slack["room"] = inside.min(axis=1) - shield.fence_margin_m
    if shield.band_waypoints_m is not None and shield.band_half_width_m is not None:
        band = RoughPath(np.asarray(shield.band_waypoints_m, dtype=np.float64))
        slack["deviation"] = shield.band_half_width_m - band.deviation_m(cells) - shield.band_margin_m
    if altitude_m is not None:
        slack["altitude"] = np.minimum(cells[:, 2] - altitude_m[0], altitude_m[1] - cells[:, 2])
    return slack, cells, g, shape


@numba.njit(cache=True)
def _connected(  # pragma: no cover (numba)
    free: NDArray[np.bool_], start: int, goal: NDArray[np.bool_], nx: int, ny: int, nz: int
) -> bool:
    """Breadth-first search over the 6-neighbour grid of ``free`` cells (flat, C order) from
    ``start``: whether it reaches any ``goal`` cell."""
    if not free[start]:
        return False
    seen = np.zeros(free.shape[0], dtype=np.bool_)
    queue = np.empty(free.shape[0], dtype=np.int64)
    head, tail = 0, 1
    queue[0] = start
    seen[start] = True
    sy, sx = nz, ny * nz
    while head < tail:
        c = queue[head]
        head += 1
        if goal[c]:
            return True
        i, rem = c // sx, c % sx
        j, k = rem // sy, rem % sy
        for di, dj, dk in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
            a, b, e = i + di, j + dj, k + dk
            if a < 0 or a >= nx or b < 0 or b >= ny or e < 0 or e >= nz:
                continue
            n = a * sx + b * sy + e
            if free[n] and not seen[n]:
                seen[n] = True
                queue[tail] = n
                tail += 1
    return False


def route_report(
    world: World,
    shield: ShieldConfig,
    goal_radius_m: float,
    altitude_m: tuple[float, float] | None = None,
    grid_m: float = 0.025,
) -> RouteReport:
    """Whether ``world`` leaves a route from its path's start to within ``goal_radius_m`` of its
    goal that keeps ``shield``'s margins (its known room and deviation band as set, e.g. by
    :func:`sim_harness.rl.evaluate.known_room`) and the altitude band ``altitude_m``."""
    if not (math.isfinite(grid_m) and grid_m > 0):
        raise ValueError(f"grid_m: bad value {grid_m!r}: must be finite and > 0")
    slack, cells, g, shape = margin_field(world, shield, altitude_m, grid_m)
    least = np.minimum.reduce([slack[name] for name in LIMITS])  # (clearance implies solid)
    start = int(np.argmin(np.linalg.norm(cells - world.path.start_m, axis=1)))
    goal = np.linalg.norm(cells - world.path.goal_m, axis=1) <= goal_radius_m

    def connected(s: NDArray[np.float64], spare: float) -> bool:
        return bool(_connected(s >= spare, start, goal, *shape))

    start_ok = bool(least[start] >= 0.0)
    if not connected(least, 0.0):
        closed_by = tuple(
            name for name in LIMITS
            if np.isfinite(slack[name]).any()
            and connected(np.minimum.reduce([slack[n] for n in (*LIMITS, "solid") if n != name]), 0.0)
        )
        return RouteReport(world.name, False, 0.0, closed_by, start_ok, g)
    lo, hi = 0.0, float(min(least[start], least[goal].max()))
    while hi - lo > g / 2:  # the bottleneck, to half a cell
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if connected(least, mid) else (lo, mid)
    return RouteReport(world.name, True, round(lo, 3), (), start_ok, g)
