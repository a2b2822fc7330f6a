"""World files: the contract, the errors people get for bad files, and the ten paper worlds."""

from __future__ import annotations

from collections import deque
from pathlib import Path

import numpy as np
import pytest
import yaml

from quadnav_onboard.primitives import PrimitiveSet
from sim_harness.collision import clearance_m, sweep_collides
from sim_harness.world import (
    TEST_WORLD_IDS,
    TRAIN_WORLD_IDS,
    Box,
    Cylinder,
    Sphere,
    WorldError,
    load_world,
    paper_world_path,
    parse_world,
    resolve_world_arg,
    world_to_mapping,
)

ISSUE_EXAMPLE = """
name: env04-slalom-lr
description: free text
path:
  waypoints: [[0, 0, 2], [60, 0, 2]]
  speed_m_s: 1.0
bounds: {floor_z: 0.0, ceiling_z: 8.0}
obstacles:
  - {type: box, center: [10, 1.5, 2], size: [1, 3, 4], yaw_deg: 0}
  - {type: sphere, center: [50, 0, 2], radius: 1.2}
  - {type: cylinder, center: [20, -1, 2.5], radius: 0.5, height: 5, axis: z}
"""


_OK = "name: a\npath: {waypoints: [[0,0,2],[9,0,2]]}\n"


def _ob(entry: str) -> str:
    return _OK + "obstacles:\n - " + entry


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "w.yaml"
    p.write_text(text)
    return p


def test_issue_example_loads_with_every_shape(tmp_path: Path) -> None:
    """The example world file loads into the shapes it describes."""
    w = load_world(_write(tmp_path, ISSUE_EXAMPLE))
    assert w.name == "env04-slalom-lr" and w.floor_z_m == 0.0 and w.ceiling_z_m == 8.0
    assert w.obstacles == (Box((10, 1.5, 2), (1, 3, 4), 0.0), Sphere((50, 0, 2), 1.2),
                           Cylinder((20, -1, 2.5), 0.5, 5, "z"))
    assert w.path.length_m == pytest.approx(60.0)


def test_defaults_speed_axis_yaw_and_no_bounds() -> None:
    """Optional keys take their documented defaults; no bounds means no floor or ceiling."""
    w = parse_world({"name": "x", "path": {"waypoints": [[0, 0, 1], [5, 0, 1]]},
                     "obstacles": [{"type": "cylinder", "center": [3, 0, 1], "radius": 1, "height": 2},
                                   {"type": "box", "center": [1, 0, 0], "size": [1, 1, 1]}]})
    assert w.path.speed_m_s == 1.0 and w.floor_z_m is None and w.ceiling_z_m is None
    assert w.obstacles[0].axis == "z" and w.obstacles[1].yaw_deg == 0.0
    assert w.geometry.floor_z_m == -np.inf and w.geometry.ceiling_z_m == np.inf


@pytest.mark.parametrize(
    ("text", "entry", "reason"),
    [
        ("path: {waypoints: [[0,0,2],[9,0,2]]}", "w.yaml", "missing required key 'name'"),
        ("name: a", "w.yaml", "missing required key 'path'"),
        ("name: a\npath: {waypoints: [[0,0,2]]}", "path", "at least 2"),
        ("name: a\npath: {waypoints: [[0,0,2],[9,0,2]], speed_m_s: -1}", "path", "must be positive"),
        (_ob("{type: box, center: [1,2,3], size: [1,1,1]}\n - {type: cone, center: [1,2,3]}"), "obstacles[1]",
         "unknown shape type 'cone'"),
        (_ob("{type: box, center: [1,2,3], size: [1,-3,4]}"),
         "obstacles[0]", "'size' must be 3 positive numbers"),
        (_ob("{type: sphere, center: [1,2,3], radius: -1}"),
         "obstacles[0]", "'radius' must be positive"),
        (_ob("{type: sphere, center: [1,x,3], radius: 1}"),
         "obstacles[0]", "'center' must be a finite number, got 'x'"),
        (_ob("{type: sphere, center: [1,2], radius: 1}"),
         "obstacles[0]", "list of 3 numbers"),
        (_ob("{type: sphere, center: [1,2,3]}"),
         "obstacles[0]", "missing required key 'radius'"),
        (_ob("{type: cylinder, center: [1,2,3], radius: 1, height: 2, axis: w}"), "obstacles[0]",
         "'axis' must be one of"),
        (_ob("{type: box, center: [1,2,3], size: [1,1,1], colr: 3}"),
         "obstacles[0]", "unknown key(s) ['colr']"),
        (_OK + "bounds: {floor_z: 3, ceiling_z: 1}", "bounds", "must be above"),
        ("name: a\npath: {waypoints: [[0,0,2],[0,0,2]]}", "path", "distinct"),
        (_ob("{type: sphere, center: [1,2,3], radius: true}"),
         "obstacles[0]", "finite number"),
    ],
)
def test_bad_world_file_names_file_entry_and_reason(
    tmp_path: Path, text: str, entry: str, reason: str
) -> None:
    """Each class of mistake raises WorldError whose message has the file, the entry and the reason."""
    p = _write(tmp_path, text)
    with pytest.raises(WorldError) as exc:
        load_world(p)
    msg = str(exc.value)
    assert str(p) in msg and entry in msg and reason in msg, msg


