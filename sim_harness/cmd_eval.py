"""``quadnav-sim eval``: fly a checkpoint greedily in worlds and print the paper's table."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from quadnav_onboard.policy import Policy
    from quadnav_onboard.shield import ShieldConfig
    from sim_harness.env import EnvConfig
    from sim_harness.noise import DepthNoise
    from sim_harness.rl.evaluate import FlightLimits
    from sim_harness.world import World

__all__ = [
    "Flights",
    "add_flight_flags",
    "add_flights_flags",
    "add_parser",
    "at_flight_scale",
    "count_arg",
    "flight_setup",
    "flights_from_flags",
    "load_flights",
    "run",
    "seed_arg",
    "shield_from_flags",
    "shown_path",
    "sim_env_config",
    "worlds_from_flags",
]


def shield_from_flags(policy: Policy, args: argparse.Namespace) -> ShieldConfig:
    """The filter to fly ``policy`` with, by ``--shield`` and ``--shield-set`` (see
    :func:`add_flight_flags`); raises ConfigError/ValueError on a bad override."""
    from quadnav_onboard.shield import shield_config_from_meta
    from sim_harness.rl.evaluate import override_shield

    shield = shield_config_from_meta(policy.checkpoint.meta)
    if args.shield != "model":
        shield = dataclasses.replace(shield, enabled=args.shield == "on")
    return override_shield(shield, args.shield_set)


def at_flight_scale(
    env_cfg: EnvConfig, worlds: list[World], args: argparse.Namespace, max_steps: int | None = None
) -> tuple[EnvConfig, list[World]]:
    """The env and worlds at ``--primitive-scale`` (default: the checkpoint's own, ``env_cfg``'s);
    unchanged at the scale world files are written for."""
    from sim_harness.env import REFERENCE_SCALE_M, at_primitive_scale

    scale = args.primitive_scale if args.primitive_scale is not None else env_cfg.primitives.scale_m
    if scale == REFERENCE_SCALE_M:
        return env_cfg, worlds
    return at_primitive_scale(env_cfg, worlds, scale, max_steps)


def worlds_from_flags(args: argparse.Namespace) -> tuple[list[World], list[Path | str]]:
    """The worlds of ``--world`` (repeated) or ``--procedural N --procedural-seed P`` (default: the
    ten paper worlds), each with where it came from; raises WorldError on a bad world."""
    from sim_harness.world import load_world, paper_world_path, resolve_world_arg

    if args.procedural is not None:
        from sim_harness.procgen import procedural_worlds

        worlds = procedural_worlds(args.procedural, args.procedural_seed)
        return worlds, [f"<procgen {w.name} seed {args.procedural_seed}>" for w in worlds]
    paths: list[Path | str] = (
        [resolve_world_arg(w) for w in args.world]
        if args.world
        else [paper_world_path(i) for i in range(1, 11)]
    )
    return [load_world(p) for p in paths], paths


def sim_env_config(
    policy: Policy, args: argparse.Namespace, worlds: list[World]
) -> tuple[EnvConfig, list[World]]:
    """The env and worlds of an eval without a flight config: ``--shield``/``--shield-set``,
    ``--start-jitter-m`` (default 0.5), ``--max-steps`` (default 120) and ``--primitive-scale``."""
    from sim_harness.rl.evaluate import env_config_for_policy

    jitter = 0.5 if args.start_jitter_m is None else args.start_jitter_m
    env_cfg = env_config_for_policy(
        policy, max_steps=args.max_steps or 120, start_jitter_m=jitter, shield=shield_from_flags(policy, args)
    )
    return at_flight_scale(env_cfg, worlds, args, args.max_steps)


def flight_setup(
    policy: Policy, args: argparse.Namespace, worlds: list[World], paths: list[Path | str]
) -> tuple[EnvConfig, list[World], FlightLimits]:
    """``--flight-config``: the flight's mission in ``worlds`` (each checked against the config as
    the daemon checks the path it flies), with ``--shield``/``--shield-set`` applied on top."""
    from quadnav_onboard.daemon.config import check_mission_path, load_flight_config
    from sim_harness.rl.evaluate import flight_eval_setup, override_shield

    flight = load_flight_config(args.flight_config, require_waypoints=False)
    env_cfg, flown, limits = flight_eval_setup(policy, flight, worlds, args.start_jitter_m)
    for w, p in zip(flown, paths, strict=True):
        where = "mission.waypoints_m" if flight.mission.waypoints_m is not None else f"{p} path.waypoints"
        check_mission_path(flight, w.path, args.flight_config, where)
    shield = env_cfg.shield
    if args.shield != "model":
        shield = dataclasses.replace(shield, enabled=args.shield == "on")
    shield = override_shield(shield, args.shield_set)
    return dataclasses.replace(env_cfg, shield=shield), flown, limits


@dataclasses.dataclass(frozen=True)
class Flights:
    """What an eval flies, from its flags: the env, the worlds, and under ``--flight-config`` the
    flight's stop conditions and the depth noise."""

    env_config: EnvConfig
    worlds: list[World]
    limits: FlightLimits | None
    depth_noise: DepthNoise | None
    sources: list[Path | str]
    """Where each world given came from (``--world``'s files; the rooms, with ``--layouts``)."""


