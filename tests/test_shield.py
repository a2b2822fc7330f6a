"""The depth safety filter: back-projection, memory, predicted paths and the allowed set."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadnav_onboard.frames import pixel_slopes
from quadnav_onboard.preprocess import preprocess_depth_pair
from quadnav_onboard.primitives import DEFAULT_DIRECTIONS, PrimitiveSet
from quadnav_onboard.shield import (
    PointMemory,
    ShieldConfig,
    allowed_actions,
    depth_points_heading,
    points_per_view,
    primitive_clearance,
    primitive_samples,
    shield_at_scale,
    shield_config_from_meta,
    view_points_heading,
)
from quadnav_onboard.step import primitive_targets, step_fractions

ON = ShieldConfig(enabled=True)
PRIMS = PrimitiveSet()
FORWARD = DEFAULT_DIRECTIONS.index((1, 0, 0))
HOVER = DEFAULT_DIRECTIONS.index((0, 0, 0))


def wall_input(distance_m: float, cfg: ShieldConfig = ON) -> np.ndarray:
    """A 32x32 network input of a flat wall facing the camera at ``distance_m`` (z-depth)."""
    return np.full((32, 32), distance_m / cfg.max_range_m, dtype=np.float32)


def test_back_projection_puts_a_facing_wall_at_its_depth_and_spans_the_field_of_view():
    pts = depth_points_heading(wall_input(4.0))
    assert pts.shape == (1024, 3)
    np.testing.assert_allclose(pts[:, 0], 4.0, rtol=1e-6)
    half_w = 4.0 * math.tan(math.radians(ON.hfov_deg) / 2)
    half_h = 4.0 * math.tan(math.radians(ON.vfov_deg) / 2)
    assert pts[0, 1] > 0.9 * half_w and pts[0, 2] > 0.9 * half_h  # row 0 up, column 0 left
    assert pts[-1, 1] < -0.9 * half_w and pts[-1, 2] < -0.9 * half_h
    assert np.all(np.abs(pts[:, 1]) < half_w) and np.all(np.abs(pts[:, 2]) < half_h)


def test_pixels_that_saw_nothing_give_no_points():
    d = wall_input(3.0)
    d[:, :16] = 1.0  # left half: nothing within range
    pts = depth_points_heading(d).reshape(32, 32, 3)
    assert np.isnan(pts[:, :16]).all() and np.isfinite(pts[:, 16:]).all()


def _slanted_wall_frame_mm(near_x_m: float, slope: float, cfg: ShieldConfig = ON) -> np.ndarray:
    """A D435 frame (240 x 424, mm) of the plane x = near_x_m + slope * y (heading frame, camera at
    the origin): seen at a grazing angle when ``slope`` is large."""
    ty = pixel_slopes(424, 240, cfg.hfov_deg, cfg.vfov_deg)[0]
    x = near_x_m / (1.0 - slope * ty)  # the ray (1, ty, tz) meets the plane at this z-depth
    x = np.where(x > 0, x, np.inf)
    return np.broadcast_to(np.clip(np.round(x * 1000.0), 0, 65535), (240, 424)).astype(np.uint16)


def test_a_slanted_faces_points_lie_on_it_when_placed_where_they_were_seen():
    """A wall 1 m ahead slanting away to the left (~76 deg from facing the camera): each cell's
    nearest depth placed on the ray of the pixel that saw it lies on the wall (to the mm
    quantisation); on the cell's centre ray it lies in front of the wall, nearer than it is."""
    slope = 4.0
    frame = _slanted_wall_frame_mm(1.0, slope)
    _, near, near_at = preprocess_depth_pair(frame)
    seen = near < 0.999
    assert seen.sum() > 200

    def off_wall_m(pts: np.ndarray) -> np.ndarray:  # signed: < 0 in front of the wall
        p = pts.reshape(32, 32, 3)[seen]
        return (p[:, 0] - 1.0 - slope * p[:, 1]) / math.hypot(1.0, slope)

    placed = off_wall_m(depth_points_heading(near, ON, near_at))
    centred = off_wall_m(depth_points_heading(near, ON))
    assert np.abs(placed).max() < 0.005
    assert centred.max() < 0.005 and centred.min() < -0.02  # nearer than the wall, by cm


