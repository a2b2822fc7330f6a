"""The paper's real-flight labs as worlds: rooms with walls, the flight config's mission flown in
the eval with its geofence and altitude band as stop conditions, and the room known to the filter."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from quadnav_onboard.daemon.config import dry_run_config, flies_hardware, load_flight_config
from quadnav_onboard.policy import DEFAULT_MODEL_PATH, PGUD_MODEL_PATH, Policy
from quadnav_onboard.primitives import DEFAULT_DIRECTIONS
from quadnav_onboard.shield import ShieldConfig
from sim_harness.collision import clearance_m
from sim_harness.env import VecQuadNavEnv
from sim_harness.render import render_inputs
from sim_harness.rl.evaluate import FlightLimits, evaluate, flight_eval_setup, known_room, policy_greedy_fn
from sim_harness.route import route_report
from sim_harness.world import WorldError, load_world, parse_world, resolve_world_arg, world_to_mapping

REPO = Path(__file__).resolve().parents[1]
FLIGHT = REPO / "config" / "flight.yaml"
ROOM = {
    "name": "room",
    "path": {"waypoints": [[0, 0, 1.2], [2, 2, 1.2]]},
    "bounds": {"floor_z": 0.0, "ceiling_z": 3.0},
    "room": {"x": [-1.0, 3.0], "y": [-1.0, 3.0]},
}


def test_a_room_builds_solid_walls_that_the_camera_sees_and_the_vehicle_hits():
    w = parse_world(ROOM, "t")
    assert len(w.walls) == 4 and w.obstacles == ()
    assert w.room_box_m() == ((-1.0, -1.0, 0.0), (3.0, 3.0, 3.0))
    c = clearance_m(w, np.array([[2.5, 1.0, 1.2], [3.1, 1.0, 1.2], [1.0, 1.0, 1.2]]))
    assert c[0] == pytest.approx(0.5) and c[1] < 0 and c[2] == pytest.approx(1.2)  # ceiling 1.8 m up
    depth = render_inputs(w, np.array([[1.0, 1.0, 1.2]]), np.zeros(1)).mean  # facing the +x wall, 2 m
    assert np.median(depth[0]) < 0.35  # everything within about 3 m of a 10 m range


def test_a_room_round_trips_and_a_bad_room_names_the_file_and_the_key():
    w = parse_world(ROOM, "t")
    again = parse_world(world_to_mapping(w), "t2")
    assert again.room_xy_m == w.room_xy_m and len(again.geometry.kind) == 4
    for room, needle in (
        ({"x": [0, 0.5], "y": [-1, 3]}, "room: 'x'"),
        ({"x": [-1, 3]}, "missing required key 'y'"),
        ({"x": [-1, 3], "y": [-1, float("nan")]}, "'y' must be a finite number"),
        ({"x": [-1, 3], "y": [0.1, 3]}, "outside the room"),
    ):
        with pytest.raises(WorldError, match=needle):
            parse_world({**ROOM, "room": room}, "lab.yaml")
    with pytest.raises(WorldError, match="needs 'bounds'"):
        parse_world({**ROOM, "bounds": {"floor_z": 0.0}}, "lab.yaml")


def test_the_lab_worlds_are_the_papers_labs_and_fit_the_flight_config():
    cfg = load_flight_config(FLIGHT)
    lo, hi = np.asarray(cfg.safety.geofence_min_m), np.asarray(cfg.safety.geofence_max_m)
    for name, n_obstacles in (("lab01", 0), ("lab02", 2), ("lab03", 1), ("lab04", 2)):
        w = load_world(resolve_world_arg(f"{name}.yaml"))
        assert len(w.obstacles) == n_obstacles and len(w.walls) == 4
        assert w.path.length_m == pytest.approx(3.5, abs=0.01)  # the paper's 3.5 m, diagonal
        np.testing.assert_allclose(w.path.waypoints_m, cfg.mission.waypoints_m)
        room_lo, room_hi = w.room_box_m()
        assert np.all(np.asarray(room_lo)[:2] < lo[:2]) and np.all(np.asarray(room_hi)[:2] > hi[:2])
    assert resolve_world_arg("lab02") == resolve_world_arg("lab02-two-boxes.yaml")
    with pytest.raises(WorldError, match="matches"):
        resolve_world_arg("lab")


def test_a_dry_run_replaces_only_the_hardware_sections_of_the_flight_config():
    cfg = load_flight_config(FLIGHT)
    assert flies_hardware(cfg)
    dry = dry_run_config(cfg)
    assert dry.depth.kind == "socket" and not dry.vehicle.url.startswith("serial")
    assert dry.trigger != cfg.trigger and dry.record.directory == "records"
    for section in ("mission", "primitives", "shield", "safety", "preprocess", "reward"):
        assert getattr(dry, section) == getattr(cfg, section), section
    sim = load_flight_config(REPO / "config" / "sim.yaml", require_waypoints=False)
    assert not flies_hardware(sim) and dry_run_config(sim) is sim


def test_the_geofence_and_the_altitude_band_stop_a_flight():
    lim = FlightLimits((-1.0, -1.0, -0.5), (3.0, 3.0, 2.8), 0.4, 2.5)
    out = lim.stop(np.array([[0, 0, 1.2], [3.2, 0, 1.2], [0, 0, 2.6], [0, 0, 0.2], [0, 0, 2.9]]))
    assert out.tolist() == [None, "geofence", "altitude", "altitude", "geofence"]


def test_known_room_is_the_walls_less_the_clearance_and_the_geofence():
    w = parse_world(ROOM, "t")
    sh = ShieldConfig(enabled=True)
    lim = FlightLimits((-2.0, -0.5, -0.5), (5.0, 5.0, 2.8), 0.4, 2.5)
    got = known_room(sh, w, lim)
    inset = sh.clearance_m - sh.fence_margin_m
    assert got.fence_min_m == pytest.approx((-1.0 + inset, -0.5, inset))
    assert got.fence_max_m == pytest.approx((3.0 - inset, 3.0 - inset, 3.0 - inset))
    paper = load_world(REPO / "sim_harness" / "worlds" / "env01-free.yaml")  # no walls: its ceiling
    assert known_room(sh, paper).fence_max_m[2] == pytest.approx(8.0 - inset)


def test_known_room_also_knows_the_flights_deviation_limit_round_the_path():
    """Under a flight config the filter keeps inside the deviation limit round the world's path (a
    stop, known space like the geofence); without one (the paper's worlds) there is no band."""
    w = parse_world(ROOM, "t")
    sh = ShieldConfig(enabled=True)
    lim = FlightLimits((-2.0, -0.5, -0.5), (5.0, 5.0, 2.8), 0.4, 2.5, 1.5)
    got = known_room(sh, w, lim)
    assert got.band_half_width_m == 1.5
    np.testing.assert_allclose(got.band_waypoints_m, w.path.waypoints_m)
    assert known_room(sh, w).band_waypoints_m is None
    flight = load_flight_config(FLIGHT)
    policy = Policy.from_path(DEFAULT_MODEL_PATH)
    _, _, limits = flight_eval_setup(policy, flight, [load_world(resolve_world_arg("lab01"))])
    assert limits.max_deviation_m == flight.safety.max_deviation_m


@pytest.mark.slow
def test_the_flight_config_flies_lab_env_1_to_the_goal_and_a_tight_geofence_stops_it():
    """The shipped model under config/flight.yaml (0.5 m primitives, 0.5 m/s, 30 steps, noise on)
    reaches the goal in the free lab; with the geofence's far side moved onto the path the flights
    end on the geofence or short of it (safe, never a goal, never a crash)."""
    policy = Policy.from_path(DEFAULT_MODEL_PATH)
    flight = load_flight_config(FLIGHT)
    world = load_world(resolve_world_arg("lab01"))
    env_cfg, worlds, limits = flight_eval_setup(policy, flight, [world])
    assert env_cfg.primitives.scale_m == 0.5 and env_cfg.max_steps == 30
    assert worlds[0].path.speed_m_s == 0.5 and env_cfg.start_jitter_m == flight.mission.start_tolerance_m
    from quadnav_onboard.policy import masked_argmax
    from sim_harness.noise import DepthNoise

    def act(d, r, a):
        return masked_argmax(policy.q_values_batch(d, r), a)

    rows = evaluate(act, worlds, 4, 0, env_cfg, limits=limits, depth_noise=DepthNoise())
    assert [r.outcome for r in rows] == ["goal"] * 4
    assert all(r.time_s <= 1.3 * 22 for r in rows)
    tight = FlightLimits(
        limits.geofence_min_m, (1.5, 1.5, 2.8), limits.altitude_floor_m, limits.altitude_ceiling_m
    )
    rows = evaluate(act, worlds, 4, 0, env_cfg, limits=tight, known_rooms=False)
    assert all(r.outcome == "geofence" for r in rows)
    rows = evaluate(act, worlds, 4, 0, env_cfg, limits=tight)  # the filter knows it: no crossing
    assert all(r.outcome in ("timeout", "deviation") and not r.crash for r in rows)


def _route(world_name: str, deviation_limit: bool, ceiling_m: float | None = None):
    """The product's route check (:mod:`sim_harness.route`) of a lab under config/flight.yaml, its
    filter as the shipped model flies it there, with or without the deviation limit, under the
    flight's altitude ceiling or ``ceiling_m``."""
    flight = load_flight_config(FLIGHT)
    s = flight.safety
    policy = Policy.from_path(DEFAULT_MODEL_PATH)
    env_cfg, worlds, limits = flight_eval_setup(policy, flight, [load_world(resolve_world_arg(world_name))])
    if not deviation_limit:
        limits = dataclasses.replace(limits, max_deviation_m=None)
    shield = known_room(env_cfg.shield, worlds[0], limits)
    altitude = (s.altitude_floor_m, s.altitude_ceiling_m if ceiling_m is None else ceiling_m)
    return route_report(worlds[0], shield, flight.mission.goal_radius_m, altitude)


def test_every_lab_but_the_closed_one_leaves_a_way_round_that_keeps_the_filters_clearances():
    """The free lab, lab Env 2 (both boxes free on the left) and the one-box lab have a route with
    0.15 m or more to spare for a vehicle that keeps 0.5 m from the boxes, 0.1 m inside the known
    room and inside the 1.5 m deviation limit. The closed lab (the slalom) has none, and its boxes
    are too tall to fly over inside the altitude band (docs/worlds.md, "A lab with no way round"):
    a planner cannot be what fails there. Without the deviation limit a route opens only near the
    boxes' tops, where their edges are farther than their sides."""
    for name, spare_m in (("lab01", 0.2), ("lab02", 0.15), ("lab03", 0.2)):
        got = _route(name, deviation_limit=True)
        assert got.route and got.spare_m >= spare_m, (name, got)
    closed = _route("lab04", deviation_limit=True)
    assert not closed.route and closed.start_ok and set(closed.closed_by) == {"clearance", "deviation"}
    assert _route("lab04", deviation_limit=False).route
    assert not _route("lab04", deviation_limit=False, ceiling_m=2.0).route
    flight = load_flight_config(FLIGHT)
    tops = [o.center_m[2] + o.size_m[2] / 2 for o in load_world(resolve_world_arg("lab04")).obstacles]
    assert min(tops) + ShieldConfig().clearance_m > flight.safety.altitude_ceiling_m


@pytest.mark.parametrize(("face_m", "forward"), [(1.0, False), (1.2, True)])
def test_a_corner_start_leaves_the_filter_no_sideways_move_and_a_near_box_no_forward_one(face_m, forward):
    """docs/hardware.md, 7.5: from the lab's corner start (0.6 m inside the geofence on both
    axes) no primitive to the side is allowed; a box face 1.2 m along the path leaves the forward
    primitive, one 1.0 m along does not (a 0.5 m step, its overshoot and the 0.5 m clearance)."""
    flight = load_flight_config(FLIGHT)
    s, c = face_m + 0.2, -0.3  # lab03's box (0.4 m deep, reaching 0.3 m left of the path), moved
    box = {"type": "box", "center": [(s - c) / np.sqrt(2), (s + c) / np.sqrt(2), 1.1],
           "size": [0.4, 1.2, 2.2], "yaw_deg": 45}
    room = world_to_mapping(load_world(resolve_world_arg("lab01")))
    world = parse_world({**room, "obstacles": [box]}, "t")
    policy = Policy.from_path(DEFAULT_MODEL_PATH)
    env_cfg, worlds, limits = flight_eval_setup(policy, flight, [world], start_jitter_m=0.0)
    env_cfg = dataclasses.replace(env_cfg, shield=known_room(env_cfg.shield, worlds[0], limits))
    env = VecQuadNavEnv(worlds, 1, seed=0, config=env_cfg, autoreset=False)
    env.reset()
    allowed = {DEFAULT_DIRECTIONS[a] for a in np.flatnonzero(env.allowed[0])}
    assert not any(d[0] == 0 and d[1] != 0 for d in allowed)  # nothing sideways
    assert ((1, 0, 0) in allowed) is forward


def test_in_the_one_box_lab_the_pgud_model_hovers_where_the_filter_still_allows_a_way_on():
    """docs/results.md, "Lab rehearsal": from lab03's start (no jitter, no noise) the pgud model
    (bundled until 0.5.0) flies forward, left and up, then holds its place about 0.5 m along until
    the step limit. The filter vetoes the forward primitive there (the box's corner) but still
    allows one that moves on (forward-left), and the DQN ranks hover above it: the planner, not the
    filter, stops it."""
    from quadnav_onboard.policy import masked_argmax

    flight = load_flight_config(FLIGHT)
    policy = Policy.from_path(PGUD_MODEL_PATH)
    env_cfg, worlds, limits = flight_eval_setup(
        policy, flight, [load_world(resolve_world_arg("lab03"))], start_jitter_m=0.0
    )
    env_cfg = dataclasses.replace(env_cfg, shield=known_room(env_cfg.shield, worlds[0], limits))
    env = VecQuadNavEnv(worlds, 1, seed=0, config=env_cfg, autoreset=False)
    depth, rel = env.reset()
    for _ in range(8):
        action = masked_argmax(policy.q_values_batch(depth, rel), env.allowed)
        depth, rel, *_ = env.step(action)
    assert not env.done[0]
    along = worlds[0].path.closest(env.pos_m)[0][0]
    assert 0.3 < along < 0.7
    allowed = {DEFAULT_DIRECTIONS[a] for a in np.flatnonzero(env.allowed[0])}
    assert (1, 0, 0) not in allowed and any(d[0] == 1 for d in allowed)
    chosen = masked_argmax(policy.q_values_batch(depth, rel), env.allowed)[0]
    assert DEFAULT_DIRECTIONS[chosen] == (0, 0, 0)


def test_in_the_one_box_lab_the_bundled_model_flies_on_to_the_goal():
    """From the same start as the pgud model above (no jitter, no noise), the bundled model, taught
    in random box layouts of the lab, goes round lab03's box to the goal without a crash."""
    flight = load_flight_config(FLIGHT)
    policy = Policy.from_path(DEFAULT_MODEL_PATH)
    env_cfg, worlds, limits = flight_eval_setup(
        policy, flight, [load_world(resolve_world_arg("lab03"))], start_jitter_m=0.0
    )
    (row,) = evaluate(policy_greedy_fn(policy), worlds, 1, 0, env_cfg, limits=limits)
    assert row.outcome == "goal" and not row.crash
