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

:func:`lattice_route` is the tighter check: a best-first search over the primitives themselves
from the path's start at rest, each one's flown path predicted as the filter predicts it (the
position loop, the stopping look-ahead) from a vehicle that tracks perfectly, and allowed when it
keeps every margin from the TRUE geometry (the filter only knows what it saw, which is less). It
answers whether some sequence of allowed primitives reaches the goal within the step limit (and
gives a short one's length); not whether a planner finds it.
"""

from __future__ import annotations

import dataclasses
import heapq
import math
from typing import TYPE_CHECKING, Any

import numba
import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.frames import body_to_world
from quadnav_onboard.primitives import PrimitiveSet
from quadnav_onboard.shield import (
    ShieldConfig,
    band_path,
    primitive_samples,
    within_known_space,
)
from quadnav_onboard.step import step_inputs
from sim_harness.collision import clearance_m
from sim_harness.world import World

if TYPE_CHECKING:
    from sim_harness.env import VecQuadNavEnv

__all__ = [
    "LIMITS",
    "LatticeRoute",
    "RouteReport",
    "lattice_route",
    "margin_field",
    "route_report",
    "true_geometry_verdict",
]

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
        if len(self.closed_by) == 1:
            opens = f"; lifting {self.closed_by[0]} alone would open one"
        elif self.closed_by:
            opens = "; lifting any one of " + ", ".join(self.closed_by) + " alone would open one"
        else:
            opens = "; no single limit lifted alone opens one"
        return f"{self.world}: no route keeps the filter's margins (grid {self.grid_m:.3f} m){opens}"


def _grid(world: World, shield: ShieldConfig, grid_m: float, max_deviation_m: float | None
          ) -> tuple[NDArray, float, tuple[int, int, int]]:
    """Cell centres (n, 3) of the box the route can be in, the voxel size used, the grid's shape."""
    pts = world.path.waypoints_m
    # the band may be lifted (closed_by); the episode's own deviation stop may not
    reach = max_deviation_m if max_deviation_m is not None else max(3.0, shield.band_half_width_m or 0.0)
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
    max_deviation_m: float | None = None,
) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.float64], float, tuple[int, int, int]]:
    """Per limit of :data:`LIMITS` the slack (m) of every cell, the cells (n, 3), the voxel size and
    the grid's shape. A limit the filter does not know (no room, no band, no altitude band) has an
    infinite slack. Two more entries are never lifted: ``solid``, the distance to the nearest solid
    (no route goes through a wall), and ``stop``, the slack inside ``max_deviation_m`` of the path,
    the episode's deviation stop (the env's; in flight the supervisor's)."""
    cells, g, shape = _grid(world, shield, grid_m, max_deviation_m)
    inf = np.full(cells.shape[0], np.inf)
    slack = {name: inf for name in LIMITS}
    solid = clearance_m(world, cells)
    slack["clearance"] = solid - shield.clearance_m
    slack["solid"] = solid
    slack["stop"] = inf
    if shield.fence_min_m is not None and shield.fence_max_m is not None:
        inside = np.minimum(cells - np.asarray(shield.fence_min_m), np.asarray(shield.fence_max_m) - cells)
        slack["room"] = inside.min(axis=1) - shield.fence_margin_m
    if shield.band_waypoints_m is not None and shield.band_half_width_m is not None:
        band = band_path(shield.band_waypoints_m)
        slack["deviation"] = shield.band_half_width_m - band.deviation_m(cells) - shield.band_margin_m
    if max_deviation_m is not None:
        slack["stop"] = max_deviation_m - world.path.deviation_m(cells)
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
    max_deviation_m: float | None = None,
) -> RouteReport:
    """Whether ``world`` leaves a route from its path's start to within ``goal_radius_m`` of its
    goal that keeps ``shield``'s margins (its known room and deviation band as set, e.g. by
    :func:`sim_harness.rl.evaluate.known_room`) and the altitude band ``altitude_m``, within the
    deviation stop ``max_deviation_m`` of the path."""
    if not (math.isfinite(grid_m) and grid_m > 0):
        raise ValueError(f"grid_m: bad value {grid_m!r}: must be finite and > 0")
    slack, cells, g, shape = margin_field(world, shield, altitude_m, grid_m, max_deviation_m)
    least = np.minimum.reduce([slack[name] for name in (*LIMITS, "stop")])  # clearance implies solid
    start = int(np.argmin(np.linalg.norm(cells - world.path.start_m, axis=1)))
    goal = np.linalg.norm(cells - world.path.goal_m, axis=1) <= goal_radius_m

    def connected(s: NDArray[np.float64], spare: float) -> bool:
        return bool(_connected(s >= spare, start, goal, *shape))

    start_ok = bool(least[start] >= 0.0)
    if not connected(least, 0.0):
        closed_by = tuple(
            name for name in LIMITS
            if np.isfinite(slack[name]).any()
            and connected(np.minimum.reduce([slack[n] for n in (*LIMITS, "solid", "stop") if n != name]), 0.0)
        )
        return RouteReport(world.name, False, 0.0, closed_by, start_ok, g)
    lo, hi = 0.0, float(min(least[start], least[goal].max()))
    while hi - lo > g / 2:  # the bottleneck, to half a cell
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if connected(least, mid) else (lo, mid)
    return RouteReport(world.name, True, round(lo, 3), (), start_ok, g)


