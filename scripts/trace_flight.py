#!/usr/bin/env python3
"""Step-by-step trace of one evaluation flight: where the vehicle was, what the filter allowed,
what the DQN ranked first and what it flew, and the clearance of its first K primitives (--top, default 3) as
the filter judged it and from the true geometry (for reading a crash or a stall of ``quadnav-sim
eval``).

The flight is trial T of world I of ``quadnav-sim eval`` run with the same flags: it is flown by
the eval's own loop (``evaluate``: same worlds, seeds, filter and the room known to it, scale, and
under ``--flight-config`` the flight's limits and the depth noise), so the trace ends as that
trial did. Trace development worlds, never the test set (procedural seed 4242) when choosing
anything.

Usage:  python scripts/trace_flight.py [--model CKPT] [--world W ... | --procedural N --procedural-seed P]
            [--world-index I] [--trial T] [--trials 10] [--seed 0] [--top K]
            [--primitive-scale M | --flight-config FLIGHT.yaml [--layouts N --layout-seed S]]
            [--start-jitter-m M] [--max-steps N] [--depth-noise auto|on|off]
            [--shield on|off|model] [--shield-set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def main() -> int:
    from sim_harness.cmd_eval import add_flights_flags, load_flights
    from sim_harness.rl.evaluate import evaluate, policy_greedy_fn
    from sim_harness.route import true_geometry_verdict

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_flights_flags(ap, shield_default="on", trials_default=10)  # the eval's, its filter forced on
    ap.add_argument("--world-index", type=int, default=0, help="which world of the list (from 0)")
    ap.add_argument("--trial", type=int, default=0, help="which trial of that world (from 0)")
    ap.add_argument("--top", type=int, default=3,
                    help="primitives listed per decision, the DQN's ranking first (default 3; "
                         "the primitive count lists every one)")
    args = ap.parse_args()
    if not (0 <= args.trial < args.trials) or args.world_index < 0:
        print(f"trace_flight: need 0 <= --trial < --trials ({args.trials}) and --world-index >= 0",
              file=sys.stderr)
        return 2
    if args.top < 1:
        print(f"trace_flight: --top: bad value {args.top}: must be >= 1", file=sys.stderr)
        return 2
    loaded = load_flights("trace_flight", args.model, args)
    if loaded is None:
        return 2
    policy, flights = loaded
    worlds = flights.worlds
    if args.world_index >= len(worlds):
        print(f"trace_flight: --world-index {args.world_index}: the list has {len(worlds)} worlds",
              file=sys.stderr)
        return 2
    target = worlds[args.world_index]
    print(target.name)
    for ob in target.obstacles:
        print("  ", ob)
    directions = np.asarray(flights.env_config.primitives.directions)
    top_n = min(args.top, len(directions))
    i = args.trial

    def trace(world, env, depth, rel, actions) -> None:
        if world is not target or env.done[i]:
            return
        q = policy.q_values_batch(depth, rel, env.config.primitives.scale_m)
        true = true_geometry_verdict(env, np.array([i]))[1][0]
        seen = env.clearance_m[i]
        top = [(int(a), bool(env.allowed[i, a]), round(float(seen[a]), 2), round(float(true[a]), 2))
               for a in np.argsort(-q[i])[:top_n]]
        print(f"{int(env.steps[i]):3d} pos {np.round(env.pos_m[i], 2)} "
              f"allowed {int(env.allowed[i].sum()):2d} "
              f"flies {int(actions[i]):2d} {directions[actions[i]].astype(int)}  "
              f"top {top_n} (action, allowed, clearance m: the filter's, from the true geometry) {top}")

    # the worlds before it are flown too: a world's seed is its place in the list (world_seed)
    rows = evaluate(policy_greedy_fn(policy), worlds[: args.world_index + 1], args.trials, args.seed,
                    flights.env_config, limits=flights.limits, depth_noise=flights.depth_noise, on_step=trace)
    print("outcome:", rows[args.world_index * args.trials + i].outcome)
    return 0


if __name__ == "__main__":
    sys.exit(main())