def test_the_memory_places_points_where_given_and_on_centre_rays_without():
    depth = wall_input(2.0)[None]
    at = np.zeros((1, 32, 32, 2), np.float32)
    at[..., 1] = 0.5  # every surface seen at its cell's right edge
    centred, placed = PointMemory(1, ON), PointMemory(1, ON)
    centred.add([0], depth, np.zeros((1, 3)), np.zeros(1))
    placed.add([0], depth, np.zeros((1, 3)), np.zeros(1), at)
    view = slice(-points_per_view(ON), -points_per_view(ON) + 1024)  # the newest view's surface points
    shift = centred.points[0, view, 1] - placed.points[0, view, 1]  # right is -y
    step = 2.0 * 2.0 * math.tan(math.radians(ON.hfov_deg) / 2) / 32
    np.testing.assert_allclose(shift, 0.5 * step, rtol=1e-4)
    np.testing.assert_allclose(placed.points[0, view, 0], 2.0, rtol=1e-6)


def test_a_wall_ahead_vetoes_forward_primitives_and_keeps_hovering():
    mem = PointMemory(1, ON)
    mem.add([0], wall_input(1.2)[None], np.zeros((1, 3)), np.zeros(1))
    s = primitive_samples(PRIMS, np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1), ON, np.zeros((1, 3)))
    clearance = primitive_clearance(s, mem.points, ON)
    allowed = allowed_actions(clearance, ON)[0]
    forward = [i for i, d in enumerate(DEFAULT_DIRECTIONS) if d[0] == 1]
    assert not allowed[forward].any()
    assert allowed[HOVER]
    assert clearance[0, HOVER] == pytest.approx(1.2, abs=0.05)


def test_the_wall_is_remembered_after_it_leaves_the_field_of_view():
    cfg = ShieldConfig(enabled=True, memory_steps=3, shadow_m=0.0)
    mem = PointMemory(1, cfg)
    mem.add([0], wall_input(3.0, cfg)[None], np.zeros((1, 3)), np.zeros(1))
    # turned 90 deg left, looking at nothing: the wall (now on the right) is still in memory
    mem.add([0], np.ones((1, 32, 32), np.float32), np.array([[1.0, 0, 0]]), np.array([math.pi / 2]))
    pts = mem.points[0][np.isfinite(mem.points[0, :, 0])]
    assert len(pts) == 1024
    np.testing.assert_allclose(pts[:, 0], 3.0, rtol=1e-6)


def test_at_half_scale_the_memory_keeps_the_same_travel():
    """Written for 1 m primitives, flown with 0.5 m ones: twice the decisions (rounded up), so a
    wall passed 3 m back is still remembered after six 0.5 m steps, as after three 1 m steps."""
    written = ShieldConfig(enabled=True, memory_steps=4)
    assert shield_at_scale(written, 1.0, 1.0) is written
    assert shield_at_scale(written, 1.0, 0.5).memory_steps == 8
    assert shield_at_scale(written, 0.5, 1.0).memory_steps == 2
    assert shield_at_scale(ShieldConfig(memory_steps=3), 1.0, 0.4).memory_steps == 8  # 7.5 -> 8
    assert shield_at_scale(ShieldConfig(memory_steps=1), 1.0, 3.0).memory_steps == 1  # never 0
    assert shield_at_scale(written, 1.0, 0.5).clearance_m == written.clearance_m

    def remembers_the_wall(cfg: ShieldConfig, step_m: float, steps: int) -> bool:
        mem = PointMemory(1, cfg)
        mem.add([0], wall_input(2.0, cfg)[None], np.zeros((1, 3)), np.zeros(1))
        for k in range(1, steps + 1):  # sidestepping left, looking at nothing
            mem.add([0], np.ones((1, 32, 32), np.float32), np.array([[0.0, k * step_m, 0]]), np.zeros(1))
        return bool(np.isfinite(mem.points[0, :, 0]).any())

    assert remembers_the_wall(written, 1.0, 3)
    assert not remembers_the_wall(written, 0.5, 6)  # unscaled: the same 3 m forgets it
    assert remembers_the_wall(shield_at_scale(written, 1.0, 0.5), 0.5, 6)
    with pytest.raises(ValueError, match="scales"):
        shield_at_scale(written, 1.0, 0.0)


