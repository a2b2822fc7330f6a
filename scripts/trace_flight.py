#!/usr/bin/env python3
"""Step-by-step trace of one evaluation flight: where the vehicle was, what the filter allowed,
what the DQN ranked first and what it flew (for reading a crash or a stall of ``quadnav-sim eval``).

The flight is the one ``quadnav-sim eval`` flies as trial T of world I (same env seed), with the
model's own filter. Trace development worlds, never the test set (procedural seed 4242).

Usage:  python scripts/trace_flight.py (--procedural-seed P --procedural N | --world W.yaml)
            [--world-index I] [--trial T] [--trials 10] [--seed 0] [--model CKPT] [--primitive-scale M]
            [--shield on|off|model] [--shield-set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def main() -> int:
    from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy, masked_argmax
    from sim_harness.cmd_eval import add_flight_flags, at_flight_scale, shield_from_flags
    from sim_harness.env import VecQuadNavEnv
    from sim_harness.procgen import procedural_worlds
    from sim_harness.rl.evaluate import env_config_for_policy, world_seed
    from sim_harness.world import load_world

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=str(DEFAULT_MODEL_PATH))
    ap.add_argument("--world", default=None, help="a world file (else generated worlds)")
    ap.add_argument("--procedural", type=int, default=12)
    ap.add_argument("--procedural-seed", type=int, default=None)
    ap.add_argument("--world-index", type=int, default=0, help="which world of the set (eval's order)")
    ap.add_argument("--trial", type=int, default=0)
    ap.add_argument("--trials", type=int, default=10, help="trials flown together, as in the eval run")
    ap.add_argument("--seed", type=int, default=0, help="the eval run's --seed")
    add_flight_flags(ap, shield_default="on")  # --primitive-scale, --shield, --shield-set: as eval
    ap.add_argument("--max-steps", type=int, default=120)
    args = ap.parse_args()
    if (args.world is None) == (args.procedural_seed is None):
        print("trace_flight: give --world or --procedural-seed", file=sys.stderr)
        return 2
    policy = Policy.from_path(args.model)
    worlds = (
        [load_world(args.world)] if args.world else procedural_worlds(args.procedural, args.procedural_seed)
    )
    env_cfg = env_config_for_policy(policy, max_steps=args.max_steps, shield=shield_from_flags(policy, args))
    env_cfg, worlds = at_flight_scale(env_cfg, worlds, args)
    world = worlds[args.world_index]
    print(world.name)
    for ob in world.obstacles:
        print("  ", ob)
    env = VecQuadNavEnv([world], args.trials, seed=world_seed(args.seed, args.world_index), config=env_cfg,
                        autoreset=False)
    directions = np.asarray(env.prims.directions)
    depth, rel = env.reset()
    i, step = args.trial, 0
    while not env.done[i]:
        q = policy.q_values_batch(depth, rel)
        action = masked_argmax(q, env.allowed)
        top = [(int(a), bool(env.allowed[i, a]), round(float(env.clearance_m[i, a]), 2))
               for a in np.argsort(-q[i])[:3]]
        print(f"{step:3d} pos {np.round(env.pos_m[i], 2)} allowed {int(env.allowed[i].sum()):2d} "
              f"flies {int(action[i]):2d} {directions[action[i]].astype(int)}  "
              f"top 3 (action, allowed, clearance m) {top}")
        depth, rel, _, _, _, info = env.step(action)
        step += 1
    print("outcome:", info["outcome"][i])
    return 0


if __name__ == "__main__":
    sys.exit(main())
