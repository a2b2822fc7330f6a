#!/usr/bin/env python3
"""How much a model that reads the primitive scale (``network_scale_input``) uses it: in the
decisions of an eval's flights, the share whose first choice changes when the network is told
another scale than the one flown (the flights themselves fly the scale flown, as ``quadnav-sim
eval`` does). A network that ignores its scale lane answers alike at both: 0 %.

Usage:  python scripts/scale_sensitivity.py --model CKPT [--world W ...] [--trials 10] [--seed 0]
            [--primitive-scale M] [--shield on|off] --other-scale 0.5
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def main() -> int:
    from sim_harness.cmd_eval import add_flights_flags, load_flights
    from sim_harness.rl.evaluate import evaluate, policy_greedy_fn

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_flights_flags(ap, shield_default="off", trials_default=10)
    ap.add_argument("--other-scale", type=float, required=True, metavar="M",
                    help="the scale (m) the network is also told at every decision")
    args = ap.parse_args()
    if not (np.isfinite(args.other_scale) and args.other_scale > 0):
        print(f"scale_sensitivity: --other-scale: bad value {args.other_scale}: must be > 0", file=sys.stderr)
        return 2
    loaded = load_flights("scale_sensitivity", args.model, args)
    if loaded is None:
        return 2
    policy, flights = loaded
    if not policy.reads_scale:
        print(f"scale_sensitivity: {args.model or 'the bundled model'} does not read the scale "
              "(network_scale_input)", file=sys.stderr)
        return 2
    flown = flights.env_config.primitives.scale_m
    counts = {"decisions": 0, "changed": 0}

    def count(world, env, depth, rel, actions) -> None:
        live = ~env.done
        other = policy.q_values_batch(depth, rel, args.other_scale).argmax(axis=1)
        told = policy.q_values_batch(depth, rel, flown).argmax(axis=1)
        counts["decisions"] += int(live.sum())
        counts["changed"] += int((live & (other != told)).sum())

    evaluate(policy_greedy_fn(policy), flights.worlds, args.trials, args.seed, flights.env_config,
             limits=flights.limits, depth_noise=flights.depth_noise, on_step=count)
    n, changed = counts["decisions"], counts["changed"]
    print(f"flown at {flown} m, told {args.other_scale} m as well: the first choice changes in "
          f"{changed} of {n} decisions ({100.0 * changed / max(n, 1):.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
