"""``quadnav-sim show WORLD [--pose X Y Z YAW_DEG] [-o OUT.png]``: a PNG of a world.

WORLD is a world YAML file or a paper world id (``env04``, ``4``); ``all`` draws the ten paper
worlds into the directory given by ``-o``. With ``--pose`` the picture adds the depth image the
camera sees there and the network's 32x32 input.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

__all__ = ["add_parser"]

_CAMERAS = ("424x240", "848x480")


def _run(args: argparse.Namespace) -> int:
    from sim_harness import render
    from sim_harness.show import save_world_png
    from sim_harness.world import WorldError, load_world, paper_world_path, resolve_world_arg

    camera = render.D435_424x240 if args.camera == "424x240" else render.D435_848x480
    pose = None if args.pose is None else np.array(args.pose[:3], dtype=np.float64)
    yaw = 0.0 if args.pose is None else math.radians(args.pose[3])
    try:
        if args.world == "all":
            jobs = [(load_world(paper_world_path(i)), None) for i in range(1, 11)]
        else:
            jobs = [(load_world(resolve_world_arg(args.world)), args.output)]
    except WorldError as exc:
        print(f"quadnav-sim show: error: {exc}", file=sys.stderr)
        return 2
    for world, out in jobs:
        if out is None:
            out = f"{args.output or '.'}/{world.name}.png" if args.world == "all" else f"{world.name}.png"
        written = save_world_png(world, out, pose, yaw, camera)
        print(written)
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("show", help="draw a world (top and side views, optional camera view) as PNG",
                              description="Draw a world (top and side views; with --pose, also the camera's "
                              "depth image and the 32x32 network input) as a PNG.")
    p.add_argument("world", metavar="WORLD", help="world YAML file, paper world id (env04), or 'all'")
    p.add_argument("--pose", nargs=4, type=float, metavar=("X", "Y", "Z", "YAW_DEG"),
                   help="also render the depth camera at this pose (world m, yaw deg)")
    p.add_argument("-o", "--output", metavar="OUT.png",
                   help="PNG to write (default: <world name>.png); a directory with 'all'")
    p.add_argument("--camera", choices=_CAMERAS, default="424x240", help="D435 depth resolution")
    p.set_defaults(func=_run)
