"""Worlds: a rough path, a floor and a ceiling, and obstacles (boxes, spheres, cylinders).

A world is read from a YAML file with this contract (world frame: x forward, y left, z up; metres)::

    name: env04-slalom-lr            # required
    description: free text           # optional
    path:
      waypoints: [[0, 0, 2], [60, 0, 2]]
      speed_m_s: 1.0                 # optional, default 1.0
    bounds: {floor_z: 0.0, ceiling_z: 8.0}   # optional; floor and ceiling are solid
    room: {x: [-0.9, 3.4], y: [-0.9, 3.4]}   # optional: a room's walls (their inner faces, m)
    obstacles:                       # optional list; `center` is each shape's geometric centre
      - {type: box, center: [10, 1.5, 2], size: [1, 3, 4], yaw_deg: 0}
      - {type: sphere, center: [50, 0, 2], radius: 1.2}
      - {type: cylinder, center: [20, -1, 2.5], radius: 0.5, height: 5, axis: z}   # axis x|y|z

A bad file raises :class:`WorldError` naming the file, the entry (``obstacles[3]``) and the reason.
Every waypoint of the path (its start and goal included) must lie in free space: above the floor,
below the ceiling and outside every obstacle, with at least :data:`WAYPOINT_CLEARANCE_M` (the
simulated quad's radius) to spare; a path starting inside a box would crash on take-off, and one
above the ceiling could never be flown. The take-off climb, straight up from the ground below the
start (the floor, or z = 0 without one) as the emulated vehicle flies it, must be clear too. The
segments between waypoints may cross obstacles: flying round them is the planner's job.

``room`` (a lab) gives the inner faces of four walls along the world axes; it needs a floor and a
ceiling, and the walls (:data:`WALL_THICKNESS_M` thick, floor to ceiling) are solid like any
obstacle (:attr:`World.walls`, packed after ``obstacles``). Unlike obstacles they are *known*: the
depth safety filter keeps its clearance from them whether or not a view saw them
(:meth:`World.room_box_m`, :attr:`quadnav_onboard.shield.ShieldConfig.fence_min_m`).
Every world also carries :class:`Geometry`, the obstacles packed into arrays for the ray caster
(:mod:`sim_harness.render`) and the collision checker (:mod:`sim_harness.collision`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.config import ConfigError, load_yaml
from quadnav_onboard.path import RoughPath

__all__ = [
    "MAX_SPEED_M_S",
    "TEST_WORLD_IDS",
    "TRAIN_WORLD_IDS",
    "WALL_THICKNESS_M",
    "WAYPOINT_CLEARANCE_M",
    "WORLDS_DIR",
    "WORLD_LIMIT_M",
    "Box",
    "Cylinder",
    "Geometry",
    "Obstacle",
    "Sphere",
    "World",
    "WorldError",
    "load_world",
    "paper_world_path",
    "parse_world",
    "resolve_world_arg",
    "world_to_mapping",
]

WORLDS_DIR = Path(__file__).resolve().parent / "worlds"
TRAIN_WORLD_IDS = (1, 2, 3, 4, 5, 6, 7)
TEST_WORLD_IDS = (8, 9, 10)

WORLD_LIMIT_M = 10_000.0
"""Every coordinate and size (m) of a world file lies within ±10 km (yaw angles within ±360 deg)."""
MAX_SPEED_M_S = 5.0
"""Fastest moving setpoint (m/s) a world's path may ask for (the flight config's ``speed_m_s`` range)."""

WAYPOINT_CLEARANCE_M = 0.3
"""Least distance (m) from every waypoint to the floor, the ceiling and each obstacle: the radius of
the simulated quad (``sim_harness.quad.QuadParams.radius_m``), so it can be at each waypoint
without touching anything."""

WALL_THICKNESS_M = 0.2
"""Thickness (m) of the walls a world's ``room`` builds."""

# Shape codes in Geometry.kind.
KIND_BOX, KIND_SPHERE, KIND_CYLINDER = 0, 1, 2
Vec3 = tuple[float, float, float]


class WorldError(ValueError):
    """A world file that cannot be used; the message names the file, the entry and the reason."""


