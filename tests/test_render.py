"""Ray casting: hit depths against closed forms, z-depth semantics, image orientation, bounds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadnav_onboard.frames import quat_from_yaw, rotmat_yaw
from quadnav_onboard.path import RoughPath
from sim_harness.collision import clearance_m
from sim_harness.render import (
    CameraModel,
    D435_424x240,
    cast_depth_m,
    render_depth_m,
    render_frame_mm,
    render_inputs,
    render_network_inputs,
)
from sim_harness.world import Box, Cylinder, Sphere, World, load_world, paper_world_path

# 5x5 pixels, 90 deg x 90 deg: slopes ty = tz = (0.8, 0.4, 0, -0.4, -0.8); pixel (2, 2) is the optical axis.
CAM5 = CameraModel(5, 5, hfov_deg=90.0, vfov_deg=90.0, min_range_m=0.1, max_range_m=50.0)
SLOPES = np.array([0.8, 0.4, 0.0, -0.4, -0.8])
PATH = RoughPath.straight([0, 0, 2], [60, 0, 2])


def _world(*obstacles, floor=None, ceiling=None) -> World:
    return World(name="t", path=PATH, floor_z_m=floor, ceiling_z_m=ceiling, obstacles=obstacles)


def _depth(world: World, pos=(0.0, 0.0, 2.0), yaw=0.0, cam=CAM5) -> np.ndarray:
    return render_depth_m(world, [pos], [yaw], cam)[0]


def test_camera_slopes_put_row0_up_and_col0_left() -> None:
    """Row 0 looks up (+z), column 0 looks left (+y), the centre pixel looks along +x."""
    ty, tz = CAM5.ray_slopes()
    np.testing.assert_allclose(ty, SLOPES, atol=1e-12)
    np.testing.assert_allclose(tz, SLOPES, atol=1e-12)


def test_sphere_hit_depth_matches_closed_form() -> None:
    """Sphere at 5 m, radius 2.5: axis depth 2.5; off-axis, |o + t d - c| = r's near root."""
    d = _depth(_world(Sphere((5.0, 0.0, 2.0), 2.5)))
    assert d[2, 2] == pytest.approx(2.5, abs=1e-5)
    # pixel (2, 1): direction (1, 0.4, 0): (1 + 0.16) t^2 - 10 t + (25 - 6.25) = 0
    a, b, c = 1.16, -10.0, 18.75
    assert d[2, 1] == pytest.approx((-b - math.sqrt(b * b - 4 * a * c)) / (2 * a), abs=1e-5)
    assert d[0, 0] == 0.0  # misses: no floor, no ceiling -> no return


def test_box_face_gives_the_same_z_depth_across_pixels() -> None:
    """A wall facing the camera reads its distance in every pixel: z-depth, not ray length."""
    d = _depth(_world(Box((6.5, 0.0, 2.0), (1.0, 20.0, 20.0))))
    np.testing.assert_allclose(d, 6.0, atol=1e-5)


def test_yawed_box_hits_its_edge() -> None:
    """A unit box yawed 45 deg presents an edge: the axis ray hits at 6 - sqrt(2)/2."""
    d = _depth(_world(Box((6.0, 0.0, 2.0), (1.0, 1.0, 4.0), yaw_deg=45.0)))
    assert d[2, 2] == pytest.approx(6.0 - math.sqrt(0.5), abs=1e-5)
    # from (4.5, 0, 2) the ray (1, 0.4) meets the left front face x - y = 6 - sqrt(0.5), at y < sqrt(0.5)
    c = 6.0 - math.sqrt(0.5)
    t = (c - 4.5) / 0.6
    assert 0.4 * t < math.sqrt(0.5)
    assert _depth(_world(Box((6.0, 0.0, 2.0), (1.0, 1.0, 4.0), yaw_deg=45.0)), pos=(4.5, 0.0, 2.0))[2, 1] == (
        pytest.approx(t, abs=1e-5))


@pytest.mark.parametrize(("axis", "expect_axis"), [("z", 4.5), ("y", 4.5), ("x", 4.0)])
def test_cylinder_on_each_axis(axis: str, expect_axis: float) -> None:
    """A cylinder (radius 0.5, centre (5, 0, 2)) on x, y or z: axis-ray depth from its side or its cap."""
    length = 4.0 if axis == "y" else 2.0
    d = _depth(_world(Cylinder((5.0, 0.0, 2.0), 0.5, length, axis)))
    assert d[2, 2] == pytest.approx(expect_axis, abs=1e-5)
    if axis == "z":
        # ray (1, 0.4): (t - 5)^2 + (0.4 t)^2 = 0.25 -> 1.16 t^2 - 10 t + 24.75 = 0, near root
        a, b, c = 1.16, -10.0, 24.75
        disc = b * b - 4 * a * c
        assert disc < 0 and d[2, 1] == 0.0  # passes beside it
    if axis == "y":
        assert d[2, 1] == pytest.approx(4.5, abs=1e-5)  # same side line, y = 1.8 <= 2
    if axis == "x":
        assert d[2, 1] == 0.0  # at x = 4 the ray is at y = 1.6, outside the 0.5 cap


