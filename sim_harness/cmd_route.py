"""``quadnav-sim route``: whether each world leaves a route that keeps the safety filter's margins."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from sim_harness.cmd_eval import (
    add_flight_flags,
    at_flight_scale,
    count_arg,
    flight_setup,
    seed_arg,
    shield_from_flags,
)

if TYPE_CHECKING:
    from sim_harness.route import LatticeRoute

__all__ = ["add_parser", "run"]


def _grid_size(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and 0.005 <= value <= 1.0):
        raise argparse.ArgumentTypeError(f"must be in [0.005, 1] m, got {text}")
    return value


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "route",
        help="check that each world leaves a route from start to goal that keeps the filter's margins",
        description="Flood-fill each world's free space, shrunk by the depth safety filter's margins "
        "(clearance from every solid, the known room, and under --flight-config the deviation limit "
        "and the altitude band), and say whether the path's start still connects to its goal, with "
        "how much to spare, or which limits close it; then search the primitives themselves from the "
        "start for a short sequence that keeps the margins from the true geometry and reaches "
        "the goal within the step limit. Both are necessary conditions for a goal, not sufficient "
        "ones: the filter knows only what it saw, and the planner must find the sequence. Exit "
        "status 1 when a world fails either.",
    )
    p.add_argument(
        "--world", action="append", required=True, metavar="WORLD",
        help="world YAML file, a shipped world's name or a paper id; repeat for more",
    )
    p.add_argument(
        "--model", default=None, help="checkpoint whose filter is checked (default: the shipped model)"
    )
    p.add_argument(
        "--flight-config", default=None, metavar="FLIGHT.yaml",
        help="check under this flight config's mission, filter, geofence, deviation limit and altitude band "
        "(as quadnav-sim eval --flight-config flies it)",
    )
    add_flight_flags(p, shield_default="on")
    p.add_argument(
        "--grid-m", type=_grid_size, default=0.025, metavar="M",
        help="voxel size of the fill, in [0.005, 1] m (default 0.025; coarser for worlds over 6M cells)",
    )
    p.add_argument(
        "--trials", type=count_arg, default=None, metavar="N",
        help="with --flight-config: also search from the N jittered starts of quadnav-sim eval "
        "--flight-config with the same worlds in the same order, --trials N and --seed (from a "
        "start with no sequence, a vehicle that tracks perfectly cannot reach the goal keeping the "
        "margins from the true geometry)",
    )
    p.add_argument("--seed", type=seed_arg, default=0, help="with --trials: the eval's --seed (default 0)")
    p.add_argument("--json", default=None, metavar="OUT", help="also write the reports as JSON")
    p.set_defaults(func=run, start_jitter_m=None)


def run(args: argparse.Namespace) -> int:
    from quadnav_onboard.checkpoint import CheckpointError
    from quadnav_onboard.config import ConfigError
    from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy
    from sim_harness.rl.evaluate import env_config_for_policy, eval_starts, known_room
    from sim_harness.route import lattice_route, route_report
    from sim_harness.world import WorldError, load_world, resolve_world_arg

    if args.trials is not None and not args.flight_config:
        print("quadnav-sim route: --trials draws the starts of an eval under --flight-config: give one",
              file=sys.stderr)
        return 2
    if args.flight_config and args.primitive_scale is not None:
        print("quadnav-sim route: --flight-config sets the primitives: not with --primitive-scale",
              file=sys.stderr)
        return 2
    model = Path(args.model) if args.model else DEFAULT_MODEL_PATH
    try:
        policy = Policy.from_path(model)
        paths = [resolve_world_arg(w) for w in args.world]
        worlds = [load_world(p) for p in paths]
        limits = None
        if args.flight_config:
            env_cfg, worlds, limits = flight_setup(policy, args, worlds, list(paths))
        else:
            env_cfg = env_config_for_policy(policy, shield=shield_from_flags(policy, args))
            env_cfg, worlds = at_flight_scale(env_cfg, worlds, args)
    except (CheckpointError, WorldError, ConfigError, ValueError) as exc:
        print(f"quadnav-sim route: {exc}", file=sys.stderr)
        return 2
    if not env_cfg.shield.enabled:
        print("quadnav-sim route: the filter is off (--shield off): it keeps no margins to check",
              file=sys.stderr)
        return 2
    altitude = None if limits is None else (limits.altitude_floor_m, limits.altitude_ceiling_m)
    prims = env_cfg.primitives.build()
    rows, ok = [], True
    for index, world in enumerate(worlds):
        shield = known_room(env_cfg.shield, world, limits)
        stop = env_cfg.reward.max_deviation_m  # the episode's deviation stop (flight: the supervisor's)
        report = route_report(world, shield, env_cfg.goal_radius_m, altitude, args.grid_m, stop)
        lattice = lattice_route(
            world, prims, shield, env_cfg.goal_radius_m, env_cfg.max_steps, altitude, stop
        )
        print(report.describe())
        print("  " + _describe_lattice(lattice, prims.scale_m, env_cfg.max_steps))
        row = {**report.to_dict(), "primitives": lattice.to_dict()}
        if args.trials is not None:
            starts = eval_starts(world, index, args.trials, args.seed, env_cfg, limits)
            found = [
                lattice_route(world, prims, shield, env_cfg.goal_radius_m, env_cfg.max_steps, altitude, stop,
                              start_m=s)
                for s in starts
            ]
            print("  " + _describe_starts(found, args.trials, args.seed))
            row["eval_starts"] = {
                "trials": args.trials, "seed": args.seed, "starts_m": starts.round(4).tolist(),
                "routes": [f.to_dict() for f in found],
            }
        rows.append(row)
        ok &= report.route and lattice.steps is not None
    if args.json:
        out = {
            "model": str(model),
            "flight_config": args.flight_config,
            "clearance_m": env_cfg.shield.clearance_m,
            "primitive_scale_m": prims.scale_m,
            "max_steps": env_cfg.max_steps,
            "reports": rows,
        }
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    return 0 if ok else 1


def _describe_starts(found: list[LatticeRoute], trials: int, seed: int) -> str:
    steps = [f.steps for f in found if f.steps is not None]
    undecided = sum(not f.decided for f in found)
    text = (f"from the eval's {trials} starts (--trials {trials} --seed {seed}): a sequence from "
            f"{len(steps)}")
    if steps:
        text += f" ({min(steps)}-{max(steps)} steps)"
    return text + (f", {undecided} undecided" if undecided else "")


def _describe_lattice(lattice: LatticeRoute, scale_m: float, max_steps: int) -> str:
    if lattice.steps is not None:
        return (f"by {scale_m:g} m primitives, each keeping the margins from the true geometry: "
                f"the goal in {lattice.steps} steps (limit {max_steps})")
    if not lattice.decided:
        return f"by {scale_m:g} m primitives: undecided (the search stopped at {lattice.states} states)"
    return (f"by {scale_m:g} m primitives: no sequence that keeps the margins reaches the goal in "
            f"{max_steps} steps")