def test_each_seen_point_casts_a_shadow_point_further_along_its_ray():
    cfg = ShieldConfig(enabled=True, shadow_m=0.5)
    depth = wall_input(3.0, cfg)
    depth[:, :16] = 1.0  # the left half saw nothing
    pts = view_points_heading(depth, cfg)
    assert pts.shape == (points_per_view(cfg), 3) == (2048, 3)
    surface, shadow = pts[:1024], pts[1024:]
    seen = np.isfinite(surface[:, 0])
    assert seen.sum() == 512 and np.array_equal(seen, np.isfinite(shadow[:, 0]))
    r_surface = np.linalg.norm(surface[seen], axis=1)
    np.testing.assert_allclose(np.linalg.norm(shadow[seen], axis=1), r_surface + 0.5, rtol=1e-5)
    np.testing.assert_allclose(  # same ray
        shadow[seen] / (r_surface + 0.5)[:, None], surface[seen] / r_surface[:, None], atol=1e-6
    )
    assert points_per_view(ShieldConfig(shadow_m=0.0)) == 1024
    np.testing.assert_array_equal(view_points_heading(depth, ShieldConfig(shadow_m=0.0)), surface)


def _one_cell_view(distance_m: float, cfg: ShieldConfig = ON) -> np.ndarray:
    """An input that saw one surface, in the centre cell, ``distance_m`` ahead; nothing elsewhere."""
    depth = np.ones((32, 32), np.float32)
    depth[16, 16] = distance_m / cfg.max_range_m
    return depth


@pytest.mark.parametrize(("second_view_m", "carve", "shadow_left"), [
    (None, True, True),  # nothing looked at the shadow again
    (10.0, True, False),  # a view from the side saw through it: gone
    (10.0, False, True),  # ... unless carving is off
    (2.1, True, True),  # the side view's surface is within the margin behind it: not seen through
])
def test_a_shadow_is_forgotten_once_a_view_from_elsewhere_sees_through_it(
    second_view_m: float | None, carve: bool, shadow_left: bool
) -> None:
    """From the origin, one surface 2 m ahead: its point and its shadow 0.3 m behind. A second
    view from 2.3 m to the right, looking left (+y) straight at the shadow, that measured nothing
    there (10 m) or a surface 2.1 m away (under the shadow's 2.0 m + ``seen_margin_m``)."""
    cfg = ShieldConfig(enabled=True, carve_shadows=carve)
    mem = PointMemory(1, cfg)
    mem.add([0], _one_cell_view(2.0, cfg)[None], np.zeros((1, 3)), np.zeros(1))
    before = mem.points[0][np.isfinite(mem.points[0, :, 0])]
    assert before.shape == (2, 3) and before[1, 0] > before[0, 0] + 0.25  # the surface, its shadow
    if second_view_m is not None:
        shadow = before[1]
        side = np.array([[shadow[0], shadow[1] - 2.0, shadow[2]]])
        seen = np.full((1, 32, 32), min(second_view_m / cfg.max_range_m, 1.0), np.float32)
        mem.add([0], seen, side, np.array([math.pi / 2]))
    after = mem.points[0][np.isfinite(mem.points[0, :, 0])]
    assert any(np.allclose(p, before[0]) for p in after)  # a seen surface is never forgotten
    assert any(np.allclose(p, before[1]) for p in after) == shadow_left


def test_the_shadow_makes_the_unseen_back_of_a_ledge_solid():
    """A ledge below the camera seen from 3 m (its front face fills the lower third of the view):
    a point 0.6 m behind the seen face and 0.3 m below its top edge is solid in a pipe or a crate.
    Surfaces alone leave it outside the 0.5 m clearance; with shadows it is inside."""
    plain, shaded = ShieldConfig(enabled=True, shadow_m=0.0), ShieldConfig(enabled=True, shadow_m=0.5)
    depth = np.ones((32, 32), np.float32)
    depth[22:, :] = 3.0 / plain.max_range_m
    mems = []
    for cfg in (plain, shaded):
        mem = PointMemory(1, cfg)
        mem.add([0], depth[None], np.zeros((1, 3)), np.zeros(1))
        mems.append(mem)
    top = np.nanmax(depth_points_heading(depth, plain)[:, 2])  # the face's top edge (z, heading frame)
    behind = np.array([3.6, 0.0, top - 0.3])[None, None, None, :]  # (1, 1, 1, 3) sample
    c_plain = primitive_clearance(behind, mems[0].points, plain)[0, 0]
    c_shaded = primitive_clearance(behind, mems[1].points, shaded)[0, 0]
    assert c_plain > plain.clearance_m and c_shaded < 0.3