def test_cylinder_x_cap_and_side() -> None:
    """An x-axis cylinder (x 4..6, radius 0.5): the axis ray hits the cap at 4; from y = 1.5 the ray
    with slope -0.2 is outside the cap disc at x = 4 (y = 0.7) and enters the side at y = 0.5, t = 5."""
    w = _world(Cylinder((5.0, 0.0, 2.0), 0.5, 2.0, "x"))
    cam = CameraModel(3, 1, hfov_deg=2 * math.degrees(math.atan(0.3)), vfov_deg=1.0, min_range_m=0.1)
    np.testing.assert_allclose(cam.ray_slopes()[0], [0.2, 0.0, -0.2], atol=1e-12)
    on_axis = render_depth_m(w, [(0.0, 0.0, 2.0)], [0.0], cam)[0, 0]
    assert on_axis[1] == pytest.approx(4.0, abs=1e-5)
    beside = render_depth_m(w, [(0.0, 1.5, 2.0)], [0.0], cam)[0, 0]
    assert beside[2] == pytest.approx(5.0, abs=1e-5) and beside[1] == 0.0 and beside[0] == 0.0


def test_floor_and_ceiling_depths() -> None:
    """Level camera at 2 m, ceiling at 6 m: row 0 sees the ceiling at 4/0.8, the last row the floor
    at 2/0.8."""
    d = _depth(_world(floor=0.0, ceiling=6.0))
    np.testing.assert_allclose(d[0], 4.0 / 0.8, atol=1e-5)
    np.testing.assert_allclose(d[1], 4.0 / 0.4, atol=1e-5)
    np.testing.assert_allclose(d[3], 2.0 / 0.4, atol=1e-5)
    np.testing.assert_allclose(d[4], 2.0 / 0.8, atol=1e-5)
    np.testing.assert_array_equal(d[2], 0.0)  # level rays never meet either plane


def test_range_limits_read_zero() -> None:
    """Hits nearer than min range or farther than max range read 0 (no return), like a D435."""
    cam = CameraModel(5, 5, 90.0, 90.0, min_range_m=0.5, max_range_m=5.0)
    assert _depth(_world(Box((0.7, 0, 2), (0.2, 9, 9))), cam=cam)[2, 2] == pytest.approx(0.6, abs=1e-5)
    assert _depth(_world(Box((0.4, 0, 2), (0.2, 9, 9))), cam=cam)[2, 2] == 0.0
    assert _depth(_world(Box((6.0, 0, 2), (1.0, 9, 9))), cam=cam)[2, 2] == 0.0
    assert _depth(_world(Box((4.0, 0, 2), (1.0, 9, 9))), cam=cam)[2, 2] == pytest.approx(3.5, abs=1e-5)


def test_nearest_surface_wins_and_yaw_turns_the_view() -> None:
    """Behind a near box, a far sphere is hidden; turning 180 deg shows what is behind."""
    w = _world(Box((3.0, 0, 2), (1, 2, 2)), Sphere((6.0, 0, 2), 1.0), Sphere((-8.0, 0, 2), 1.0))
    assert _depth(w)[2, 2] == pytest.approx(2.5, abs=1e-5)
    assert _depth(w, yaw=math.pi)[2, 2] == pytest.approx(7.0, abs=1e-5)


def test_hit_points_lie_on_surfaces_in_a_paper_world() -> None:
    """Every returned depth, turned back into a point, lies on a surface (collision SDF ~ 0)."""
    w = load_world(paper_world_path(10))
    rng = np.random.default_rng(3)
    pos = np.stack([rng.uniform(0, 55, 32), rng.uniform(-1, 1, 32), rng.uniform(1, 3, 32)], -1)
    yaw = rng.uniform(-1.0, 1.0, 32)
    free = clearance_m(w, pos) > 0.3  # where a quad can be
    pos, yaw = pos[free], yaw[free]
    cam = CameraModel(48, 32)
    t = cast_depth_m(w.geometry, pos, rotmat_yaw(yaw), cam)
    ty, tz = cam.ray_slopes()
    dirs_body = np.stack(np.broadcast_arrays(1.0, ty[None, :], tz[:, None]), -1)  # (H, W, 3)
    dirs_world = np.einsum("nab,hwb->nhwa", rotmat_yaw(yaw), dirs_body)
    hit = np.isfinite(t) & (t > 0)
    pts = pos[:, None, None, :] + t[..., None] * dirs_world
    sdf = clearance_m(w, pts[hit])
    assert hit.mean() > 0.5 and np.abs(sdf).max() < 1e-6
    # and halfway to each hit there is free space
    assert (clearance_m(w, (pos[:, None, None, :] + 0.5 * t[..., None] * dirs_world)[hit]) > 0).all()


