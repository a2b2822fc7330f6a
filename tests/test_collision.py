"""Collision: exact clearances to each shape, and continuous checks along trails (no tunnelling)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadnav_onboard.path import RoughPath
from sim_harness.collision import clearance_m, collides, sweep_collides
from sim_harness.world import Box, Cylinder, Sphere, World, load_world, paper_world_path

PATH = RoughPath.straight([0, 0, 2], [60, 0, 2])


def _world(*obstacles, floor=None, ceiling=None) -> World:
    return World(name="t", path=PATH, floor_z_m=floor, ceiling_z_m=ceiling, obstacles=obstacles)


def test_clearance_closed_forms_for_each_shape() -> None:
    """Distances to a sphere, a yawed box (edge and corner), and cylinders on x/y/z match hand results."""
    assert clearance_m(_world(Sphere((5, 0, 2), 1.0)), [0, 0, 2]) == pytest.approx(4.0)
    box = _world(Box((6, 0, 2), (1, 1, 4), yaw_deg=45))
    assert clearance_m(box, [0, 0, 2]) == pytest.approx(6 - math.sqrt(0.5))
    assert clearance_m(box, [6, 0, 5]) == pytest.approx(1.0)  # above the top face
    assert clearance_m(box, [6, 0, 2]) == pytest.approx(-0.5)  # centre: half the size inside
    cz = _world(Cylinder((5, 0, 2), 0.5, 2.0, "z"))
    assert clearance_m(cz, [5, 3, 2]) == pytest.approx(2.5)
    assert clearance_m(cz, [5, 3, 6]) == pytest.approx(math.hypot(2.5, 3.0))  # to the rim of the top cap
    cx = _world(Cylinder((5, 0, 2), 0.5, 2.0, "x"))
    assert clearance_m(cx, [0, 0, 2]) == pytest.approx(4.0)  # to the cap
    assert clearance_m(cx, [5, 0, 4]) == pytest.approx(1.5)  # to the side
    cy = _world(Cylinder((5, 0, 2), 0.5, 2.0, "y"))
    assert clearance_m(cy, [5, 3, 2]) == pytest.approx(2.0)  # to the cap at y = 1
    assert clearance_m(cy, [0, 0, 2]) == pytest.approx(4.5)


def test_floor_and_ceiling_count() -> None:
    """Below 0.3 m of the floor or the ceiling a 0.3 m sphere collides."""
    w = _world(floor=0.0, ceiling=5.0)
    got = collides(w, [[0, 0, 0.25], [0, 0, 0.35], [0, 0, 4.8], [0, 0, 2.5], [0, 0, -1.0]], 0.3)
    np.testing.assert_array_equal(got, [True, False, True, False, True])


def test_thin_wall_cannot_be_tunnelled() -> None:
    """A 0.1 m wall between two trail points 3 m apart: both ends are clear, the sweep collides."""
    w = _world(Box((10, 0, 2), (0.1, 6, 6)))
    trail = np.array([[[8.5, 0, 2]], [[11.5, 0, 2]]])
    assert not collides(w, trail[:, 0], 0.3).any()
    assert sweep_collides(w, trail, 0.3)[0]


def test_grazing_pass_detected_and_near_miss_not() -> None:
    """Passing 0.25 m from a wall collides for a 0.3 m quad; passing 0.35 m does not."""
    w = _world(Box((10, 2, 2), (4, 1, 6)))  # face at y = 1.5
    graze = np.array([[[5, 1.25, 2]], [[15, 1.25, 2]]])
    miss = np.array([[[5, 1.15, 2]], [[15, 1.15, 2]]])
    assert sweep_collides(w, graze, 0.3)[0] and not sweep_collides(w, miss, 0.3)[0]


def test_sweep_agrees_with_dense_sampling_over_random_trails() -> None:
    """Vectorised over N trails in a paper world, the sweep equals a 1 mm-step point check."""
    w = load_world(paper_world_path(10))
    rng = np.random.default_rng(0)
    n = 300
    start = np.stack([rng.uniform(0, 58, n), rng.uniform(-2, 2, n), rng.uniform(0.5, 4, n)], -1)
    trail = np.stack([start, start + rng.normal(0, 0.6, (n, 3)), start + rng.normal(0, 1.2, (n, 3))])
    got = sweep_collides(w, trail, 0.3)
    u = np.linspace(0, 1, 1001)[:, None, None]
    dense = np.concatenate([trail[0] + u * (trail[1] - trail[0]), trail[1] + u * (trail[2] - trail[1])])
    want = collides(w, dense.reshape(-1, 3), 0.3).reshape(dense.shape[:2]).any(axis=0)
    # the sweep may miss only contacts shallower than its 1 cm tolerance
    depth = 0.3 - clearance_m(w, dense.reshape(-1, 3)).reshape(dense.shape[:2]).min(axis=0)
    assert 0.1 < want.mean() < 0.9
    assert (got == want)[depth > 0.01].all() and (~got | want).all()


def test_sweep_shape_errors() -> None:
    with pytest.raises(ValueError, match=r"\(K>=1, N, 3\)"):
        sweep_collides(_world(), np.zeros((4, 3)), 0.3)
