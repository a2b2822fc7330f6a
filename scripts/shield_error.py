#!/usr/bin/env python3
"""How far the depth filter's predicted clearance is from the truth, over evaluation flights.

At every decision of the flights ``quadnav-sim eval`` flies (same seeding, filter and scale), the
filter predicts the clearance of each primitive from the views it remembers. This script takes the
primitive the policy flies, evaluates the *same* predicted positions (the filter's samples along
it, tracking included) against the world's true geometry, and reports predicted minus true
clearance over the decisions whose true clearance is under ``--within`` metres: the steps where an
error matters. Positive = the filter thinks there is more room than there is (the dangerous side).
It isolates perception and memory; the tracking model is the same on both sides.

Usage:  python scripts/shield_error.py [--model CKPT] [--seed 2000] [--trials 10]
            [--primitive-scale 0.5] [--shield-set depth_pooling=mean] [--within 1.0] [--json OUT]

Defaults fly the training worlds Env 1-7 (never the held-out Env 8-10) at eval seed 2000.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np


def main() -> int:
    from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy, masked_argmax
    from quadnav_onboard.shield import primitive_samples
    from sim_harness.cmd_eval import add_flight_flags, at_flight_scale, shield_from_flags
    from sim_harness.collision import clearance_m
    from sim_harness.env import VecQuadNavEnv
    from sim_harness.rl.evaluate import env_config_for_policy, world_seed
    from sim_harness.world import load_world, paper_world_path

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=str(DEFAULT_MODEL_PATH))
    ap.add_argument("--envs", type=int, nargs="+", default=list(range(1, 8)), help="paper worlds (1-7)")
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--seed", type=int, default=2000, help="eval seed (as quadnav-sim eval --seed)")
    ap.add_argument("--within", type=float, default=1.0,
                    help="count decisions with true clearance < this (m)")
    ap.add_argument("--json", type=Path, default=None)
    add_flight_flags(ap, shield_default="on")  # --primitive-scale, --shield, --shield-set: as eval
    args = ap.parse_args()
    if any(not 1 <= e <= 7 for e in args.envs):
        print("shield_error: --envs must be training worlds 1-7 (Env 8-10 are held out)", file=sys.stderr)
        return 2
    policy = Policy.from_path(args.model)
    env_cfg = env_config_for_policy(policy, shield=shield_from_flags(policy, args))
    if not env_cfg.shield.enabled:
        print("shield_error: the filter is off; nothing to compare", file=sys.stderr)
        return 2
    worlds = [load_world(paper_world_path(e)) for e in args.envs]
    env_cfg, worlds = at_flight_scale(env_cfg, worlds, args)
    pred_all: list[np.ndarray] = []
    true_all: list[np.ndarray] = []
    for w_i, world in enumerate(worlds):
        env = VecQuadNavEnv([world], args.trials, seed=world_seed(args.seed, w_i), config=env_cfg,
                            autoreset=False)
        depth, rel = env.reset()
        while not env.done.all():
            action = masked_argmax(policy.q_values_batch(depth, rel, env_cfg.primitives.scale_m), env.allowed)
            live = np.flatnonzero(~env.done)
            yaw = world.path.heading_at(env.pos_m[live])
            samples = primitive_samples(
                env.prims, env.cmd_pos_m[live], env.cmd_vel_m_s[live], yaw, env_cfg.shield,
                pos_world_m=env.pos_m[live], vel_world_m_s=env.vel_m_s[live],
            )[np.arange(live.size), action[live]]  # (L, S, 3): the flown primitive's samples
            true = clearance_m(world, samples.reshape(-1, 3)).reshape(samples.shape[:2]).min(axis=1)
            pred_all.append(env.clearance_m[live, action[live]])
            true_all.append(true)
            depth, rel, *_ = env.step(action)
    pred, true = np.concatenate(pred_all), np.concatenate(true_all)
    near = true < args.within
    err = pred[near] - true[near]
    pct = {f"p{q}": round(float(np.percentile(err, q)), 3) for q in (50, 90, 95, 99)} if err.size else {}
    out = {
        "model": args.model, "envs": args.envs, "trials": args.trials, "seed": args.seed,
        "primitive_scale_m": env_cfg.primitives.scale_m, "shield": dataclasses.asdict(env_cfg.shield),
        "decisions": int(pred.size), "near_decisions": int(near.sum()), "within_m": args.within,
        "error_m": pct, "error_max_m": round(float(err.max()), 3) if err.size else None,
    }
    print(f"{pred.size} decisions, {int(near.sum())} with true clearance < {args.within} m; "
          "predicted - true (m): " + "  ".join(f"{k} {v:+.3f}" for k, v in pct.items()))
    if args.json:
        args.json.write_text(json.dumps(out, indent=2), encoding="utf-8")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
