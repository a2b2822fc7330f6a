"""The route check: does a world leave a way from start to goal that keeps the filter's margins?"""

from __future__ import annotations

from pathlib import Path

import pytest

from quadnav_onboard.primitives import PrimitiveSet
from quadnav_onboard.shield import ShieldConfig
from sim_harness.cli import main
from sim_harness.route import lattice_route, route_report
from sim_harness.world import parse_world

FILTER = ShieldConfig(enabled=True)  # clearance 0.5 m
FLIGHT = str(Path(__file__).resolve().parents[1] / "config" / "flight.yaml")


def _wall_with_gap(gap_m: float, gap_y_m: float = 0.0) -> dict:
    """A 4 m path along x through a full-height wall at x = 2 with one gap of ``gap_m`` at y."""
    lo, hi = gap_y_m - gap_m / 2, gap_y_m + gap_m / 2
    return {
        "name": f"gap{gap_m}",
        "path": {"waypoints": [[0, 0, 1.0], [4, 0, 1.0]]},
        "bounds": {"floor_z": 0.0, "ceiling_z": 2.0},
        "obstacles": [
            {"type": "box", "center": [2.0, (lo - 6.0) / 2, 1.0], "size": [0.2, 6.0 + lo, 2.0]},
            {"type": "box", "center": [2.0, (hi + 6.0) / 2, 1.0], "size": [0.2, 6.0 - hi, 2.0]},
        ],
    }


def test_a_gap_wider_than_twice_the_clearance_is_a_route_with_the_difference_to_spare():
    world = parse_world(_wall_with_gap(1.4), "t")
    r = route_report(world, FILTER, goal_radius_m=0.5, grid_m=0.02)
    assert r.route and r.start_ok and r.closed_by == ()
    assert r.spare_m == pytest.approx(0.7 - 0.5, abs=0.03)  # half the gap less the clearance


def test_a_narrower_gap_is_no_route_and_the_clearance_is_what_closes_it():
    world = parse_world(_wall_with_gap(0.9), "t")
    r = route_report(world, FILTER, goal_radius_m=0.5, grid_m=0.02)
    assert not r.route and r.spare_m == 0.0 and r.closed_by == ("clearance",)
    assert route_report(world, ShieldConfig(enabled=True, clearance_m=0.4), 0.5, grid_m=0.02).route


def test_a_gap_outside_the_deviation_band_is_closed_by_the_band():
    world = parse_world(_wall_with_gap(1.4, gap_y_m=1.8), "t")
    assert route_report(world, FILTER, 0.5, grid_m=0.02).route
    banded = FILTER.with_band(world.path.waypoints_m, 1.0)
    r = route_report(world, banded, 0.5, grid_m=0.02)
    assert not r.route and r.closed_by == ("deviation",)


def test_a_start_that_breaks_a_margin_is_said_and_a_bad_grid_is_refused():
    world = parse_world(_wall_with_gap(1.4), "t")
    low = route_report(world, FILTER, 0.5, altitude_m=(1.2, 2.0), grid_m=0.02)  # the start is at 1 m
    assert not low.route and not low.start_ok and "start itself" in low.describe()
    with pytest.raises(ValueError, match="grid_m"):
        route_report(world, FILTER, 0.5, grid_m=float("nan"))


def test_the_primitives_fly_through_a_gap_on_their_lattice_and_not_through_a_narrower_one():
    """The lattice search: 1 m primitives straight through a 1.4 m gap on the path (4 steps to the
    goal 4 m on, 0.5 m radius); none through a 0.9 m one inside a 5 m deviation stop."""
    prims = PrimitiveSet(scale_m=1.0)
    wide = lattice_route(parse_world(_wall_with_gap(1.4), "t"), prims, FILTER, 0.5, 20, max_deviation_m=5)
    assert wide.steps == 4 and wide.decided
    narrow = lattice_route(parse_world(_wall_with_gap(0.9), "t"), prims, FILTER, 0.5, 20, max_deviation_m=5)
    assert narrow.steps is None and narrow.decided
    # the wall ends 6 m off the path: without the deviation stop, round its end
    assert lattice_route(parse_world(_wall_with_gap(0.9), "t"), prims, FILTER, 0.5, 20).steps is not None


def test_a_route_the_lattice_cannot_follow_is_found_by_the_fill_and_not_by_the_search():
    """A 1.4 m gap 0.25 m off the path: any curve passes it with 0.2 m to spare, but the 1 m
    lattice from the path's start crosses the wall only 0 or 1 m off the path, 0.45 m from an edge
    of the gap (0.5 m needed): the fill says yes, the primitives no."""
    world = parse_world(_wall_with_gap(1.4, gap_y_m=0.25), "t")
    assert route_report(world, FILTER, 0.5, grid_m=0.02).route
    got = lattice_route(world, PrimitiveSet(scale_m=1.0), FILTER, 0.5, 20, max_deviation_m=5)
    assert got.steps is None and got.decided