def test_hovering_in_place_replaces_the_newest_view_instead_of_forgetting_old_ones():
    cfg = ShieldConfig(enabled=True, memory_steps=2, min_travel_m=0.3, shadow_m=0.0)
    mem = PointMemory(1, cfg)
    mem.add([0], wall_input(5.0, cfg)[None], np.zeros((1, 3)), np.zeros(1))  # the old view
    for _ in range(5):  # hovering 1 m further on: one slot, rewritten
        mem.add([0], wall_input(2.0, cfg)[None], np.array([[1.0, 0, 0]]), np.zeros(1))
    xs = np.unique(np.round(mem.points[0, :, 0], 3))
    assert set(xs.tolist()) == {3.0, 5.0}
    mem.add([0], wall_input(2.0, cfg)[None], np.array([[2.0, 0, 0]]), np.zeros(1))  # moved: push
    assert 5.0 not in set(np.unique(np.round(mem.points[0, :, 0], 3)).tolist())


def test_predicted_path_overshoots_a_sharp_reversal_that_the_command_does_not():
    left = DEFAULT_DIRECTIONS.index((1, -1, 0))  # right turn while flying left at 1 m/s
    v = np.array([[1.0, 1.0, 0.0]])
    cmd = primitive_samples(PRIMS, np.zeros((1, 3)), v, np.zeros(1), ON)
    flown = primitive_samples(PRIMS, np.zeros((1, 3)), v, np.zeros(1), ON, np.zeros((1, 3)), v)
    assert flown[0, left, :, 1].max() > cmd[0, left, :, 1].max() + 0.05


def test_samples_follow_the_heading_frame():
    s = primitive_samples(PRIMS, np.zeros((1, 3)), np.zeros((1, 3)), np.array([math.pi / 2]), ON)
    end = s[0, FORWARD, ON.samples - 1]  # the primitive's end point: 1 m forward = +y in the world
    np.testing.assert_allclose(end, [0.0, 1.0, 0.0], atol=1e-9)


def test_when_nothing_is_clear_the_least_bad_primitives_are_allowed():
    c = np.array([[0.1, 0.3, 0.2], [0.9, 0.1, 0.6]])
    np.testing.assert_array_equal(allowed_actions(c, ON), [[False, True, False], [True, False, True]])
    assert allowed_actions(c, ShieldConfig(enabled=False)).all()


def test_clearance_ignores_missing_points_and_is_capped():
    s = np.zeros((1, 2, 3, 3))
    s[0, 1, :, 0] = 1.0
    pts = np.full((1, 4, 3), np.nan, dtype=np.float32)
    pts[0, 0] = [1.2, 0.0, 0.0]
    c = primitive_clearance(s, pts, ON)
    np.testing.assert_allclose(c, [[1.2, 0.2]], atol=1e-6)
    assert primitive_clearance(s, np.full((1, 4, 3), np.nan, np.float32), ON).max() == ON.search_radius_m


def test_checkpoint_meta_names_the_shield_or_means_none():
    assert not shield_config_from_meta({}).enabled
    cfg = shield_config_from_meta({"shield": {"enabled": True, "clearance_m": 0.6}})
    assert cfg.enabled and cfg.clearance_m == 0.6
    with pytest.raises(ValueError, match="clearance"):
        shield_config_from_meta({"shield": {"enabled": True, "clearance": 0.6}})


def test_a_level_tolerance_vetoes_climbs_and_descents_into_unseen_space_only():
    """With ``seen_level_tol_m`` finite, the first view (8 m of free space ahead) allows level
    primitives but not those that end a metre above or below, outside the camera's 58 deg field."""
    cfg = ShieldConfig(enabled=True, seen_level_tol_m=0.3)
    mem = PointMemory(1, cfg)
    pos = np.array([[0.0, 0.0, 2.0]])
    mem.add([0], wall_input(8.0, cfg)[None], pos, np.zeros(1))
    from quadnav_onboard.shield import shield_verdict

    still = (pos, np.zeros((1, 3)), np.zeros(1), pos, np.zeros((1, 3)))
    allowed, _ = shield_verdict(PRIMS, mem.points, mem.depth_m, mem.pose, *still, cfg)
    for a, (f, lat, v) in enumerate(DEFAULT_DIRECTIONS):
        if v != 0:
            assert not allowed[0, a], (f, lat, v)
    assert allowed[0, FORWARD] and allowed[0, HOVER]
    off, _ = shield_verdict(PRIMS, mem.points, mem.depth_m, mem.pose, *still, ON)
    assert off.all()


