"""``quadnav-sim serve``: the sim's vehicle side as standalone processes, like a vehicle on the bench.

The same parts ``quadnav-onboard --dry-run`` starts (:class:`sim_harness.vehicle_side.VehicleSide`):

* the emulated PX4, sending MAVLink to UDP 127.0.0.1:``--api-port`` (default 14640; PX4 SITL's
  14540 and 14580 are left alone, so a SITL left running never meets this emulator);
* the sim camera on the Unix socket ``<run dir>/depth.sock``;
* an emulated OptiTrack Motive (NatNet 3.0, unicast) on UDP ``--mocap-port`` (default 1510,
  Motive's), its frames to ``--mocap-port + 1``.

It prints what to connect to, logs the vehicle's events and runs until SIGINT/SIGTERM.
``config/serve.yaml`` flies the daemon against it (docs/emulator.md).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

__all__ = ["API_PORT", "MOCAP_PORT", "RUN_DIR", "add_parser", "run"]

API_PORT = 14640
"""Default offboard API port: not PX4 SITL's 14540 (where SITL sends) nor 14580 (where it listens)."""
MOCAP_PORT = 1510
"""Default NatNet command port (Motive's); frames go to the next port."""
RUN_DIR = "/tmp/quadnav-sim"
"""Default folder of the camera's socket and the parts' logs."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "serve",
        help="run the sim's vehicle side (emulated PX4, camera, mocap) until Ctrl-C",
        description="Run the sim's vehicle side, each part its own process: the emulated PX4 quadrotor "
        "on real MAVLink 2 over UDP (MAVSDK: udpin://0.0.0.0:<api-port>), the sim D435 on a Unix "
        "socket, and an emulated OptiTrack Motive (NatNet) streaming the true pose.",
    )
    p.add_argument("--world", required=True, help="world YAML file or paper id (env04, 4)")
    p.add_argument("--api-port", type=int, default=API_PORT,
                   help=f"offboard API UDP port (default {API_PORT}; PX4 SITL uses 14540)")
    p.add_argument("--gcs-port", type=int, default=0,
                   help="also send to this ground-station UDP port, e.g. 14550 for QGroundControl "
                   "(default: none)")
    p.add_argument("--mocap-port", type=int, default=MOCAP_PORT,
                   help=f"NatNet command port (default {MOCAP_PORT}); frames go to the next port")
    p.add_argument("--run-dir", default=RUN_DIR,
                   help=f"folder of the camera socket and the logs (default {RUN_DIR})")
    p.add_argument("--no-camera", action="store_true", help="no sim camera")
    p.add_argument("--no-mocap", action="store_true", help="no emulated Motive (fly on PX4's estimate)")
    p.add_argument("--heartbeat-hz", type=float, default=None, help="HEARTBEAT rate (default 1 Hz, as PX4)")
    p.add_argument("--vision-only", action="store_true",
                   help="local position only from the companion's vision/mocap messages")
    p.add_argument("--config", default=None, metavar="YAML", help="EmulatorConfig YAML (PX4-like settings)")
    p.add_argument("--scenario", default=None, metavar="FAULTS.yaml", help="fault scenario to schedule")
    p.set_defaults(func=run)


def _port(value: int, name: str, allow_zero: bool = False) -> int:
    if not (0 if allow_zero else 1) <= value <= 65535:
        raise ValueError(f"--{name}: {value} is not a UDP port ({0 if allow_zero else 1}..65535)")
    return value


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from quadnav_onboard.config import ConfigError, load_yaml_config
    from sim_harness.px4 import EmulatorConfig
    from sim_harness.px4.scenario import load_scenario
    from sim_harness.sidecar import set_on_signals
    from sim_harness.vehicle_side import StartCancelled, VehicleSide, VehicleSideError
    from sim_harness.world import WorldError, load_world, resolve_world_arg

    try:
        world_path = resolve_world_arg(args.world)
        world = load_world(world_path)
        cfg = load_yaml_config(EmulatorConfig, args.config) if args.config else EmulatorConfig()
        overrides: dict[str, object] = {}
        if args.heartbeat_hz is not None:
            if not 0 < args.heartbeat_hz <= 100:
                raise ValueError(f"--heartbeat-hz: {args.heartbeat_hz} is not in (0, 100]")
            overrides["heartbeat_hz"] = args.heartbeat_hz
        if args.vision_only:
            overrides["vision_only"] = True
        cfg = dataclasses.replace(cfg, **overrides)
        if args.scenario:
            load_scenario(args.scenario)  # refuse a bad file here, before anything starts
        api_port = _port(args.api_port, "api-port")
        gcs_port = _port(args.gcs_port, "gcs-port", allow_zero=True) or None
        mocap_port = _port(args.mocap_port, "mocap-port")
        if mocap_port == 65535:
            raise ValueError("--mocap-port: 65535 leaves no port for the frames (the next port)")
        run_dir = Path(args.run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
    except (ConfigError, WorldError, ValueError, OSError) as exc:
        print(f"quadnav-sim serve: {exc}", file=sys.stderr)
        return 2

    parts = ("vehicle",) + (() if args.no_camera else ("camera",)) + (() if args.no_mocap else ("mocap",))
    side = VehicleSide(
        world_path,
        api_port=api_port,
        gcs_port=gcs_port,
        emulator=overrides,
        emulator_config=args.config,
        mocap={"command_port": mocap_port, "data_port": mocap_port + 1},
        scenario=args.scenario,
        parts=parts,
        run_dir=run_dir,
    )
    stop = threading.Event()
    previous = set_on_signals(stop)
    print(f"quadnav-sim serve: the sim's vehicle side in world '{world.name}' ({world_path})")
    print(f"  vehicle (emulated PX4): udpin://0.0.0.0:{api_port}   (MAVSDK; vehicle.url)", flush=True)
    try:
        try:
            side.start(cancel=stop)  # a signal while the parts warm up stops them all
        except StartCancelled:
            print("quadnav-sim serve: stopped", flush=True)
            return 0
        except VehicleSideError as exc:
            print(f"quadnav-sim serve: {exc}", file=sys.stderr)
            return 2
        start = side.parts["vehicle"].info.get("start_m")
        if gcs_port:
            print(f"  ground station: UDP {gcs_port} on 127.0.0.1 (QGroundControl listens there)")
        if "camera" in side.parts:
            print(f"  camera (424x240 depth, 30 fps): {side.depth_socket}   (depth.kind: socket)")
        if "mocap" in side.parts:
            host, port = side.mocap_command
            print(f"  mocap (OptiTrack NatNet, y-up): {host}:{port}   (odometry.kind: mocap, optitrack)")
        print(f"  heartbeat {cfg.heartbeat_hz:g} Hz, vision-only {cfg.vision_only}, start {start} m "
              f"(world x fwd, y left, z up); logs in {run_dir}")
        print("  Ctrl-C to stop.", flush=True)
        while not stop.wait(0.5):
            dead = [name for name, part in side.parts.items() if part.process.poll() is not None]
            if dead:
                print(f"quadnav-sim serve: part(s) {', '.join(dead)} stopped; see {run_dir}", file=sys.stderr)
                return 1
    finally:
        side.stop()
        for s, handler in previous.items():
            signal.signal(s, handler)
    print("quadnav-sim serve: stopped", flush=True)
    return 0

