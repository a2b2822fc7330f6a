"""``quadnav-onboard``: the flight daemon's command line.

Exit codes (see :class:`quadnav_onboard.daemon.supervisor.ExitCode` and docs/daemon.md):
0 goal reached; 1 internal error; 2 refused before arming (bad config, model or pre-flight check);
3 safe abort (supervisor or operator stop: ended holding or landed); 4 crash.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

from quadnav_onboard.sdnotify import SdNotifier
from quadnav_onboard.trigger import MissionTriggerConfig, trigger_config_from_mapping

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadnav-onboard",
        description="Fly a quadrotor with the quadnav DQN planner through PX4 (MAVSDK offboard).",
        epilog="exit codes: 0 goal reached, 1 internal error, 2 refused before arming, 3 safe abort, 4 crash",
    )
    p.add_argument("--config", metavar="FLIGHT.yaml", help="flight configuration (see config/flight.yaml)")
    p.add_argument(
        "--dry-run",
        action="store_true",
        help="fly in the sim harness: the config's mission, limits and filter; a config naming real "
        "hardware (a uvc camera or a serial autopilot, config/flight.yaml) gets the sim's vehicle, "
        "depth (with the D435-like noise), odometry, trigger and record directory (docs/hardware.md)",
    )
    p.add_argument(
        "--world",
        metavar="WORLD.yaml",
        help="with --dry-run: world file to fly, or a shipped world's name (lab02; default: Env 1)",
    )
    p.add_argument(
        "--in-process",
        action="store_true",
        help="with --dry-run: run the sim's vehicle, camera and mocap inside the daemon's process "
        "(for tests; the default runs each as its own process, as on a vehicle)",
    )
    p.add_argument(
        "--px4-sitl",
        nargs="?",
        const=14550,
        type=int,
        metavar="PORT",
        help="with --dry-run: fly the PX4 SITL you started (the config's vehicle.url, e.g. "
        "config/px4-sitl.yaml) through the world; the sim camera (and mocap) render from the state "
        "PX4 reports on UDP PORT (default 14550, PX4's GCS link; sys_test/README.md)",
    )
    p.add_argument("--model", metavar="CKPT.pt", help="checkpoint to fly (overrides model_path)")
    p.add_argument("--json", action="store_true", help="print the flight summary as one JSON object")
    p.add_argument(
        "--record-dir", metavar="DIR", help="write the flight record here (overrides record.directory)"
    )
    p.add_argument("--no-record", action="store_true", help="do not write a flight record")
    p.add_argument(
        "--log-format", choices=("auto", "json", "console"), default="auto", help="log format (stderr)"
    )
    p.add_argument(
        "--print-config",
        action="store_true",
        help="print every flight-config key with its default, type, range, unit and meaning as a "
        "commented YAML, and exit (docs/configuration.md is the same as tables)",
    )
    return p


def _fail(msg: str) -> int:
    print(f"quadnav-onboard: {msg}", file=sys.stderr)
    return 2


def _open_recorder(cfg: Any, metadata: dict[str, str]) -> Any:
    if not cfg.record.enabled:
        return None
    from quadnav_onboard.record.recorder import FlightRecorder

    return FlightRecorder.new_in(  # a new file, named by the start time; never over another
        cfg.record.directory,
        metadata=metadata,
        depth_decimation=cfg.record.depth_decimation,
        writer=cfg.record.writer,
    )


def main(argv: list[str] | None = None) -> int:
    t_start_mono_s = time.monotonic()
    args = build_parser().parse_args(argv)
    if args.print_config:
        from quadnav_onboard.config_reference import flight_config_yaml

        sys.stdout.write(flight_config_yaml())
        return 0
    from quadnav_onboard.logs import configure_logging

    configure_logging(json={"auto": None, "json": True, "console": False}[args.log_format])
    from quadnav_onboard.checkpoint import CheckpointError
    from quadnav_onboard.config import ConfigError
    from quadnav_onboard.daemon.config import (
        default_sim_config,
        dry_run_config,
        flies_hardware,
        load_flight_config,
    )
    from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy

    if args.world and not args.dry_run:
        return _fail("--world needs --dry-run")
    if args.in_process and not args.dry_run:
        return _fail("--in-process needs --dry-run")
    if args.px4_sitl is not None and (not args.dry_run or args.in_process or not args.config):
        return _fail("--px4-sitl needs --dry-run and --config (e.g. config/px4-sitl.yaml), not --in-process")
    if not args.config and not args.dry_run:
        return _fail("give --config FLIGHT.yaml, or --dry-run to fly the simulator")
    source = args.config or "<embedded defaults/sim.yaml>"
    try:
        cfg = (
            load_flight_config(args.config, require_waypoints=not args.dry_run)
            if args.config
            else default_sim_config()
        )
        args.depth_noise = bool(args.dry_run and flies_hardware(cfg))
        if args.dry_run:
            cfg = dry_run_config(cfg)
        if args.record_dir:
            cfg = replace(cfg, record=replace(cfg.record, directory=args.record_dir))
        if args.no_record:
            cfg = replace(cfg, record=replace(cfg.record, enabled=False))
        trigger = _trigger_config(cfg, source, simulated=args.dry_run)
    except ConfigError as exc:
        return _fail(f"configuration error:\n{exc}")
    model_path = Path(args.model or cfg.model_path or DEFAULT_MODEL_PATH)
    try:
        policy = Policy.from_path(model_path)
    except CheckpointError as exc:
        return _fail(f"model refused: {exc}")
    except ConfigError as exc:
        return _fail(f"model refused: {model_path}: {exc}")
    try:
        n_prims = (cfg.primitives or policy.primitive_config()).build().n_actions
    except (ConfigError, ValueError) as exc:
        return _fail(f"model refused: {model_path}: bad action set: {exc}")
    if policy.n_actions != n_prims:
        return _fail(f"model refused: {model_path}: {policy.n_actions} outputs, the action set has {n_prims}")
    try:
        summary = _fly(args, cfg, policy, trigger, model_path, t_start_mono_s)
    except ConfigError as exc:
        return _fail(f"configuration error:\n{exc}")
    except (ValueError, OSError) as exc:  # a bad world file, a device that cannot open: no traceback
        return _fail(f"cannot start: {exc}")
    except Exception as exc:  # a bug: keep the traceback in the log
        from quadnav_onboard.logs import get_logger

        get_logger("quadnav.cli").exception("startup_failed")
        print(f"quadnav-onboard: internal error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(summary.to_dict(), allow_nan=False, default=str))
    else:
        print(summary.paper_row())
        for line in summary.latency_lines():
            print(line)
    return summary.exit_code


def _trigger_config(cfg: Any, source: str, *, simulated: bool) -> MissionTriggerConfig:
    # No fallback: a missing trigger would read as "auto", i.e. a vehicle that starts by itself.
    return trigger_config_from_mapping(cfg.trigger, source=source, simulated=simulated)


def _notifier() -> SdNotifier:
    return SdNotifier.from_env()


def _check_mission_path(args: argparse.Namespace, cfg: Any, path: Any, world: str | None) -> None:
    """The mission against the path flown (the config's waypoints, or the dry run's world): raises
    ConfigError naming the file, the key and the value (a goal radius reaching back to the start, a
    waypoint outside the geofence or the altitude band)."""
    from quadnav_onboard.daemon.config import check_mission_path

    source = args.config or "<embedded defaults/sim.yaml>"
    from_config = cfg.mission.waypoints_m is not None or world is None
    check_mission_path(cfg, path, source, "mission.waypoints_m" if from_config else f"{world} path.waypoints")


def _fly(
    args: argparse.Namespace, cfg: Any, policy: Any, trigger: Any, model_path: Path, t_start_mono_s: float
) -> Any:
    import torch

    from quadnav_onboard.daemon.app import FlightDaemon
    from quadnav_onboard.daemon.config import room_aware_shield
    from quadnav_onboard.record.flight import describe_flight

    torch.set_num_threads(1)
    room = None
    if args.dry_run:
        from quadnav_onboard.daemon.dryrun import DryRun

        room = DryRun(cfg, args.world).world.room_box_m()  # reads the world file only
    cfg = replace(cfg, shield=room_aware_shield(cfg, policy.checkpoint.meta, room))
    meta = {
        "model_path": str(model_path),
        "model_sha256": policy.checkpoint.sha256,
        "dry_run": str(bool(args.dry_run)),
    }
    world = None  # the dry run's world (a world-file mapping), drawn in the record's 3-D scene
    with contextlib.ExitStack() as stack:
        if args.dry_run:
            from quadnav_onboard.daemon.dryrun import DryRun, ProcessDryRun

            wiring = DryRun if args.in_process else ProcessDryRun
            sitl = None if args.px4_sitl is None else {"port": args.px4_sitl}
            noise = getattr(args, "depth_noise", False)
            sim = stack.enter_context(wiring(cfg, args.world, sitl=sitl, depth_noise=noise))
            cfg = sim.cfg
            parts = sim.parts()
            meta["world"] = str(sim.world_path)
            from sim_harness.world import world_to_mapping

            world = world_to_mapping(sim.world)
        else:
            from quadnav_onboard.daemon.hardware import hardware_parts

            parts = hardware_parts(cfg, args.config or "config")
        _check_mission_path(args, cfg, parts["path"], meta.get("world"))
        # The deviation limit round the path flown is known space to the filter, as in the eval.
        band = cfg.shield.with_band(parts["path"].waypoints_m, cfg.safety.max_deviation_m)
        cfg = replace(cfg, shield=band)
        meta["config"] = json.dumps(asdict(cfg), default=str)
        recorder = _open_recorder(cfg, meta)
        if recorder is not None:
            with contextlib.suppress(Exception):
                recorder.rough_path(time.monotonic(), parts["path"].waypoints_m)
                describe_flight(recorder, cfg, policy, world)
        daemon = FlightDaemon(
            cfg,
            policy=policy,
            recorder=recorder,
            notifier=_notifier(),
            trigger=trigger,
            t_start_mono_s=t_start_mono_s,
            **parts,
        )
        return asyncio.run(daemon.run())


if __name__ == "__main__":
    sys.exit(main())