def test_the_predicted_path_is_the_simulated_vehicles_path_within_a_few_centimetres():
    """The filter's tracking model (its own parameters, a finer step) and the sim's kinematic quad
    (sim_harness.quad) agree on where each primitive is flown, from a sharp reversal too."""
    from quadnav_onboard.primitives import bezier_position, bezier_velocity
    from sim_harness.quad import QuadParams, QuadState, track

    v0 = np.array([[1.0, 1.0, 0.0]])
    flown = primitive_samples(PRIMS, np.zeros((1, 3)), v0, np.zeros(1), ON, np.zeros((1, 3)), v0)
    q = QuadParams()
    u = step_fractions(PRIMS.duration_s, q.dt_s)
    for a in range(PRIMS.n_actions):
        ctrl = PRIMS.control_points(np.array([a]), v0)
        _, trail = track(
            QuadState(np.zeros((1, 3)), v0.copy()), bezier_position(ctrl, u), bezier_velocity(ctrl, u, 1.0), q
        )
        sim_end = trail[-1, 0]
        np.testing.assert_allclose(flown[0, a, ON.samples - 1], sim_end, atol=0.05)


def test_a_camera_ahead_of_the_body_origin_places_what_it_sees_ahead_too():
    """camera_offset_m: a D435 0.1 m forward of the odometry's origin, heading 90 deg left: a wall at
    1.2 m depth is 1.3 m from the body, in the world's +y (placing it from the body origin, 0.1 m
    too close, errs on the safe side ahead); the view's recorded pose is the camera's."""
    cfg = ShieldConfig(enabled=True, camera_offset_m=(0.1, 0.0, 0.05), shadow_m=0.0)
    yaw = np.array([math.pi / 2])
    pos = np.array([[2.0, 3.0, 1.5]])
    plain, offset = PointMemory(1, ShieldConfig(enabled=True, shadow_m=0.0)), PointMemory(1, cfg)
    for mem in (plain, offset):
        mem.add([0], wall_input(1.2, cfg)[None], pos, yaw)
    ys = offset.points[0][np.isfinite(offset.points[0, :, 1]), 1]
    np.testing.assert_allclose(ys, 3.0 + 1.3, atol=1e-5)
    np.testing.assert_allclose(offset.pose[0, -1, :3], [2.0, 3.1, 1.55], atol=1e-9)
    s = primitive_samples(PRIMS, pos, np.zeros((1, 3)), yaw, cfg, pos)
    c_plain = primitive_clearance(s, plain.points, cfg)[0, HOVER]
    c_offset = primitive_clearance(s, offset.points, cfg)[0, HOVER]
    assert c_plain == pytest.approx(1.2, abs=0.05) and c_offset == pytest.approx(c_plain + 0.1, abs=1e-3)


def test_a_bad_camera_offset_is_refused():
    with pytest.raises(ValueError, match="camera_offset_m"):
        ShieldConfig(camera_offset_m=(0.1, float("nan"), 0.0))


def test_a_known_floor_vetoes_descents_onto_it_that_the_camera_cannot_see():
    """0.7 m above the floor, nothing seen: with the floor known (z = 0), primitives that go down
    1 m are vetoed and their clearance is their least height above it; level ones stay allowed.
    Unknown (None, NaN) or ``known_floor: false``: the floor plays no part."""
    from quadnav_onboard.shield import shield_verdict

    mem = PointMemory(1, ON)
    pos = np.array([[0.0, 0.0, 0.7]])
    mem.add([0], np.ones((1, 32, 32), np.float32), pos, np.zeros(1))
    still = (pos, np.zeros((1, 3)), np.zeros(1), pos, np.zeros((1, 3)))
    allowed, clearance = shield_verdict(PRIMS, mem.points, mem.depth_m, mem.pose, *still, ON, floor_z_m=[0.0])
    for a, (f, lat, v) in enumerate(DEFAULT_DIRECTIONS):
        assert allowed[0, a] == (v >= 0), (f, lat, v)
    down = DEFAULT_DIRECTIONS.index((0, 0, -1))
    assert clearance[0, down] == 0.0  # its samples reach below the floor
    assert clearance[0, FORWARD] == pytest.approx(0.7)
    for floor, cfg in (([np.nan], ON), (None, ON), ([0.0], ShieldConfig(enabled=True, known_floor=False))):
        unknown, _ = shield_verdict(PRIMS, mem.points, mem.depth_m, mem.pose, *still, cfg, floor_z_m=floor)
        assert unknown.all()