@dataclass(frozen=True)
class Box:
    """A box: geometric centre (world, m), full size (m) along its own x/y/z, yaw (deg) about world z."""

    center_m: Vec3
    size_m: Vec3
    yaw_deg: float = 0.0


@dataclass(frozen=True)
class Sphere:
    """A sphere: centre (world, m) and radius (m)."""

    center_m: Vec3
    radius_m: float


@dataclass(frozen=True)
class Cylinder:
    """A capped cylinder: geometric centre (world, m), radius (m), height (m) along ``axis``."""

    center_m: Vec3
    radius_m: float
    height_m: float
    axis: Literal["x", "y", "z"] = "z"


Obstacle = Box | Sphere | Cylinder

# Local frame (columns = local axes in world) of a cylinder whose local z is the given world axis.
_AXIS_FRAMES = {
    "z": np.eye(3),
    "x": np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),  # local (x,y,z) = world (y,z,x)
    "y": np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),  # local (x,y,z) = world (z,x,y)
}


@dataclass(frozen=True)
class Geometry:
    """Obstacles packed for vectorised kernels; M obstacles, all arrays read-only.

    A point ``p`` (world) is ``rot_m[i].T @ (p - center_m[i])`` in obstacle i's local frame, where
    a box spans ``±half_m``, a sphere has radius ``half_m[0]``, and a cylinder has radius
    ``half_m[0]`` and spans ``±half_m[2]`` along local z.
    """

    kind: NDArray[np.int64]
    """Shape code per obstacle (0 box, 1 sphere, 2 cylinder), shape (M,)."""
    center_m: NDArray[np.float64]
    """Geometric centres (world, m), shape (M, 3)."""
    rot_m: NDArray[np.float64]
    """Local-to-world rotations, shape (M, 3, 3)."""
    half_m: NDArray[np.float64]
    """Half extents in the local frame (m), shape (M, 3)."""
    bound_r_m: NDArray[np.float64]
    """Radius (m) of a sphere about the centre that encloses the shape, shape (M,)."""
    floor_z_m: float
    """Floor height (m); -inf when the world has none."""
    ceiling_z_m: float
    """Ceiling height (m); +inf when the world has none."""

    @classmethod
    def pack(cls, obstacles: tuple[Obstacle, ...], floor_z_m: float | None,
             ceiling_z_m: float | None) -> Geometry:
        """Pack obstacles and bounds (None = no floor / no ceiling)."""
        m = len(obstacles)
        kind = np.zeros(m, dtype=np.int64)
        center = np.zeros((m, 3))
        rot = np.tile(np.eye(3), (m, 1, 1))
        half = np.zeros((m, 3))
        for i, ob in enumerate(obstacles):
            center[i] = ob.center_m
            if isinstance(ob, Box):
                kind[i] = KIND_BOX
                half[i] = np.asarray(ob.size_m) / 2.0
                c, s = math.cos(math.radians(ob.yaw_deg)), math.sin(math.radians(ob.yaw_deg))
                rot[i] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
            elif isinstance(ob, Sphere):
                kind[i] = KIND_SPHERE
                half[i] = ob.radius_m
            else:
                kind[i] = KIND_CYLINDER
                half[i] = (ob.radius_m, ob.radius_m, ob.height_m / 2.0)
                rot[i] = _AXIS_FRAMES[ob.axis]
        bound = np.where(kind == KIND_BOX, np.linalg.norm(half, axis=1), 0.0)
        bound = np.where(kind == KIND_SPHERE, half[:, 0], bound)
        bound = np.where(kind == KIND_CYLINDER, np.hypot(half[:, 0], half[:, 2]), bound)
        arrays = [kind, center, rot, half, bound]
        for a in arrays:
            a.setflags(write=False)
        floor = -math.inf if floor_z_m is None else float(floor_z_m)
        ceiling = math.inf if ceiling_z_m is None else float(ceiling_z_m)
        return cls(*arrays, floor_z_m=floor, ceiling_z_m=ceiling)