def test_missing_file_and_malformed_yaml_are_world_errors(tmp_path: Path) -> None:
    """Unreadable or unparsable files are WorldErrors naming the file, not tracebacks."""
    with pytest.raises(WorldError, match=r"nope\.yaml"):
        load_world(tmp_path / "nope.yaml")
    with pytest.raises(WorldError, match=r"malformed YAML"):
        load_world(_write(tmp_path, "name: [unclosed"))


def test_round_trip_through_mapping() -> None:
    """world_to_mapping gives a mapping that parses back into an equal world."""
    w = load_world(paper_world_path(8))
    back = parse_world(yaml.safe_load(yaml.safe_dump(world_to_mapping(w))), "rt")
    assert back.obstacles == w.obstacles and back.name == w.name and back.ceiling_z_m == w.ceiling_z_m
    np.testing.assert_array_equal(back.path.waypoints_m, w.path.waypoints_m)
    np.testing.assert_array_equal(back.geometry.half_m, w.geometry.half_m)


def test_worlds_key_dicts_and_are_found_in_lists() -> None:
    """A World is hashable and compares by identity, so `in`, `.index` and dict keys work."""
    a, b = load_world(paper_world_path(2)), load_world(paper_world_path(2))
    assert {a: 1, b: 2}[b] == 2 and [a, b].index(b) == 1 and a in [a] and a != b


def test_resolve_world_arg_accepts_ids_and_paths(tmp_path: Path) -> None:
    """`env04`, `4` and a file path all resolve; junk is a WorldError."""
    assert resolve_world_arg("env04") == paper_world_path(4) == resolve_world_arg("4")
    assert resolve_world_arg(str(tmp_path / "x.yaml")) == tmp_path / "x.yaml"
    with pytest.raises(WorldError):
        resolve_world_arg("env11")
    with pytest.raises(WorldError):
        resolve_world_arg("forest")


# ---------------------------------------------------------------------------------------- paper worlds

ALL_IDS = TRAIN_WORLD_IDS + TEST_WORLD_IDS


def test_train_and_test_ids_partition_the_ten_worlds() -> None:
    assert sorted(ALL_IDS) == list(range(1, 11)) and TEST_WORLD_IDS == (8, 9, 10)


@pytest.mark.parametrize("i", ALL_IDS)
def test_paper_world_is_a_60m_straight_path_at_2m(i: int) -> None:
    """Every paper world loads: 60 m straight at 1 m/s, z = 2 m, floor 0, ceiling 6-8 m."""
    w = load_world(paper_world_path(i))
    assert w.name.startswith(f"env{i:02d}-")
    np.testing.assert_allclose(w.path.waypoints_m, [[0, 0, 2], [60, 0, 2]])
    assert w.path.speed_m_s == 1.0 and w.floor_z_m == 0.0 and 6.0 <= w.ceiling_z_m <= 8.0
    assert (len(w.obstacles) == 0) == (i == 1)


def _reachable(world, clearance_needed_m: float, step_m: float = 0.25, max_dev_m: float = 4.5) -> bool:
    """Whether a sphere-safe tube connects the start to within 1 m of the goal (6-connected grid)."""
    xs = np.arange(-0.5, 60.5 + 1e-9, step_m)
    ys = np.arange(-5.0, 5.0 + 1e-9, step_m)
    zs = np.arange(0.0, world.ceiling_z_m + 1e-9, step_m)
    x, y, z = np.meshgrid(xs, ys, zs, indexing="ij")
    free = clearance_m(world, np.stack([x, y, z], -1).reshape(-1, 3)).reshape(x.shape) >= clearance_needed_m
    free &= np.hypot(y, z - 2.0) <= max_dev_m
    reach = free & (np.hypot(np.hypot(x, y), z - 2.0) <= 0.3)
    assert reach.any()
    while True:
        grown = reach.copy()
        for ax in range(3):
            lo = [slice(None)] * 3
            hi = [slice(None)] * 3
            lo[ax], hi[ax] = slice(1, None), slice(None, -1)
            grown[tuple(lo)] |= reach[tuple(hi)]
            grown[tuple(hi)] |= reach[tuple(lo)]
        grown &= free
        if grown.sum() == reach.sum():
            break
        reach = grown
    return bool((reach & (np.hypot(np.hypot(x - 60.0, y), z - 2.0) <= 1.0)).any())