def test_bench_shield_flights_times_every_verdict_of_a_real_flight():
    """benchmarks/bench_shield.py --flights (the verdict figures of docs/results.md): one timed call
    per decision of the flight plus one at its start, with the memory asked for."""
    import sys
    from pathlib import Path

    from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy
    from quadnav_onboard.shield import shield_config_from_meta

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import bench_shield

    import sim_harness.env as sim_env

    real = sim_env.shield_verdict
    policy = Policy.from_path(DEFAULT_MODEL_PATH)
    shipped = shield_config_from_meta(policy.checkpoint.meta)
    r = bench_shield.time_flights(policy, shipped, 0.5, 1, memory_steps=3, envs=(1,))
    assert sim_env.shield_verdict is real  # restored
    assert r["memory_steps"] == 3 and r["flights"] == 1 and r["goals"] in (0, 1)
    assert r["calls"] >= (100 if r["goals"] else 2)  # 60 m at 0.5 m a step: ~120 decisions to the goal
    assert 0 < r["verdict_median_ms"] <= r["verdict_p99_ms"]


def test_bench_shield_starvation_measures_sleeps_with_and_without_a_preparing_thread():
    """benchmarks/bench_shield.py --starvation (the GIL check of docs/daemon.md): the preparing
    thread really prepares frames at its rate while the sleeps run (none without a filter given),
    the figures are ordered, and the thread stops."""
    import sys
    import threading
    from pathlib import Path

    from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy
    from quadnav_onboard.shield import shield_config_from_meta

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import bench_shield

    policy = Policy.from_path(DEFAULT_MODEL_PATH)
    threads = threading.active_count()
    for cfg in (None, shield_config_from_meta(policy.checkpoint.meta)):
        r = bench_shield.oversleep(policy, cfg, 0.5, sleeps=40)
        assert 0 <= r["oversleep_p50_ms"] <= r["oversleep_p99_ms"] <= r["oversleep_max_ms"]
        assert (r["prepares"] >= 2) if cfg is not None else (r["prepares"] == 0)  # 40 x 2 ms at 30 Hz
        assert threading.active_count() == threads