@dataclass(frozen=True, eq=False)
class World:
    """A world: where to fly (``path``), what bounds it and what is in the way.

    Compared and hashed by identity (its path holds arrays), so worlds can key dicts and be found
    in lists; compare ``world_to_mapping`` results for equality of content.
    """

    name: str
    """Short identifier, e.g. ``env04-slalom-lr``."""
    path: RoughPath
    """The rough path (world frame) with the moving setpoint's speed."""
    description: str = ""
    """Free text for people."""
    floor_z_m: float | None = None
    """Height (m) of a solid floor, or None."""
    ceiling_z_m: float | None = None
    """Height (m) of a solid ceiling, or None."""
    obstacles: tuple[Obstacle, ...] = ()
    """Solid obstacles."""
    room_xy_m: tuple[tuple[float, float], tuple[float, float]] | None = None
    """Inner faces of a room's walls: ((x_min, x_max), (y_min, y_max)) (world, m), or None. The
    walls stand from the floor to the ceiling: without both (a copy made for a check) there are none."""
    geometry: Geometry = field(init=False, repr=False, compare=False)
    """The obstacles and the room's walls packed into arrays (derived)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "obstacles", tuple(self.obstacles))
        object.__setattr__(
            self, "geometry", Geometry.pack(self.obstacles + self.walls, self.floor_z_m, self.ceiling_z_m)
        )

    @property
    def walls(self) -> tuple[Box, ...]:
        """The room's four walls (boxes, floor to ceiling, outside its inner faces); () without a room."""
        if self.room_xy_m is None or self.floor_z_m is None or self.ceiling_z_m is None:
            return ()
        (x0, x1), (y0, y1) = self.room_xy_m
        t, z0, z1 = WALL_THICKNESS_M, self.floor_z_m, self.ceiling_z_m
        zc, h = (z0 + z1) / 2.0, z1 - z0
        wx, wy = x1 - x0 + 2 * t, y1 - y0 + 2 * t
        return (
            Box((x0 - t / 2, (y0 + y1) / 2, zc), (t, wy, h)),
            Box((x1 + t / 2, (y0 + y1) / 2, zc), (t, wy, h)),
            Box(((x0 + x1) / 2, y0 - t / 2, zc), (wx, t, h)),
            Box(((x0 + x1) / 2, y1 + t / 2, zc), (wx, t, h)),
        )

    def room_box_m(self) -> tuple[Vec3, Vec3] | None:
        """The room as the filter knows it: lowest and highest corner (world, m) of the space inside
        the walls, from the floor to the ceiling; None without a room."""
        if self.room_xy_m is None or self.floor_z_m is None or self.ceiling_z_m is None:
            return None
        (x0, x1), (y0, y1) = self.room_xy_m
        return (x0, y0, self.floor_z_m), (x1, y1, self.ceiling_z_m)


# ---------------------------------------------------------------------------------------------- parsing


def _number(value: Any, where: str, key: str, limit: float = WORLD_LIMIT_M) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise WorldError(f"{where}: '{key}' must be a finite number, got {value!r}")
    if abs(value) > limit:
        raise WorldError(f"{where}: '{key}' must be within ±{limit:g}, got {value!r}")
    return float(value)


def _vec3(value: Any, where: str, key: str) -> Vec3:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise WorldError(f"{where}: '{key}' must be a list of 3 numbers [x, y, z], got {value!r}")
    x, y, z = (_number(v, where, key) for v in value)
    return (x, y, z)


def _positive(value: Any, where: str, key: str) -> float:
    v = _number(value, where, key)
    if v <= 0.0:
        raise WorldError(f"{where}: '{key}' must be positive, got {value!r}")
    return v


def _mapping(value: Any, where: str, required: tuple[str, ...],
             allowed: tuple[str, ...]) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise WorldError(f"{where}: expected a mapping, got {type(value).__name__} {value!r}")
    for key in required:
        if key not in value:
            raise WorldError(f"{where}: missing required key '{key}'")
    unknown = sorted(str(k) for k in value if k not in allowed)
    if unknown:
        raise WorldError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    return value


_SHAPE_KEYS = {
    "box": (("center", "size"), ("type", "center", "size", "yaw_deg")),
    "sphere": (("center", "radius"), ("type", "center", "radius")),
    "cylinder": (("center", "radius", "height"), ("type", "center", "radius", "height", "axis")),
}