@pytest.mark.parametrize("i", ALL_IDS)
def test_paper_world_is_solvable_by_a_0p3m_quad_with_margin(i: int) -> None:
    """A 0.3 m quad with 0.3 m to spare can get from start to goal within 4.5 m of the path."""
    assert _reachable(load_world(paper_world_path(i)), clearance_needed_m=0.6)


def _lattice_steps(world, offset_m, clearance_needed_m: float, max_dev_m: float = 4.5) -> int | None:
    """Fewest primitives (the 18 actions' 1 m end points, chords swept) from start + offset to within
    1 m of the goal, keeping ``clearance_needed_m`` and within ``max_dev_m`` of the path; None if none."""
    moves = np.array([d for d in PrimitiveSet().directions if any(d)], dtype=np.int64)
    start = world.path.start_m + np.asarray(offset_m)
    ys = np.arange(-5, 6)
    zs = np.arange(-int(start[2] - world.floor_z_m), int(world.ceiling_z_m - start[2]) + 1)
    grid = np.stack(np.meshgrid(np.arange(66), ys, zs, indexing="ij"), -1)  # (nx, ny, nz, 3) steps
    shape = grid.shape[:3]
    pos = (start + grid).reshape(-1, 3)
    free = (clearance_m(world, pos) >= clearance_needed_m) & (world.path.deviation_m(pos) <= max_dev_m)
    idx = (grid - [0, ys[0], zs[0]]).reshape(-1, 3)
    edges = np.zeros((len(pos), len(moves)), dtype=bool)
    for a, d in enumerate(moves):
        dst = idx + d
        cand = free & (dst >= 0).all(1) & (dst < shape).all(1)
        cand[cand] &= free[np.ravel_multi_index(tuple(dst[cand].T), shape)]
        sel = np.flatnonzero(cand)
        edges[sel, a] = ~sweep_collides(world, np.stack([pos[sel], pos[sel] + d]), clearance_needed_m)
    goal = np.linalg.norm(pos - world.path.goal_m, axis=1) <= 1.0
    s0 = int(np.ravel_multi_index((0, -ys[0], -zs[0]), shape))
    dist = {s0: 0}
    queue = deque([s0] if free[s0] else [])
    while queue:
        u = queue.popleft()
        if goal[u]:
            return dist[u]
        for a in np.flatnonzero(edges[u]):
            v = int(np.ravel_multi_index(tuple(idx[u] + moves[a]), shape))
            if v not in dist:
                dist[v] = dist[u] + 1
                queue.append(v)
    return None


@pytest.mark.parametrize("i", ALL_IDS)
def test_paper_world_is_solvable_with_the_action_lattice(i: int) -> None:
    """From the start and from jittered starts (±0.5 m in y and z), the 18 primitives' 1 m moves
    reach the goal in ~60 steps (limit 120) keeping a 0.3 m quad 0.15 m clear of everything."""
    w = load_world(paper_world_path(i))
    for offset in ((0, 0, 0), (0, 0.5, 0.5), (0, -0.5, -0.5)):
        steps = _lattice_steps(w, offset, clearance_needed_m=0.45)
        assert steps is not None and steps <= 62, (offset, steps)


@pytest.mark.parametrize("i", ALL_IDS)
def test_first_4m_are_free_for_start_jitter(i: int) -> None:
    """Any start within 0.5 m of the path's first 4 m leaves a 0.3 m quad clear of everything."""
    g = np.stack(np.meshgrid(np.linspace(0, 4, 17), np.linspace(-0.5, 0.5, 5), np.linspace(1.5, 2.5, 5),
                             indexing="ij"), -1).reshape(-1, 3)
    assert clearance_m(load_world(paper_world_path(i)), g).min() > 0.35


def test_corridor_widths_and_env8_sphere() -> None:
    """Env 3 is a 1.6-2 m corridor, Env 2 a wide one; Env 8 ends in a corridor a sphere nearly blocks."""
    def inner_width(i: int, x: float) -> float:
        w = load_world(paper_world_path(i))
        ys = np.linspace(-6, 6, 2401)
        pts = np.stack([np.full_like(ys, x), ys, np.full_like(ys, 2.0)], -1)
        free = clearance_m(w, pts) > 0
        mid = len(ys) // 2  # y = 0: the free run around the path
        lo = mid - np.argmin(free[mid::-1]) if not free[mid::-1].all() else 0
        hi = mid + np.argmin(free[mid:]) if not free[mid:].all() else len(ys)
        return float(ys[hi - 1] - ys[lo + 1]) if (lo, hi) != (0, len(ys)) else np.inf

    assert 1.6 <= inner_width(3, 30.0) <= 2.05
    assert inner_width(2, 30.0) >= 5.0
    w8 = load_world(paper_world_path(8))
    spheres = [o for o in w8.obstacles if isinstance(o, Sphere) and o.center_m[0] > 45]
    assert len(spheres) == 1
    corridor = inner_width(8, 48.0)
    assert corridor <= 3.5 and 2 * spheres[0].radius_m >= 0.8 * corridor