MAX_LATTICE_STATES = 300_000
"""The lattice search gives up (``decided`` False) past this many distinct states."""

GREED = 3.0
"""Weight of the steps-to-go bound in the lattice search's priority (1: A*, shortest first)."""


@dataclasses.dataclass(frozen=True)
class LatticeRoute:
    """What :func:`lattice_route` found for one world."""

    steps: int | None
    """Primitives of the allowed sequence found from the start to the goal (short, not always the
    shortest); None: none within the step limit (or the search gave up: ``decided``)."""
    states: int
    """Distinct states (commanded point, last primitive) the search reached."""
    decided: bool
    """False when the search stopped at :data:`MAX_LATTICE_STATES` before an answer."""

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _true_clearance(
    world: World, prims: PrimitiveSet, shield: ShieldConfig, cmd_pos: NDArray, cmd_vel: NDArray,
    yaw: NDArray, pos: NDArray, vel: NDArray,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each primitive's clearance (M, A) from ``world``'s solids along its path as the filter
    predicts it (from the commanded point and velocity, the vehicle at ``pos``/``vel``, look-ahead
    included), lowered by the filter's known room and deviation band
    (:func:`~quadnav_onboard.shield.within_known_space`); and those samples (M, A, S, 3)."""
    samples = primitive_samples(prims, cmd_pos, cmd_vel, yaw, shield, pos_world_m=pos, vel_world_m_s=vel)
    clear = clearance_m(world, samples.reshape(-1, 3)).reshape(samples.shape[:3]).min(axis=2)
    return within_known_space(clear, samples, shield), samples


def _allowed(world: World, prims: PrimitiveSet, shield: ShieldConfig, pos: NDArray, vel: NDArray,
             altitude_m: tuple[float, float] | None) -> tuple[NDArray[np.bool_], NDArray, NDArray]:
    """For M states of a vehicle that tracks perfectly (on its commanded point at its commanded
    velocity): which primitives (M, A) keep every margin against the true geometry, their end
    points and end velocities (M, A, 3)."""
    yaw = world.path.yaw_at(world.path.closest(pos)[0])
    clear, samples = _true_clearance(world, prims, shield, pos, vel, yaw, pos, vel)
    m, a = clear.shape
    ok = clear >= shield.clearance_m
    if altitude_m is not None:
        z = samples[:, :, : shield.samples, 2]  # where the vehicle is (the supervisor stops it), not past
        ok &= (z.min(axis=2) >= altitude_m[0]) & (z.max(axis=2) <= altitude_m[1])
    d_world = body_to_world(np.broadcast_to(prims.end_displacement_m(np.arange(a)), (m, a, 3)), yaw[:, None])
    v_world = body_to_world(np.broadcast_to(prims.end_velocity_m_s(np.arange(a)), (m, a, 3)), yaw[:, None])
    return ok, pos[:, None, :] + d_world, v_world


def true_geometry_verdict(env: VecQuadNavEnv, ids: NDArray[np.int64] | None = None
                          ) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """What ``env``'s filter would allow at the next decision of the vehicles ``ids`` (default:
    all) if it saw the true geometry: each primitive's path predicted from the vehicle's state as
    the filter predicts it (look-ahead included), its clearance from the world's solids, lowered
    by the known room and the deviation band as the filter lowers it; (allowed (M, A) by
    ``clearance_m`` alone, without the least-bad fallback; clearance (M, A))."""
    ids = np.arange(env.n_envs) if ids is None else np.asarray(ids, dtype=np.int64)
    allowed = np.zeros((ids.size, env.prims.n_actions), dtype=bool)
    clear = np.zeros((ids.size, env.prims.n_actions))
    for w in np.unique(env.world_idx[ids]):
        rows = np.flatnonzero(env.world_idx[ids] == w)
        sel = ids[rows]
        world, shield = env.worlds[w], env.world_shield(int(w))
        yaw = step_inputs(world.path, env.steps[sel], env.prims.duration_s, env.pos_m[sel]).yaw_rad
        clear[rows] = _true_clearance(world, env.prims, shield, env.cmd_pos_m[sel], env.cmd_vel_m_s[sel],
                                      yaw, env.pos_m[sel], env.vel_m_s[sel])[0]
        allowed[rows] = clear[rows] >= shield.clearance_m
    return allowed, clear


def lattice_route(
    world: World,
    prims: PrimitiveSet,
    shield: ShieldConfig,
    goal_radius_m: float,
    max_steps: int,
    altitude_m: tuple[float, float] | None = None,
    max_deviation_m: float | None = None,
    batch: int = 256,
    start_m: NDArray | None = None,
) -> LatticeRoute:
    """A sequence of primitives from ``world``'s path start (at rest) to within ``goal_radius_m``
    of its goal (or past its end) in at most ``max_steps``, each primitive allowed by ``shield``'s
    margins against the true geometry (see the module docstring), never farther than
    ``max_deviation_m`` from the path (the episode's stop). Best-first (weighted A*:
    steps so far plus :data:`GREED` times a lower bound of the steps to go, ``batch`` states
    expanded at a time, so the sequence found is short but not always the shortest); a state is
    dropped only when even the lower bound overruns the step limit, and every other is expanded
    before "none" is answered. ``start_m``: start there, at rest, instead of the path's start (as
    an eval's jittered start)."""
    path = world.path
    start = path.start_m.astype(np.float64) if start_m is None else np.asarray(start_m, dtype=np.float64)
    step_m = float(np.linalg.norm(prims.end_displacement_m(np.arange(prims.n_actions)), axis=1).max())

    def to_go(p: NDArray) -> NDArray:  # steps at least, from p to the goal ball (admissible)
        return np.maximum(np.linalg.norm(p - path.goal_m, axis=-1) - goal_radius_m, 0.0) / step_m

    pos_l, vel_l, g_l = [start], [np.zeros(3)], [0]
    seen: set[tuple[int, ...]] = {(*np.round(start / 0.01).astype(int).tolist(), -1)}
    heap: list[tuple[float, int]] = [(float(to_go(start)), 0)]
    while heap:
        take = [heapq.heappop(heap)[1] for _ in range(min(batch, len(heap)))]
        pos, vel = np.array([pos_l[i] for i in take]), np.array([vel_l[i] for i in take])
        g = np.array([g_l[i] for i in take])
        ok, ends, v_end = _allowed(world, prims, shield, pos, vel, altitude_m)
        rows, acts = np.nonzero(ok)
        if rows.size == 0:
            continue
        new_pos, new_vel, new_g = ends[rows, acts], v_end[rows, acts], g[rows] + 1
        arc, dev = path.closest(new_pos)
        if max_deviation_m is not None:  # the episode ends there
            inside = dev <= max_deviation_m
            new_pos, new_vel, new_g, acts, arc = (x[inside] for x in (new_pos, new_vel, new_g, acts, arc))
        near = np.linalg.norm(new_pos - path.goal_m, axis=1) <= goal_radius_m
        done = near | (arc >= path.length_m - 1e-9)
        if done.any():
            return LatticeRoute(int(new_g[done].min()), len(seen), True)
        h = to_go(new_pos)
        bound, priority = new_g + h, new_g + GREED * h
        keys = np.concatenate([np.round(new_pos / 0.01).astype(np.int64), acts[:, None]], axis=1)
        for j, key in enumerate(map(tuple, keys.tolist())):
            if bound[j] > max_steps or key in seen:
                continue
            seen.add(key)
            pos_l.append(new_pos[j])
            vel_l.append(new_vel[j])
            g_l.append(int(new_g[j]))
            heapq.heappush(heap, (float(priority[j]), len(pos_l) - 1))
        if len(seen) > MAX_LATTICE_STATES:
            return LatticeRoute(None, len(seen), False)
    return LatticeRoute(None, len(seen), True)
