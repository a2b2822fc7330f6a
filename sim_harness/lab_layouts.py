"""Random box layouts in one lab: the room a flight config flies, with new obstacles.

A lab's room, path and flight settings are fixed by the people who fly there (a world file of the
room, ``config/flight.yaml``); what changes from day to day is what stands in it. To train a
planner for that room, :func:`lab_layouts` draws layouts of boxes standing on the floor near the
path, as a lab's crates, tables and screens would, and keeps only those where a route exists that
keeps the depth safety filter's margins (the caller's ``admits``, e.g. :func:`route_admits`): a
layout without one teaches nothing but holding still.

Boxes are placed in path coordinates: ``s`` along the path from its start, ``c`` to its left.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from quadnav_onboard.frames import body_to_world
from sim_harness.world import World, WorldError, parse_world, world_to_mapping

if TYPE_CHECKING:
    from quadnav_onboard.primitives import PrimitiveSet
    from quadnav_onboard.shield import ShieldConfig

__all__ = ["LayoutRanges", "lab_layouts", "random_layout", "route_admits"]


@dataclass(frozen=True)
class LayoutRanges:
    """Where and how big the boxes of a layout are (metres, degrees); drawn uniformly."""

    boxes: tuple[float, float, float] = (0.1, 0.45, 0.45)
    """Probabilities of 0, 1 and 2 boxes."""
    s_margin_m: float = 0.8
    """Box centres keep this far from the path's start and end along it."""
    c_m: tuple[float, float] = (-0.8, 0.8)
    """Offset of a box's centre to the left of the path."""
    depth_m: tuple[float, float] = (0.3, 0.6)
    """Size along the path."""
    width_m: tuple[float, float] = (0.4, 1.2)
    """Size across the path."""
    height_m: tuple[float, float] = (0.8, 2.6)
    """Height above the floor (a box taller than the altitude band cannot be flown over)."""
    yaw_jitter_deg: float = 25.0
    """A box's yaw departs from square to the path by up to this much."""
    min_spacing_m: float = 0.4
    """Least distance along the path between two boxes' faces."""


def _box_along(world: World, s: float, c: float, depth: float, width: float, height: float,
               yaw_off_deg: float) -> dict[str, Any]:
    path = world.path
    p = path.point_at(s)
    yaw = float(path.yaw_at(np.array([s]))[0])
    left = body_to_world(np.array([0.0, 1.0, 0.0]), yaw)  # the heading frame's y axis
    floor = world.floor_z_m if world.floor_z_m is not None else 0.0
    centre = p + c * left
    return {
        "type": "box",
        "center": [float(centre[0]), float(centre[1]), floor + height / 2],
        "size": [depth, width, height],
        "yaw_deg": math.degrees(yaw) + yaw_off_deg,
    }


def random_layout(template: World, rng: np.random.Generator, ranges: LayoutRanges = LayoutRanges(),
                  name: str = "layout") -> World:
    """``template`` (its room, path and obstacles) with 0-2 random boxes added; raises
    :class:`~sim_harness.world.WorldError` when a box covers the path's start or goal."""
    r = ranges
    n = int(rng.choice(3, p=np.asarray(r.boxes) / sum(r.boxes)))
    length = template.path.length_m
    lo, hi = r.s_margin_m, length - r.s_margin_m
    boxes: list[dict[str, Any]] = []
    placed: list[tuple[float, float]] = []  # (s, depth) of the boxes so far
    for _ in range(n):
        depth = float(rng.uniform(*r.depth_m))
        for _ in range(20):  # a place along the path clear of the boxes so far
            s = float(rng.uniform(lo, hi))
            if all(abs(s - s2) >= (depth + d2) / 2 + r.min_spacing_m for s2, d2 in placed):
                break
        else:
            continue
        placed.append((s, depth))
        boxes.append(_box_along(template, s, float(rng.uniform(*r.c_m)), depth,
                                float(rng.uniform(*r.width_m)), float(rng.uniform(*r.height_m)),
                                float(rng.uniform(-r.yaw_jitter_deg, r.yaw_jitter_deg))))
    mapping = world_to_mapping(template)
    mapping["name"] = name
    mapping["description"] = f"{len(boxes)} random boxes in {template.name}"
    mapping["obstacles"] = list(mapping.get("obstacles") or []) + boxes
    return parse_world(mapping, source=f"<layout of {template.name}>")


def lab_layouts(template: World, n: int, seed: int, admits: Callable[[World], bool],
                ranges: LayoutRanges = LayoutRanges(), max_tries: int | None = None) -> list[World]:
    """``n`` random layouts of ``template`` that ``admits`` accepts, reproducible from ``seed``.
    Raises ValueError when ``max_tries`` draws (default 20 n) do not give ``n``."""
    rng = np.random.default_rng(seed)
    out: list[World] = []
    tries = 0
    limit = max_tries if max_tries is not None else 20 * max(n, 1)
    while len(out) < n:
        if tries >= limit:
            raise ValueError(f"{template.name}: only {len(out)} of {n} layouts with a route in {tries} draws")
        tries += 1
        try:
            world = random_layout(template, rng, ranges, name=f"{template.name}-layout{len(out):03d}")
        except WorldError:
            continue
        if admits(world):
            out.append(world)
    return out


def route_admits(
    shield_for: Callable[[World], ShieldConfig], prims: PrimitiveSet, goal_radius_m: float, max_steps: int,
    altitude_m: tuple[float, float] | None, max_deviation_m: float | None,
) -> Callable[[World], bool]:
    """A test that a layout leaves a sequence of primitives from the start to the goal, each
    keeping the margins of the filter ``shield_for(world)`` from the true geometry
    (:func:`sim_harness.route.lattice_route`, as ``quadnav-sim route`` checks a world)."""
    from sim_harness.route import lattice_route

    def admits(world: World) -> bool:
        found = lattice_route(world, prims, shield_for(world), goal_radius_m, max_steps, altitude_m,
                              max_deviation_m)
        return found.steps is not None

    return admits
