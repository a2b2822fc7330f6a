#!/usr/bin/env python3
"""Run a ``quadnav-sim`` command with the sim camera's field of view replaced (an experiment).

The sim renders the network's 32x32 input through a D435's depth field of view (87 x 58 deg), the
camera the product flies. The paper trained in AirSim, whose camera, set to a square image, sees
90 deg both ways (our reading: the paper states 32x32 but no field of view). This wrapper answers
"would the paper's recipe learn the up-down slaloms with the taller view?" without a flag the
product could fly by mistake: it patches the training/eval renderer for this process only. A model
trained this way must be evaluated through this wrapper too, and never shipped: it has not seen
what a D435 sees.

Usage:  python scripts/with_camera_fov.py --hfov 90 --vfov 90 -- train --name X --seed S [...]
        python scripts/with_camera_fov.py --hfov 90 --vfov 90 -- eval --model M [...]
"""

from __future__ import annotations

import argparse
import functools
import math
import sys

import sim_harness.env as sim_env
from sim_harness.cli import main as sim_main
from sim_harness.render import CameraModel, render_inputs


def patch_camera(hfov_deg: float, vfov_deg: float) -> CameraModel:
    """Make the env's renderer use a camera of the given field of view (240 rows, square pixels)."""
    if not (0 < hfov_deg < 180 and 0 < vfov_deg < 180):
        raise SystemExit(f"fields of view must be in (0, 180) deg, got --hfov {hfov_deg} --vfov {vfov_deg}")
    aspect = math.tan(math.radians(hfov_deg) / 2) / math.tan(math.radians(vfov_deg) / 2)
    width = max(1, round(240 * aspect))  # square pixels: the image plane's aspect, not the angles'
    camera = CameraModel(width, 240, hfov_deg, vfov_deg)
    sim_env.render_inputs = functools.partial(render_inputs, camera=camera)  # type: ignore[assignment]
    return camera


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--" not in argv:
        raise SystemExit("usage: with_camera_fov.py --hfov H --vfov V -- <quadnav-sim command and flags>")
    split = argv.index("--")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hfov", type=float, required=True, help="horizontal field of view (deg)")
    parser.add_argument("--vfov", type=float, required=True, help="vertical field of view (deg)")
    args = parser.parse_args(argv[:split])
    camera = patch_camera(args.hfov, args.vfov)
    print(f"sim camera patched: {camera.width}x{camera.height}, {camera.hfov_deg} x {camera.vfov_deg} deg",
          file=sys.stderr)
    return sim_main(argv[split + 1:])


if __name__ == "__main__":
    sys.exit(main())