def flights_from_flags(policy: Policy, args: argparse.Namespace) -> Flights:
    """The flights of ``quadnav-sim eval`` with ``args`` (also read by the scripts that replay
    them): ``--world``/``--procedural``, ``--flight-config`` (its limits and, unless
    ``--depth-noise off``, the depth noise; ``--layouts`` of its rooms) or the sim's env
    (:func:`sim_env_config`). Raises ValueError on flags that do not go together, WorldError and
    ConfigError on bad files."""
    if args.world and args.procedural is not None:
        raise ValueError("give --world or --procedural N, not both")
    flight_config = args.flight_config
    if flight_config and (args.primitive_scale is not None or args.max_steps is not None):
        raise ValueError("--flight-config sets the primitives and the step limit: not with "
                         "--primitive-scale or --max-steps")
    if args.layouts is not None and not (flight_config and args.world):
        raise ValueError("--layouts N needs --flight-config and the room as --world")
    worlds, paths = worlds_from_flags(args)
    limits = None
    if flight_config:
        env_cfg, worlds, limits = flight_setup(policy, args, worlds, paths)
        if args.layouts is not None:
            worlds = _layouts(env_cfg, worlds, limits, args.layouts, args.layout_seed)
    else:
        env_cfg, worlds = sim_env_config(policy, args, worlds)
    noise = None
    if args.depth_noise == "on" or (args.depth_noise == "auto" and flight_config):
        from sim_harness.noise import DepthNoise

        noise = DepthNoise()
    return Flights(env_cfg, worlds, limits, noise, paths)


def load_flights(
    prog: str, model: str | Path | None, args: argparse.Namespace
) -> tuple[Policy, Flights] | None:
    """The checkpoint ``model`` (None: the shipped model) and :func:`flights_from_flags`; on bad
    input (a checkpoint, a world, a flight config, flags) prints ``prog: what is wrong`` to stderr
    and returns None."""
    from quadnav_onboard.checkpoint import CheckpointError
    from quadnav_onboard.config import ConfigError
    from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy
    from sim_harness.world import WorldError

    try:
        policy = Policy.from_path(DEFAULT_MODEL_PATH if model is None else model)
        return policy, flights_from_flags(policy, args)
    except (CheckpointError, WorldError, ConfigError, ValueError) as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return None


def shown_path(source: Path | str) -> str:
    """A model or world as an eval file names it: a path under the working directory relative to
    it (run from the repository root, the same on every machine), any other path as it is, a
    label (a generated world) unchanged."""
    if not isinstance(source, Path):
        return source
    try:
        return source.resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return str(source)


