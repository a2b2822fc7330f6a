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
It also prints how far past a primitive's end the filter looks with each ``lookahead``
(``velocity``, the default, and ``stop``), which is what widens that band for the filter.

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
    from quadnav_onboard.primitives import DEFAULT_DIRECTIONS, PrimitiveSet
    from quadnav_onboard.step import primitive_targets, step_fractions
    from sim_harness.quad import QuadParams, QuadState, track

    prims, q = PrimitiveSet(scale_m=scale_m), QuadParams()
    u = step_fractions(prims.duration_s, q.dt_s)  # as the env samples a step
    descents = [a for a, d in enumerate(DEFAULT_DIRECTIONS) if d[2] < 0]
    first = np.repeat(descents, prims.n_actions)  # every descent, then every primitive after it
    second = np.tile(np.arange(prims.n_actions), len(descents))
    yaw, zero = np.zeros(first.size), np.zeros((first.size, 3))
    targets, target_vel = primitive_targets(prims, first, zero, zero, yaw, u)
    state, trail1 = track(QuadState(zero.copy(), zero.copy()), targets, target_vel, q)
    targets, target_vel = primitive_targets(prims, second, targets[-1], target_vel[-1], yaw, u)
    _, trail2 = track(state, targets, target_vel, q)
    drop = -np.minimum(trail1[..., 2].min(axis=0), trail2[..., 2].min(axis=0))  # (n,)
    vertical = np.asarray(DEFAULT_DIRECTIONS)[second, 2]
    out = {}
    for kind, v in (("down", -1), ("level", 0), ("up", 1)):
        sel = drop[vertical == v]
        out[kind] = {"least_m": round(float(sel.min()), 3), "most_m": round(float(sel.max()), 3)}
    return out


def filter_reach_past_end(scale_m: float) -> dict[str, dict[str, float]]:
    """How far past a primitive's commanded end the filter checks (m), flown from rest by its
    tracking model, for each look-ahead: below a straight descent's end and beyond a level
    forward primitive's end."""
    from dataclasses import replace

    from quadnav_onboard.primitives import DEFAULT_DIRECTIONS, PrimitiveSet
    from quadnav_onboard.shield import ShieldConfig, primitive_samples

    prims = PrimitiveSet(scale_m=scale_m)
    down, ahead = DEFAULT_DIRECTIONS.index((1, 0, -1)), DEFAULT_DIRECTIONS.index((1, 0, 0))
    rest = np.zeros((1, 3))
    out = {}
    for lookahead in ("velocity", "stop"):
        cfg = replace(ShieldConfig(enabled=True), lookahead=lookahead)
        s = primitive_samples(prims, rest, rest, np.zeros(1), cfg, pos_world_m=rest, vel_world_m_s=rest)[0]
        out[lookahead] = {
            "below_descent_end_m": round(float(-scale_m - s[down, :, 2].min()), 3),
            "beyond_forward_end_m": round(float(s[ahead, :, 0].max() - scale_m), 3),
        }
    return out


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
    reach = filter_reach_past_end(args.primitive_scale)
    least_level = drops["level"]["least_m"]
    stuck = (top, args.clearance_m + least_level)
    cannot_pass = [round(stuck[0], 3), round(stuck[1], 3)] if stuck[1] > stuck[0] else None
    out = {
        "primitive_scale_m": args.primitive_scale,
        "ceiling_m": args.ceiling_m,
        "clearance_m": args.clearance_m,
        "drop_below_start_m": drops,
        "filter_reach_past_end_m": reach,
        "band_m": [args.clearance_m, round(top, 3)],
        "starts_that_cannot_pass_m": cannot_pass,
    }
    for kind, d in drops.items():
        print(f"descent then {kind:5s}: lowest point {d['least_m']:.3f}-{d['most_m']:.3f} m below the start")
    for lookahead, r in reach.items():
        print(f"the filter's {lookahead} look-ahead checks {r['below_descent_end_m']:.2f} m below a "
              f"descent's end, {r['beyond_forward_end_m']:.2f} m beyond a forward one's")
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