def test_wall_across_the_path_reads_nearer_than_the_wall_in_the_centre() -> None:
    """With a wall across the path 8 m ahead, the centre pixels read less than 8 m (and about 7.5)."""
    w = _world(Box((8.0, 0.0, 3.0), (1.0, 12.0, 6.0)), floor=0.0, ceiling=6.0)
    d = render_depth_m(w, [(0.0, 0.0, 2.0)], [0.0], D435_424x240)[0]
    centre = d[110:130, 200:224]
    assert (centre > 0).all() and (centre < 8.0).all()
    np.testing.assert_allclose(centre, 7.5, atol=1e-4)
    net = render_network_inputs(w, [(0.0, 0.0, 2.0)], [0.0])[0]
    assert net[14:18, 14:18].max() == pytest.approx(0.75, abs=1e-4)


def test_full_frame_mm_with_pitch_looks_at_the_floor() -> None:
    """Pitched 90 deg nose-down at 2 m, the centre of a uint16 frame reads 2000 mm of floor."""
    w = _world(floor=0.0, ceiling=6.0)
    q_down = np.array([math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0])  # +90 deg about body y
    frame = render_frame_mm(w, np.array([0.0, 0.0, 2.0]), q_down, D435_424x240)
    assert frame.dtype == np.uint16 and frame.shape == (240, 424)
    assert abs(int(frame[120, 212]) - 2000) <= 5
    level = render_frame_mm(w, np.array([0.0, 0.0, 2.0]), quat_from_yaw(0.3), D435_424x240)
    assert level[0].min() > 0 and level[-1].min() > 0 and level[120].max() == 0


def test_batched_render_equals_one_by_one_and_is_float32() -> None:
    """Rendering N poses at once gives exactly what N single renders give."""
    w = load_world(paper_world_path(5))
    pos = np.array([[1.0, 0.0, 2.0], [10.0, -1.0, 2.5], [30.0, 1.0, 1.5]])
    yaw = np.array([0.0, 0.4, -0.3])
    cam = CameraModel(64, 48)
    batch = render_depth_m(w, pos, yaw, cam)
    assert batch.dtype == np.float32 and batch.shape == (3, 48, 64)
    for k in range(3):
        np.testing.assert_array_equal(batch[k], render_depth_m(w, pos[k:k + 1], yaw[k:k + 1], cam)[0])


def test_inside_an_obstacle_reads_nothing_valid() -> None:
    """A camera inside a solid sees no valid depth (the quad has crashed)."""
    d = _depth(_world(Sphere((0.0, 0.0, 2.0), 1.0)))
    np.testing.assert_array_equal(d, 0.0)


def test_the_shields_view_keeps_a_thin_pole_the_network_input_blends() -> None:
    """A pole 18 cm thick 5 m ahead of a wall at 8 m, thinner than a cell (30 cm there): the
    area-averaged input blends it with the wall; the nearest-surface view (same rays) reads its
    ~4.95 m, and is nowhere farther than the input."""
    w = _world(Box((8.5, 0.0, 3.0), (1.0, 12.0, 6.0)), Cylinder((5.0, 0.0, 3.0), 0.09, 6.0),
               floor=0.0, ceiling=6.0)
    mean, near, _ = render_inputs(w, [(0.0, 0.0, 2.0)], [0.0], nearest=True)
    assert render_inputs(w, [(0.0, 0.0, 2.0)], [0.0]).near is None
    np.testing.assert_array_equal(mean, render_network_inputs(w, [(0.0, 0.0, 2.0)], [0.0]))
    assert near.shape == mean.shape == (1, 32, 32) and near.dtype == np.float32
    assert np.all(near <= mean + 1e-7)
    assert mean[0, 10:20].min() > 0.55  # blended with the wall behind
    assert near[0, 10:20].min() == pytest.approx(0.495, abs=0.005)  # z-depth 4.95 m, /10 m