def test_shield_error_script_compares_predicted_and_true_clearance(tmp_path):
    """scripts/shield_error.py (the filter's error figures in docs/results.md): over real flights
    in the narrow corridor, decisions near a wall are found and the error percentiles are ordered;
    the held-out worlds are refused."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "scripts" / "shield_error.py"
    out = tmp_path / "e.json"
    run = subprocess.run([sys.executable, str(script), "--envs", "3", "--trials", "2", "--json", str(out)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    r = json.loads(out.read_text())
    assert r["decisions"] >= 2 and 0 < r["near_decisions"] <= r["decisions"]
    e = r["error_m"]
    assert e["p50"] <= e["p90"] <= e["p95"] <= e["p99"] <= r["error_max_m"]
    assert abs(e["p50"]) < 0.2  # the same samples against the same walls: the filter is right on the median
    held_out = subprocess.run([sys.executable, str(script), "--envs", "8"], capture_output=True, text=True)
    assert held_out.returncode == 2 and "held out" in held_out.stderr


def _blind_verdict(cfg: ShieldConfig, pos: np.ndarray, yaw: float = 0.0, **kw: object) -> tuple:
    """The verdict at ``pos`` (1, 3), standing still, after a view that saw nothing at all."""
    from quadnav_onboard.shield import shield_verdict

    mem = PointMemory(1, cfg)
    mem.add([0], np.ones((1, 32, 32), np.float32), pos, np.full(1, yaw))
    still = (pos, np.zeros((1, 3)), np.full(1, yaw), pos, np.zeros((1, 3)))
    return shield_verdict(PRIMS, mem.points, mem.depth_m, mem.pose, *still, cfg, **kw)


def test_a_primitive_leaving_the_geofence_is_vetoed_though_no_view_saw_the_wall():
    """The view saw nothing (no wall, no point): 0.8 m inside the fence's +y face (on the left),
    the primitives that step left 1 m would leave the fence less its margin and are vetoed; every
    other one stays allowed. Without the fence all are allowed: the camera alone never knew."""
    fence = ShieldConfig(enabled=True, fence_min_m=(-10.0, -10.0, -1.0), fence_max_m=(10.0, 0.8, 10.0))
    pos = np.array([[0.0, 0.0, 1.5]])
    allowed, clearance = _blind_verdict(fence, pos)
    for a, (f, lat, v) in enumerate(DEFAULT_DIRECTIONS):
        assert allowed[0, a] == (lat <= 0), (f, lat, v)
    left = DEFAULT_DIRECTIONS.index((0, 1, 0))
    assert clearance[0, left] < fence.clearance_m
    blind, _ = _blind_verdict(ON, pos)
    assert blind.all()


def test_the_fence_is_in_the_world_frame_whatever_the_heading():
    """Heading 90 deg left (forward = world +y): now the forward primitives leave the +y face."""
    fence = ShieldConfig(enabled=True, fence_min_m=(-10.0, -10.0, -1.0), fence_max_m=(10.0, 0.8, 10.0))
    allowed, _ = _blind_verdict(fence, np.array([[0.0, 0.0, 1.5]]), yaw=math.pi / 2)
    for a, (f, lat, v) in enumerate(DEFAULT_DIRECTIONS):
        assert allowed[0, a] == (f <= 0), (f, lat, v)


def test_a_fence_passed_per_call_overrides_the_configs_and_outside_it_the_most_inward_is_chosen():
    """Per-vehicle fences (N, 3) as the env would pass them; a vehicle already outside the fence's
    margin gets the primitives that go back in most (the least bad), not every primitive."""
    cfg = ShieldConfig(enabled=True)
    pos = np.array([[0.0, 0.0, 1.5]])
    lo, hi = np.array([[0.05, -10.0, -1.0]]), np.array([[10.0, 10.0, 10.0]])  # 5 cm behind the x face
    allowed, clearance = _blind_verdict(cfg, pos, fence_min_m=lo, fence_max_m=hi)
    assert not allowed[0, HOVER]
    assert allowed[0, FORWARD] and clearance[0, FORWARD] == pytest.approx(clearance[0].max())
    assert clearance[0, FORWARD] < cfg.clearance_m  # its first samples are still outside
    assert not any(allowed[0, a] for a, d in enumerate(DEFAULT_DIRECTIONS) if d[0] <= 0)


def test_a_room_of_walls_keeps_the_clearance_and_a_geofence_the_margin():
    cfg = ShieldConfig(enabled=True, clearance_m=0.5, fence_margin_m=0.1)
    walls = cfg.with_room((-1.0, -1.0, 0.0), (3.0, 3.0, 3.0))
    assert walls.fence_min_m == pytest.approx((-0.6, -0.6, 0.4))
    assert walls.fence_max_m == pytest.approx((2.6, 2.6, 2.6))
    both = walls.with_fence((-0.5, -2.0, -1.0), (2.8, 2.0, 2.8))  # intersected
    assert both.fence_min_m == pytest.approx((-0.5, -0.6, 0.4))
    assert both.fence_max_m == pytest.approx((2.6, 2.0, 2.6))
    assert cfg.with_fence(None, None) is cfg


@pytest.mark.parametrize(
    ("kw", "needle"),
    [
        ({"fence_min_m": (0.0, 0.0, 0.0)}, "both"),
        ({"fence_min_m": (0.0, 0.0, 0.0), "fence_max_m": (1.0, 0.0, 1.0)}, "below"),
        ({"fence_margin_m": 0.5}, "fence_margin_m"),
    ],
)
def test_a_bad_fence_is_refused(kw: dict, needle: str) -> None:
    with pytest.raises(ValueError, match=needle):
        ShieldConfig(enabled=True, **kw)


def test_a_fence_in_a_config_file_is_range_checked():
    from quadnav_onboard.config import ConfigError, parse_config

    with pytest.raises(ConfigError, match="fence_max_m"):
        parse_config(ShieldConfig, {"fence_min_m": [0, 0, 0], "fence_max_m": [1, 1, math.nan]}, source="x")
    ok = parse_config(ShieldConfig, {"fence_min_m": [0, 0, 0], "fence_max_m": [1, 1, 1]}, source="x")
    assert ok.fence_max_m == (1.0, 1.0, 1.0)


STOP = ShieldConfig(enabled=True, lookahead="stop")
DOWN_FORWARD = DEFAULT_DIRECTIONS.index((1, 0, -1))


def test_the_stop_look_ahead_is_the_hover_the_next_decision_can_choose():
    """With ``lookahead: stop`` the points past each primitive's end are those of the hover
    primitive commanded from its end at its end velocity: what the filter then checks for the
    hover at the next decision. An allowed primitive leaves an allowed hover behind it."""
    v0 = np.array([[0.5, -0.5, 0.0]])
    samples = primitive_samples(PRIMS, np.zeros((1, 3)), v0, np.zeros(1), STOP)
    assert samples.shape == (1, PRIMS.n_actions, 2 * STOP.samples, 3)
    for a in range(PRIMS.n_actions):
        end = samples[:, a, STOP.samples - 1]
        nxt = primitive_samples(PRIMS, end, PRIMS.end_velocity_m_s(np.array([a])), np.zeros(1), STOP)
        np.testing.assert_allclose(samples[0, a, STOP.samples :], nxt[0, HOVER, : STOP.samples], atol=1e-9)
        still = np.repeat(nxt[0, HOVER, -1:], STOP.samples, 0)  # after the stop, it stays
        np.testing.assert_allclose(nxt[0, HOVER, STOP.samples :], still)


def test_the_stop_after_a_descent_is_flown_as_the_simulated_vehicle_flies_it():
    """The tracked stop (filter's model) and the sim's quad agree on the lowest point of a 1 m
    descent followed by a hover, within 5 cm; it dips below the descent's end."""
    from sim_harness.quad import QuadParams, QuadState, track

    start, v0, yaw = np.array([[0.0, 0.0, 2.0]]), np.zeros((1, 3)), np.zeros(1)
    predicted = primitive_samples(PRIMS, start, v0, yaw, STOP, start, v0)[0, DOWN_FORWARD]
    q = QuadParams()
    u = step_fractions(PRIMS.duration_s, q.dt_s)
    targets, target_vel = primitive_targets(PRIMS, [DOWN_FORWARD], start, v0, yaw, u)
    state, first = track(QuadState(start.copy(), v0.copy()), targets, target_vel, q)
    targets, target_vel = primitive_targets(PRIMS, [HOVER], targets[-1], target_vel[-1], yaw, u)
    _, second = track(state, targets, target_vel, q)
    sim_low = min(first[:, 0, 2].min(), second[:, 0, 2].min())
    assert predicted[:, 2].min() == pytest.approx(sim_low, abs=0.05)
    assert predicted[:, 2].min() < 1.0 - 0.1


def test_over_a_known_floor_the_stop_look_ahead_allows_a_descent_the_velocity_one_vetoes():
    """1.8 m up, nothing seen, the floor at 0: a 1 m descent ends 0.8 m up. Carried on 0.3 s at
    its end velocity it is checked to ~0.43 m (vetoed at 0.5 m clearance); with the stop that can
    follow, to ~0.57 m (allowed). From 1.65 m both veto it."""
    from quadnav_onboard.shield import shield_verdict

    for z, velocity_allows, stop_allows in ((1.8, False, True), (1.65, False, False), (2.2, True, True)):
        pos = np.array([[0.0, 0.0, z]])
        still = (pos, np.zeros((1, 3)), np.zeros(1), pos, np.zeros((1, 3)))
        for cfg, expected in ((ON, velocity_allows), (STOP, stop_allows)):
            mem = PointMemory(1, cfg)
            mem.add([0], np.ones((1, 32, 32), np.float32), pos, np.zeros(1))
            allowed, _ = shield_verdict(
                PRIMS, mem.points, mem.depth_m, mem.pose, *still, cfg, floor_z_m=[0.0]
            )
            assert allowed[0, DOWN_FORWARD] == expected, (z, cfg.lookahead)


def test_an_unknown_look_ahead_is_refused_and_named():
    from quadnav_onboard.config import ConfigError, parse_config

    with pytest.raises(ValueError, match="lookahead must be 'velocity' or 'stop', got 'brake'"):
        ShieldConfig(enabled=True, lookahead="brake")
    with pytest.raises(ConfigError, match="lookahead"):
        parse_config(ShieldConfig, {"lookahead": "brake"}, source="flight.yaml: shield")