_BOUNDED = "name: a\npath: {waypoints: [[0,0,2],[5,0,2],[9,0,2]]}\nbounds: {floor_z: 0.0, ceiling_z: 4.0}\n"


@pytest.mark.parametrize(
    ("text", "needles"),
    [
        (_BOUNDED + "obstacles:\n - {type: box, center: [0, 0, 2], size: [2, 2, 2]}\n",
         ["path.waypoints[0] [0.0, 0.0, 2.0] (the start)", "inside obstacles[0] (box at [0.0, 0.0, 2.0])"]),
        (_BOUNDED + "obstacles:\n - {type: box, center: [0, 5, 2], size: [1, 1, 1]}\n"
         " - {type: sphere, center: [9, 0, 2.5], radius: 1}\n",
         ["path.waypoints[2] [9.0, 0.0, 2.0] (the goal)", "inside obstacles[1] (sphere"]),
        (_BOUNDED + "obstacles:\n - {type: cylinder, center: [5, 0.4, 2], radius: 0.2, height: 3}\n",
         ["path.waypoints[1] [5.0, 0.0, 2.0] (a waypoint)", "within 0.3 m of obstacles[0] (cylinder"]),
        ("name: a\npath: {waypoints: [[0,0,2],[5,0,9],[9,0,2]]}\nbounds: {floor_z: 0.0, ceiling_z: 8.0}\n",
         ["path.waypoints[1] [5.0, 0.0, 9.0]", "above the ceiling (bounds.ceiling_z 8.0)"]),
        ("name: a\npath: {waypoints: [[0,0,-1],[9,0,2]]}\nbounds: {floor_z: 0.0}\n",
         ["path.waypoints[0] [0.0, 0.0, -1.0] (the start)", "below the floor (bounds.floor_z 0.0)"]),
        ("name: a\npath: {waypoints: [[0,0,2],[9,0,0.1]]}\nbounds: {floor_z: 0.0}\n",
         ["path.waypoints[1] [9.0, 0.0, 0.1] (the goal)", "within 0.3 m of the floor"]),
        (_BOUNDED + "obstacles:\n - {type: box, center: [0, 0, 0.5], size: [1, 1, 1]}\n",
         ["path.waypoints[0] [0.0, 0.0, 2.0] (the start)", "the take-off from the ground below it (z 0)",
          "passes through obstacles[0] (box at [0.0, 0.0, 0.5])"]),
    ],
)
def test_a_path_through_solids_or_out_of_bounds_is_refused_at_load(
    tmp_path: Path, text: str, needles: list[str]
) -> None:
    """A start inside an obstacle would crash on take-off (and count as the policy's crash in eval),
    a waypoint above the ceiling or below the floor could never be flown: such a world is refused
    when it is loaded, naming the file, the waypoint and what it is in."""
    path = _write(tmp_path, text)
    with pytest.raises(WorldError) as info:
        load_world(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: ")
    for needle in needles:
        assert needle in msg


def test_segments_may_cross_obstacles_and_waypoints_may_pass_close_by(tmp_path: Path) -> None:
    """The rough path may run through an obstacle between waypoints (the planner flies round it),
    and a waypoint just beyond the quad's radius from a solid is fine."""
    text = _BOUNDED + "obstacles:\n - {type: box, center: [3, 0, 2], size: [1, 4, 4]}\n" \
        " - {type: sphere, center: [5, 0.81, 2], radius: 0.5}\n"
    assert len(load_world(_write(tmp_path, text)).obstacles) == 2


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("name: a\npath: {waypoints: [[0,0,2],[1.0e+12,0,2]]}\n",
         "'waypoint' must be within ±10000, got 1000000000000.0"),
        ("name: a\npath: {waypoints: [[0,0,2],[9,0,2]], speed_m_s: 100}\n",
         "'speed_m_s' must be at most 5 m/s"),
        (_ob("{type: sphere, center: [4, 0, 2], radius: 1.0e+9}"), "'radius' must be within ±10000"),
        (_ob("{type: box, center: [4, 5, 2], size: [1, 1, 1], yaw_deg: 1.0e+6}"),
         "'yaw_deg' must be within ±360"),
    ],
)
def test_absurd_world_numbers_are_refused(tmp_path: Path, text: str, needle: str) -> None:
    with pytest.raises(WorldError) as info:
        load_world(_write(tmp_path, text))
    assert needle in str(info.value) and "w.yaml" in str(info.value)
