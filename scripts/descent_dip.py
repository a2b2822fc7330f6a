#!/usr/bin/env python3
"""How far below its start a descent takes the vehicle, whatever primitive follows it.

Every descent primitive from rest is flown by the sim's vehicle (``sim_harness.quad``), then each
of the 18 primitives after it; the script reports the lowest point below the start for each kind
of second primitive (down, level, up). It is the physics behind the filter's cap at 1 m in
docs/results.md: under a ceiling at ``--ceiling-m`` over a floor at 0, keeping ``--clearance-m``
from both leaves the vehicle's centre a band of heights; a level pass under the ceiling needs
the centre at or below the band's top, and a descent taken to get there keeps the floor clearance
only from a start at least ``clearance + least dip`` up. Starts between the band's top and that
height cannot pass with any sequence of primitives (climbing back ends above the band's top).

Usage:  python scripts/descent_dip.py [--primitive-scale 1.0] [--ceiling-m 2.10] [--clearance-m 0.5]
            [--json OUT]

The defaults are Env 7's hanging panels (undersides 2.10 m up) and the filter's clearance.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def lowest_after_descents(scale_m: float) -> dict[str, dict[str, float]]:
    """For each kind of second primitive (down, level, up), the least and the greatest drop (m)
    below the start over every descent followed by every primitive of that kind."""
    from quadnav_onboard.primitives import DEFAULT_DIRECTIONS, PrimitiveSet, bezier_position, bezier_velocity
    from sim_harness.quad import QuadParams, QuadState, track

    prims, q = PrimitiveSet(scale_m=scale_m), QuadParams()
    k = round(prims.duration_s / q.dt_s)
    u = (np.arange(1, k + 1) / k)[:, None]
    drops: dict[str, list[float]] = {"down": [], "level": [], "up": []}
    kinds = {-1: "down", 0: "level", 1: "up"}
    for first in (a for a, d in enumerate(DEFAULT_DIRECTIONS) if d[2] < 0):
        c1 = prims.control_points(np.array([first]), np.zeros((1, 3)))
        state, t1 = track(
            QuadState(np.zeros((1, 3)), np.zeros((1, 3))), bezier_position(c1, u),
            bezier_velocity(c1, u, prims.duration_s), q,
        )
        for second, d in enumerate(DEFAULT_DIRECTIONS):
            c2 = prims.control_points(np.array([second]), prims.end_velocity_m_s(np.array([first])))
            _, t2 = track(
                QuadState(state.pos_m.copy(), state.vel_m_s.copy()), c1[:, -1] + bezier_position(c2, u),
                bezier_velocity(c2, u, prims.duration_s), q,
            )
            drops[kinds[int(np.sign(d[2]))]].append(-min(t1[:, 0, 2].min(), t2[:, 0, 2].min()))
    return {kind: {"least_m": round(min(v), 3), "most_m": round(max(v), 3)} for kind, v in drops.items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--primitive-scale", type=float, default=1.0, help="m per axis, in (0, 5] (default 1.0)")
    ap.add_argument("--ceiling-m", type=float, default=2.10, help="ceiling height over the floor (m, > 0)")
    ap.add_argument("--clearance-m", type=float, default=0.5, help="kept from floor and ceiling (m, > 0)")
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args()
    for name in ("primitive_scale", "ceiling_m", "clearance_m"):
        value = getattr(args, name)
        if not (np.isfinite(value) and value > 0) or (name == "primitive_scale" and value > 5):
            ap.error(f"--{name.replace('_', '-')} {value!r}: out of range")
    top = args.ceiling_m - args.clearance_m
    if top <= args.clearance_m:
        ap.error(f"--ceiling-m {args.ceiling_m} leaves no heights free at --clearance-m {args.clearance_m}")
    drops = lowest_after_descents(args.primitive_scale)
    least_level = drops["level"]["least_m"]
    stuck = (top, args.clearance_m + least_level)
    cannot_pass = [round(stuck[0], 3), round(stuck[1], 3)] if stuck[1] > stuck[0] else None
    out = {
        "primitive_scale_m": args.primitive_scale,
        "ceiling_m": args.ceiling_m,
        "clearance_m": args.clearance_m,
        "drop_below_start_m": drops,
        "band_m": [args.clearance_m, round(top, 3)],
        "starts_that_cannot_pass_m": cannot_pass,
    }
    for kind, d in drops.items():
        print(f"descent then {kind:5s}: lowest point {d['least_m']:.3f}-{d['most_m']:.3f} m below the start")
    print(f"heights keeping {args.clearance_m} m from floor and ceiling: {args.clearance_m}-{top:.2f} m")
    if cannot_pass:
        print(f"starts from {stuck[0]:.2f} to {stuck[1]:.3f} m cannot pass under the ceiling")
    else:
        print("every start can pass under the ceiling")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