def _parse_obstacle(entry: Any, where: str) -> Obstacle:
    if not isinstance(entry, Mapping) or "type" not in entry:
        raise WorldError(f"{where}: expected a mapping with a 'type' (box, sphere, cylinder), got {entry!r}")
    shape = entry["type"]
    if shape not in _SHAPE_KEYS:
        raise WorldError(f"{where}: unknown shape type {shape!r}; expected one of {sorted(_SHAPE_KEYS)}")
    required, allowed = _SHAPE_KEYS[shape]
    _mapping(entry, where, required, allowed)
    center = _vec3(entry["center"], where, "center")
    if shape == "box":
        size = _vec3(entry["size"], where, "size")
        if min(size) <= 0.0:
            raise WorldError(f"{where}: 'size' must be 3 positive numbers, got {list(entry['size'])!r}")
        return Box(center, size, _number(entry.get("yaw_deg", 0.0), where, "yaw_deg", limit=360.0))
    if shape == "sphere":
        return Sphere(center, _positive(entry["radius"], where, "radius"))
    axis = entry.get("axis", "z")
    if axis not in ("x", "y", "z"):
        raise WorldError(f"{where}: 'axis' must be one of x, y, z, got {axis!r}")
    return Cylinder(center, _positive(entry["radius"], where, "radius"),
                    _positive(entry["height"], where, "height"), axis)


def _parse_room(
    value: Any, where: str, floor: float | None, ceiling: float | None
) -> tuple[tuple[float, float], tuple[float, float]] | None:
    if value is None:
        return None
    room = _mapping(value, where, ("x", "y"), ("x", "y"))
    if floor is None or ceiling is None:
        raise WorldError(f"{where}: a room needs 'bounds' with both floor_z and ceiling_z")
    out = []
    for key in ("x", "y"):
        span = room[key]
        if not isinstance(span, (list, tuple)) or len(span) != 2:
            raise WorldError(f"{where}: '{key}' must be [min, max] (m), got {span!r}")
        lo, hi = (_number(v, where, key) for v in span)
        if not hi - lo > 2 * WAYPOINT_CLEARANCE_M:
            raise WorldError(f"{where}: '{key}' {list(span)}: max must exceed min by more than "
                             f"{2 * WAYPOINT_CLEARANCE_M:g} m")
        out.append((lo, hi))
    return (out[0], out[1])


def parse_world(mapping: Any, source: str = "<world>") -> World:
    """Validate a mapping (e.g. loaded YAML) into a :class:`World`; errors name ``source`` and the entry."""
    top = _mapping(
        mapping, source, ("name", "path"), ("name", "description", "path", "bounds", "obstacles", "room")
    )
    name = top["name"]
    if not isinstance(name, str) or not name.strip():
        raise WorldError(f"{source}: name: must be a non-empty string, got {name!r}")
    description = top.get("description", "") or ""
    if not isinstance(description, str):
        raise WorldError(f"{source}: description: must be a string, got {description!r}")

    where = f"{source}: path"
    path_map = _mapping(top["path"], where, ("waypoints",), ("waypoints", "speed_m_s"))
    wps = path_map["waypoints"]
    if not isinstance(wps, (list, tuple)) or len(wps) < 2:
        raise WorldError(f"{where}: 'waypoints' must be a list of at least 2 [x, y, z] points, got {wps!r}")
    waypoints = [_vec3(p, f"{where}.waypoints[{k}]", "waypoint") for k, p in enumerate(wps)]
    speed = _positive(path_map.get("speed_m_s", 1.0), where, "speed_m_s")
    if speed > MAX_SPEED_M_S:
        raise WorldError(f"{where}: 'speed_m_s' must be at most {MAX_SPEED_M_S:g} m/s, got {speed!r}")
    try:
        rough = RoughPath(np.array(waypoints, dtype=np.float64), speed)
    except ValueError as exc:
        raise WorldError(f"{where}: {exc}") from None

    floor = ceiling = None
    if top.get("bounds") is not None:
        where = f"{source}: bounds"
        bounds = _mapping(top["bounds"], where, (), ("floor_z", "ceiling_z"))
        if bounds.get("floor_z") is not None:
            floor = _number(bounds["floor_z"], where, "floor_z")
        if bounds.get("ceiling_z") is not None:
            ceiling = _number(bounds["ceiling_z"], where, "ceiling_z")
        if floor is not None and ceiling is not None and ceiling <= floor:
            raise WorldError(f"{where}: 'ceiling_z' ({ceiling}) must be above 'floor_z' ({floor})")

    raw_obs = top.get("obstacles") or []
    if not isinstance(raw_obs, (list, tuple)):
        raise WorldError(f"{source}: obstacles: must be a list, got {type(raw_obs).__name__}")
    obstacles = tuple(_parse_obstacle(e, f"{source}: obstacles[{i}]") for i, e in enumerate(raw_obs))
    room = _parse_room(top.get("room"), f"{source}: room", floor, ceiling)
    world = World(name=name.strip(), path=rough, description=description.strip(), floor_z_m=floor,
                  ceiling_z_m=ceiling, obstacles=obstacles, room_xy_m=room)
    _check_waypoints_free(world, source)
    return world