def test_the_cli_checks_the_labs_under_the_flight_config(tmp_path, capsys):
    """End to end: ``quadnav-sim route`` on the shipped labs under config/flight.yaml."""
    import json

    out = tmp_path / "route.json"
    rc = main(["route", "--world", "lab02", "--world", "lab04", "--flight-config", FLIGHT,
               "--json", str(out)])
    text = capsys.readouterr().out
    assert rc == 1  # lab04 has no route
    assert "lab02-two-boxes: a route keeps" in text and "lab04-two-boxes-closed: no route" in text
    assert "no sequence that keeps the margins reaches the goal in 30 steps" in text
    reports = json.loads(out.read_text())["reports"]
    assert [r["route"] for r in reports] == [True, False]
    assert reports[0]["primitives"]["steps"] <= 30 and reports[1]["primitives"]["steps"] is None
    assert main(["route", "--world", "lab01", "--flight-config", FLIGHT]) == 0
    assert main(["route", "--world", "lab01", "--shield", "off"]) == 2


def test_the_cli_searches_from_the_evals_own_starts(tmp_path, capsys):
    """``--trials N --seed E``: the lattice search from each of the N starts ``quadnav-sim eval
    --flight-config`` flies (those of ``evaluate``'s env, world by world in list order); none in
    the closed lab; the flags that do not go together are refused with exit 2."""
    import json

    import numpy as np

    from quadnav_onboard.daemon.config import load_flight_config
    from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy
    from sim_harness.noise import DepthNoise
    from sim_harness.rl.evaluate import eval_starts, evaluate, flight_eval_setup, policy_greedy_fn
    from sim_harness.world import load_world, resolve_world_arg

    out = tmp_path / "route.json"
    rc = main(["route", "--world", "lab02", "--world", "lab04", "--flight-config", FLIGHT,
               "--trials", "3", "--seed", "5", "--json", str(out)])
    text = capsys.readouterr().out
    assert rc == 1  # lab04: no route from the path's start
    assert "from the eval's 3 starts (--trials 3 --seed 5): a sequence from 0" in text
    reports = json.loads(out.read_text())["reports"]
    assert [r["eval_starts"]["trials"] for r in reports] == [3, 3]
    assert all(r["steps"] is None for r in reports[1]["eval_starts"]["routes"])
    assert all(r["decided"] for rep in reports for r in rep["eval_starts"]["routes"])

    # the starts are the eval's: the positions evaluate() flies from, noise or not
    policy = Policy.from_path(DEFAULT_MODEL_PATH)
    worlds = [load_world(resolve_world_arg(w)) for w in ("lab02", "lab04")]
    env_cfg, worlds, limits = flight_eval_setup(policy, load_flight_config(FLIGHT), worlds)
    flown: dict[str, np.ndarray] = {}

    def first(world, env, *_):
        flown.setdefault(world.name, env.pos_m.copy())

    evaluate(policy_greedy_fn(policy), worlds, 3, 5, env_cfg, limits=limits, depth_noise=DepthNoise(),
             on_step=first)
    for i, w in enumerate(worlds):
        np.testing.assert_allclose(reports[i]["eval_starts"]["starts_m"], flown[w.name], atol=1e-4)
        np.testing.assert_allclose(eval_starts(w, i, 3, 5, env_cfg, limits), flown[w.name])
    assert not np.allclose(flown[worlds[0].name], worlds[0].path.start_m)  # jittered

    assert main(["route", "--world", "lab02", "--trials", "3"]) == 2  # no flight config
    assert "--trials draws the starts of an eval under --flight-config" in capsys.readouterr().err


def test_the_true_geometry_verdict_is_the_lattice_check_for_a_vehicle_at_rest_on_its_point():
    """``true_geometry_verdict`` (what the env's filter would allow, seeing the true geometry)
    agrees primitive for primitive with the route search's own check (``_allowed``) for vehicles
    at rest on their commanded points, the lab's room and deviation band known to both; and it
    vetoes something there (the lab's corner start leaves no sideways move)."""
    import dataclasses

    import numpy as np

    from quadnav_onboard.daemon.config import load_flight_config
    from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy
    from sim_harness.env import VecQuadNavEnv
    from sim_harness.rl.evaluate import flight_eval_setup, known_room
    from sim_harness.route import _allowed, true_geometry_verdict
    from sim_harness.world import load_world, resolve_world_arg

    policy = Policy.from_path(DEFAULT_MODEL_PATH)
    env_cfg, worlds, limits = flight_eval_setup(
        policy, load_flight_config(FLIGHT), [load_world(resolve_world_arg("lab02"))]
    )
    shield = known_room(env_cfg.shield, worlds[0], limits)
    cfg = dataclasses.replace(env_cfg, shield=shield)
    env = VecQuadNavEnv(worlds, 4, seed=3, config=cfg, autoreset=False)
    env.reset()
    allowed, clear = true_geometry_verdict(env)
    expected, _, _ = _allowed(worlds[0], env.prims, shield, env.cmd_pos_m.copy(), np.zeros((4, 3)), None)
    np.testing.assert_array_equal(allowed, expected)
    assert allowed.any() and not allowed.all() and np.isfinite(clear).all()
