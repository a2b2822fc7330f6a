"""Procedural training worlds: valid, seeded, of every family, with room to fly."""

import numpy as np
import pytest

from sim_harness.collision import clearance_m
from sim_harness.procgen import FAMILIES, MIN_GAP_M, procedural_worlds, random_world


def test_seeded_and_cycling_through_the_families():
    a, b = procedural_worlds(8, seed=5), procedural_worlds(8, seed=5)
    assert [w.name for w in a] == [w.name for w in b]
    assert [len(w.obstacles) for w in a] == [len(w.obstacles) for w in b]
    assert {w.name.split("-", 1)[1] for w in a} == set(FAMILIES)
    assert [len(w.obstacles) for w in procedural_worlds(8, seed=6)] != [len(w.obstacles) for w in a]


@pytest.mark.parametrize("family", FAMILIES)
def test_every_family_leaves_the_start_free_and_has_obstacles(family):
    rng = np.random.default_rng(0)
    for _ in range(10):
        w = random_world(rng, family)
        assert len(w.obstacles) > 0 and w.path.length_m == pytest.approx(60.0)
        start = np.stack([np.linspace(0.0, 4.0, 9), np.zeros(9), np.full(9, 2.0)], axis=1)
        assert (clearance_m(w, start) > 0.6).all()


def test_clutter_keeps_the_minimum_gap_between_obstacles():
    """Footprints of clutter obstacles are at least MIN_GAP_M apart, so a passage always exists."""
    rng = np.random.default_rng(1)
    w = random_world(rng, "clutter")
    foot = []
    for ob in w.obstacles:
        c = np.asarray(ob.center_m)
        r = getattr(ob, "radius_m", None)
        if r is None:  # a crate: half its diagonal
            r = float(np.hypot(ob.size_m[0], ob.size_m[1]) / 2)
        foot.append((c[0], c[1], r))
    for i, (x1, y1, r1) in enumerate(foot):
        for x2, y2, r2 in foot[i + 1 :]:
            assert np.hypot(x1 - x2, y1 - y2) - r1 - r2 >= MIN_GAP_M - 1e-6


def test_up_down_slaloms_leave_the_minimum_gap_below_or_above_each_obstacle():
    """Every panel or pipe leaves MIN_GAP_M between it and the floor or the ceiling: the quad can
    always pass under or over it."""
    rng = np.random.default_rng(2)
    for _ in range(40):
        w = random_world(rng, "slalom_ud")
        for ob in w.obstacles:
            half = ob.radius_m if hasattr(ob, "radius_m") else ob.size_m[2] / 2
            lo, hi = ob.center_m[2] - half, ob.center_m[2] + half
            assert max(lo - w.floor_z_m, w.ceiling_z_m - hi) >= MIN_GAP_M - 1e-6, (w.name, ob)


def test_unknown_family_is_an_error():
    with pytest.raises(ValueError, match="unknown world family"):
        random_world(np.random.default_rng(0), "maze")


def test_families_can_be_weighted_by_naming_them_again():
    worlds = procedural_worlds(8, seed=5, families=("corridor", "slalom_ud", "slalom_ud"))
    kinds = [w.name.split("-", 1)[1] for w in worlds]
    assert kinds == ["corridor", "slalom_ud", "slalom_ud"] * 2 + ["corridor", "slalom_ud"]
    with pytest.raises(ValueError, match="unknown world family 'forest'"):
        procedural_worlds(2, seed=5, families=("corridor", "forest"))