def _check_takeoff_clear(world: World, source: str) -> None:
    """Refuse a world whose take-off climb (straight up from the ground below the start to the
    start) passes through or within :data:`WAYPOINT_CLEARANCE_M` of an obstacle."""
    from sim_harness.collision import sweep_collides  # imports this module

    start = world.path.start_m
    ground_z = 0.0 if world.floor_z_m is None else world.floor_z_m
    if start[2] <= ground_z:
        return
    climb = np.array([[start[0], start[1], ground_z], start])[:, None, :]
    no_floor = World(world.name, world.path, ceiling_z_m=world.ceiling_z_m, obstacles=world.obstacles)
    if not sweep_collides(no_floor, climb, WAYPOINT_CLEARANCE_M)[0]:  # the floor is the ground
        return
    for i, ob in enumerate(world.obstacles):
        alone = World(name=world.name, path=world.path, obstacles=(ob,))
        if sweep_collides(alone, climb, WAYPOINT_CLEARANCE_M)[0]:
            raise WorldError(
                f"{source}: path.waypoints[0] {start.tolist()} (the start): the take-off from the ground "
                f"below it (z {ground_z:g}) passes through obstacles[{i}] ({type(ob).__name__.lower()} at "
                f"{list(ob.center_m)})"
            )


def _check_waypoints_free(world: World, source: str) -> None:
    """Refuse a waypoint (start and goal included) below the floor, above the ceiling or inside an
    obstacle, or nearer to any of them than :data:`WAYPOINT_CLEARANCE_M`; the error names the
    file, the waypoint and what it is in."""
    from sim_harness.collision import clearance_m  # imports this module

    r = WAYPOINT_CLEARANCE_M
    wps = world.path.waypoints_m
    role = {0: "the start", len(wps) - 1: "the goal"}
    for k, wp in enumerate(wps):
        where = f"{source}: path.waypoints[{k}] {wp.tolist()} ({role.get(k, 'a waypoint')})"
        if world.floor_z_m is not None and wp[2] < world.floor_z_m + r:
            what = "below the floor" if wp[2] < world.floor_z_m else f"within {r} m of the floor"
            raise WorldError(f"{where}: {what} (bounds.floor_z {world.floor_z_m})")
        if world.ceiling_z_m is not None and wp[2] > world.ceiling_z_m - r:
            what = "above the ceiling" if wp[2] > world.ceiling_z_m else f"within {r} m of the ceiling"
            raise WorldError(f"{where}: {what} (bounds.ceiling_z {world.ceiling_z_m})")
        if world.room_xy_m is not None:
            (x0, x1), (y0, y1) = world.room_xy_m
            if not (x0 + r <= wp[0] <= x1 - r and y0 + r <= wp[1] <= y1 - r):
                raise WorldError(f"{where}: outside the room or within {r} m of its walls "
                                 f"(room.x {[x0, x1]}, room.y {[y0, y1]})")
    if not world.obstacles:
        return
    for k in np.flatnonzero(clearance_m(world, wps) < r):
        wp = wps[k]
        where = f"{source}: path.waypoints[{k}] {wp.tolist()} ({role.get(int(k), 'a waypoint')})"
        for i, ob in enumerate(world.obstacles):
            alone = World(name=world.name, path=world.path, obstacles=(ob,))
            c = float(clearance_m(alone, wp[None])[0])
            if c < r:
                what = "inside" if c < 0 else f"within {r} m of"
                raise WorldError(f"{where}: {what} obstacles[{i}] ({type(ob).__name__.lower()} at "
                                 f"{list(ob.center_m)})")
    _check_takeoff_clear(world, source)


