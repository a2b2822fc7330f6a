"""``quadnav-sim serve``: the emulated PX4 as a standalone process, like PX4 SITL.

It sends MAVLink to UDP 127.0.0.1:14540 (the offboard API: ``udpin://0.0.0.0:14540``) and to
14550 (a ground station such as QGroundControl), prints what to connect to, logs the vehicle's
events and runs until SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "serve",
        help="run the emulated PX4 (MAVLink over UDP) in a world until Ctrl-C",
        description="Run the emulated PX4 quadrotor on real MAVLink 2 over UDP, flying in a world "
        "with real collisions. Connect MAVSDK with udpin://0.0.0.0:<api-port>.",
    )
    p.add_argument("--world", required=True, help="world YAML file or paper id (env04, 4)")
    p.add_argument("--api-port", type=int, default=14540, help="offboard API UDP port (default 14540)")
    p.add_argument("--gcs-port", type=int, default=14550,
                   help="ground-station UDP port (default 14550; 0 = none)")
    p.add_argument("--heartbeat-hz", type=float, default=None, help="HEARTBEAT rate (default 1 Hz, as PX4)")
    p.add_argument("--vision-only", action="store_true",
                   help="local position only from the companion's vision/mocap messages")
    p.add_argument("--config", default=None, metavar="YAML", help="EmulatorConfig YAML (PX4-like settings)")
    p.add_argument("--scenario", default=None, metavar="FAULTS.yaml", help="fault scenario to schedule")
    p.set_defaults(func=run)


def _port(value: int, name: str) -> int:
    if not 0 <= value <= 65535:
        raise ValueError(f"--{name}: {value} is not a UDP port (0..65535)")
    return value


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from quadnav_onboard.config import ConfigError, load_yaml_config
    from quadnav_onboard.logs import configure_logging, get_logger
    from sim_harness.px4 import EmulatorConfig, Px4Emulator
    from sim_harness.px4.scenario import apply_scenario, load_scenario
    from sim_harness.world import WorldError, load_world, resolve_world_arg

    configure_logging()
    log = get_logger("quadnav-sim.serve")
    try:
        world = load_world(resolve_world_arg(args.world))
        cfg = load_yaml_config(EmulatorConfig, args.config) if args.config else EmulatorConfig()
        overrides: dict[str, object] = {}
        if args.heartbeat_hz is not None:
            if not 0 < args.heartbeat_hz <= 100:
                raise ValueError(f"--heartbeat-hz: {args.heartbeat_hz} is not in (0, 100]")
            overrides["heartbeat_hz"] = args.heartbeat_hz
        if args.vision_only:
            overrides["vision_only"] = True
        cfg = dataclasses.replace(cfg, **overrides)
        scenario = load_scenario(args.scenario) if args.scenario else None
        api_port = _port(args.api_port, "api-port")
        gcs_port = _port(args.gcs_port, "gcs-port") or None
    except (ConfigError, WorldError, ValueError) as exc:
        print(f"quadnav-sim serve: {exc}", file=sys.stderr)
        return 2

    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    emu = Px4Emulator(world, cfg, api_port=api_port, gcs_port=gcs_port)
    try:
        emu.start()
        if scenario is not None:
            apply_scenario(emu.faults, scenario)
        start = emu.true_pose().pos_world_m
        print(f"quadnav-sim serve: emulated PX4 in world '{world.name}' ({Path(args.world)})")
        print(f"  offboard API : udpin://0.0.0.0:{api_port}   (MAVSDK: add_any_connection)")
        if gcs_port:
            print(f"  ground station: UDP {gcs_port} on 127.0.0.1 (QGroundControl listens there)")
        print(f"  heartbeat {cfg.heartbeat_hz:g} Hz, vision-only {cfg.vision_only}, start "
              f"{[round(float(v), 2) for v in start]} m (world x fwd, y left, z up; NED = x, -y, -z)")
        print("  Ctrl-C to stop.", flush=True)
        seen = 0
        while not stop.wait(0.2):
            events = emu.events
            for t, kind, message in events[seen:]:
                log.info("vehicle_event", kind=kind, message=message, t_mono_s=round(t, 3))
            seen = len(events)
    finally:
        emu.stop()
        for s, handler in previous.items():
            signal.signal(s, handler)
    print("quadnav-sim serve: stopped", flush=True)
    return 0