def _layouts(env_cfg: EnvConfig, rooms: list[World], limits: FlightLimits, n: int, seed: int) -> list[World]:
    """``n`` random layouts of each room, each with a route that keeps the filter's margins."""
    from sim_harness.rl.lab_task import flight_layouts

    return [w for room in rooms for w in flight_layouts(room, env_cfg, limits, n, seed)]


def _positive(text: str) -> float:
    value = float(text)
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be > 0 and finite, got {text}")
    return value


def _non_negative(text: str) -> float:
    value = float(text)
    if not (value >= 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be >= 0 and finite, got {text}")
    return value


def seed_arg(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number in [0, 2**32), got {text}") from None
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"must be in [0, 2**32), got {text}")
    return value


def count_arg(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text}")
    return value


def add_flight_flags(p: argparse.ArgumentParser, shield_default: str) -> None:
    """How the flights are flown, shared by ``eval`` and ``select``: the filter and the scale."""
    p.add_argument(
        "--primitive-scale",
        type=_positive,
        default=None,
        metavar="M",
        help="fly primitives of M metres per axis, the moving setpoint slowed to match (real flights: "
        "0.5, as in the paper); default: the checkpoint's",
    )
    p.add_argument(
        "--shield",
        choices=("model", "on", "off"),
        default=shield_default,
        help="depth safety filter: as the checkpoint says (model), forced on with the checkpoint's "
        f"settings (the defaults if it has none) or off; default: {shield_default}",
    )
    p.add_argument(
        "--shield-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one ShieldConfig field of the filter flown (repeatable; e.g. clearance_m=0.55)",
    )


def add_flights_flags(p: argparse.ArgumentParser, shield_default: str, trials_default: int,
                      trials_note: str = "") -> None:
    """The flags that say which flights an eval flies (:func:`flights_from_flags`), shared by
    ``quadnav-sim eval`` and the scripts that replay its flights (the census, the trace)."""
    p.add_argument(
        "--model", default=None, help="checkpoint (default: the shipped quadnav_onboard/models/default.pt)"
    )
    p.add_argument(
        "--world",
        action="append",
        default=None,
        metavar="WORLD",
        help="world YAML file or paper id (env04, 4); repeat for more (default: the ten paper worlds)",
    )
    p.add_argument(
        "--procedural",
        type=count_arg,
        default=None,
        metavar="N",
        help="fly N >= 1 procedurally generated worlds of the paper's families instead of --world "
        "(never trained on unless their seed is the training one; see --procedural-seed)",
    )
    p.add_argument(
        "--procedural-seed",
        type=seed_arg,
        default=4242,
        help="seed of the generated worlds (default 4242; training uses 20261124)",
    )
    p.add_argument("--trials", type=count_arg, default=trials_default,
                   help=f"trials per world (default {trials_default}{trials_note})")
    p.add_argument(
        "--seed",
        type=seed_arg,
        default=0,
        help="seed of the start jitter (default 0); the i-th world of the list (from 0) flies with seed "
        "1009 * SEED + i, so a world flown alone draws other starts than in a longer list",
    )
    p.add_argument(
        "--start-jitter-m",
        type=_non_negative,
        default=None,
        metavar="M",
        help="half-width of the random start offset per axis (default 0.5, with --flight-config its "
        "mission.start_tolerance_m; 0: every trial starts on the path's start, as the dry run does)",
    )
    p.add_argument(
        "--max-steps",
        type=count_arg,
        default=None,
        help="step limit per flight (default 120, scaled with --primitive-scale)",
    )
    add_flight_flags(p, shield_default=shield_default)
    p.add_argument(
        "--flight-config",
        default=None,
        metavar="FLIGHT.yaml",
        help="fly each world under this flight config's mission (config/flight.yaml: its primitives, "
        "speed, step limit, goal radius, deviation limit, waypoints when set, filter) with its "
        "geofence and altitude band as stop conditions (safe, not a goal) and known to the filter; "
        "not with --primitive-scale or --max-steps; --start-jitter-m defaults to its start_tolerance_m",
    )
    p.add_argument(
        "--depth-noise",
        choices=("auto", "on", "off"),
        default="auto",
        help="the D435-like depth noise model (sim_harness/noise.py) on the camera's frames; "
        "auto: on with --flight-config, else off",
    )
    p.add_argument(
        "--layouts",
        type=count_arg,
        default=None,
        metavar="N",
        help="with --flight-config: fly N >= 1 random box layouts of each --world's room instead of "
        "the world (sim_harness/lab_layouts.py: 0-2 boxes near the path, each with a sequence of "
        "primitives that keeps the filter's margins to the goal); see --layout-seed",
    )
    p.add_argument(
        "--layout-seed",
        type=seed_arg,
        default=4242,
        help="seed of the layouts (default 4242; recipes/lab.yaml trains on 20261203)",
    )


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "eval",
        help="evaluate a checkpoint: the paper's table per world and trial, then success rates",
        description="Evaluate a checkpoint greedily. Prints navigation distance, time, crash, total "
        "reward and outcome per world and trial, then the success and collision-free rates.",
    )
    add_flights_flags(p, shield_default="model", trials_default=5, trials_note=", as in the paper")
    p.add_argument("--json", default=None, metavar="OUT",
                   help="also write the rows (one per flight: the table's columns and start_m, "
                        "where it started) and the summary as JSON")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from quadnav_onboard.policy import DEFAULT_MODEL_PATH
    from sim_harness.rl.evaluate import FilterOverrules, evaluate, format_table, policy_greedy_fn, summarize

    model = Path(args.model) if args.model else DEFAULT_MODEL_PATH
    loaded = load_flights("quadnav-sim eval", model, args)
    if loaded is None:
        return 2
    policy, flights = loaded
    env_cfg, worlds, limits = flights.env_config, flights.worlds, flights.limits
    noise, paths = flights.depth_noise, flights.sources
    bar = tqdm(total=len(worlds), desc="eval", unit="world", disable=args.no_progress, file=sys.stderr)
    overrules = FilterOverrules()
    rows = evaluate(
        policy_greedy_fn(policy),
        worlds,
        args.trials,
        args.seed,
        env_cfg,
        on_world_done=lambda _w: bar.update(1),
        limits=limits,
        depth_noise=noise,
        overrules=overrules,
    )
    bar.close()
    summary = summarize(rows)
    print(format_table(rows))
    print()
    print(
        f"trials {summary['trials']}: success {summary['success_rate']:.1%}, collision-free "
        f"{summary['collision_free_rate']:.1%}, "
        f"success among safe flights {summary['success_among_safe']:.1%}"
    )
    if overrules.decisions:
        print(f"the filter overruled the DQN's first choice in {overrules.overruled} of "
              f"{overrules.decisions} decisions ({overrules.rate:.1%})")
    if args.json:
        out = {
            "model": shown_path(model),
            "model_sha256": policy.checkpoint.sha256,
            "trials": args.trials,
            "seed": args.seed,
            "start_jitter_m": env_cfg.start_jitter_m,
            "max_steps": env_cfg.max_steps,
            "primitive_scale_m": env_cfg.primitives.scale_m,
            "shield": dataclasses.asdict(env_cfg.shield),
            "flight_config": args.flight_config,
            "layouts": args.layouts,
            "layout_seed": args.layout_seed if args.layouts is not None else None,
            "depth_noise": None if noise is None else dataclasses.asdict(noise),
            "known_rooms": True,
            "worlds": [shown_path(p) for p in paths],
            "rows": [r.to_dict() for r in rows],
            "summary": summary,
            "filter_overrules": overrules.to_dict() if overrules.decisions else None,
        }
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2), encoding="utf-8")
        print(f"wrote {args.json}")
    return 0