def load_world(path: str | Path) -> World:
    """Read and validate a world YAML file; any problem raises :class:`WorldError`."""
    try:
        data = load_yaml(path)
    except ConfigError as exc:
        raise WorldError(str(exc)) from None
    return parse_world(data, source=str(path))


def world_to_mapping(world: World) -> dict[str, Any]:
    """The inverse of :func:`parse_world`: a plain mapping that can be dumped as a world YAML file."""
    obstacles: list[dict[str, Any]] = []
    for ob in world.obstacles:
        if isinstance(ob, Box):
            obstacles.append({"type": "box", "center": list(ob.center_m), "size": list(ob.size_m),
                              "yaw_deg": ob.yaw_deg})
        elif isinstance(ob, Sphere):
            obstacles.append({"type": "sphere", "center": list(ob.center_m), "radius": ob.radius_m})
        else:
            obstacles.append({"type": "cylinder", "center": list(ob.center_m), "radius": ob.radius_m,
                              "height": ob.height_m, "axis": ob.axis})
    out: dict[str, Any] = {
        "name": world.name,
        "description": world.description,
        "path": {"waypoints": world.path.waypoints_m.tolist(), "speed_m_s": world.path.speed_m_s},
        "obstacles": obstacles,
    }
    pairs = (("floor_z", world.floor_z_m), ("ceiling_z", world.ceiling_z_m))
    bounds = {k: v for k, v in pairs if v is not None}
    if bounds:
        out["bounds"] = bounds
    if world.room_xy_m is not None:
        out["room"] = {"x": list(world.room_xy_m[0]), "y": list(world.room_xy_m[1])}
    return out


# ---------------------------------------------------------------------------------------------- paper worlds


def paper_world_path(i: int) -> Path:
    """File of the paper's environment ``i`` (1..10): ``sim_harness/worlds/envNN-*.yaml``."""
    if isinstance(i, bool) or not isinstance(i, int) or not 1 <= i <= 10:
        raise WorldError(f"paper world id must be an integer 1..10, got {i!r}")
    matches = sorted(WORLDS_DIR.glob(f"env{i:02d}-*.yaml"))
    if len(matches) != 1:
        raise WorldError(f"{WORLDS_DIR}: expected exactly one env{i:02d}-*.yaml, found {len(matches)}")
    return matches[0]


def resolve_world_arg(arg: str) -> Path:
    """A command-line world: a file path, a paper world id (``env04``, ``4``, ``env04-slalom-lr``),
    or a shipped world by name or its start (``lab02``, ``lab02.yaml``, ``lab02-two-boxes.yaml``),
    looked up in sim_harness/worlds/ when no such file exists."""
    p = Path(arg)
    if p.exists():
        return p
    if p.parent == Path(".") and not arg.lower().startswith("env"):
        stem = p.stem if p.suffix in (".yaml", ".yml") else p.name
        shipped = (
            sorted(WORLDS_DIR.glob(f"{stem}.yaml"))
            or sorted(WORLDS_DIR.glob(f"{stem}-*.yaml"))
            or sorted(WORLDS_DIR.glob(f"{stem}*.yaml"))
        )
        if len(shipped) == 1:
            return shipped[0]
        if len(shipped) > 1:
            raise WorldError(f"world {arg!r}: matches {[s.name for s in shipped]} in {WORLDS_DIR}; give one")
    if p.suffix in (".yaml", ".yml"):
        return p
    key = arg.lower().removeprefix("env").split("-", 1)[0]
    if key.isdigit():
        return paper_world_path(int(key))
    raise WorldError(f"world {arg!r}: not a file and not a paper world id (env01..env10)")
