"""``quadnav-sim select``: choose among checkpoints without touching the held-out worlds.

The rule (the one ``docs/results.md`` uses to pick the shipped seed): score = goals − crashes over

- the training worlds Env 1–7, 10 trials each, start-jitter seeds 0 and 1000 (140 flights each), and
- a development set of 8 generated worlds (procedural seed 777), 10 trials each, seeds 0 and 1
  (160 flights),

flown greedily with the depth safety filter (``--shield on``: the checkpoint's settings, the
defaults for a checkpoint trained without it, which is how the shipped model flies).
Ties go to the checkpoint listed first. The held-out Env 8–10 and the test worlds (procedural seed
4242) are never flown here.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

__all__ = ["DEV_PROCEDURAL_SEED", "add_parser", "run"]

DEV_PROCEDURAL_SEED = 777
"""Seed of the generated development worlds (never the training 20261124 or the test 4242)."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    from sim_harness.cmd_eval import add_flight_flags

    p = subparsers.add_parser(
        "select",
        help="score checkpoints on the training and development worlds (never the held-out ones)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("models", nargs="+", metavar="CKPT", help="checkpoints to score")
    add_flight_flags(p, shield_default="on")
    p.add_argument("--trials", type=int, default=10, help="trials per world and seed (default 10)")
    p.add_argument("--max-steps", type=int, default=120, help="step limit per flight (default 120)")
    p.add_argument("--json", default=None, metavar="OUT", help="also write the scores as JSON")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from quadnav_onboard.checkpoint import CheckpointError
    from quadnav_onboard.config import ConfigError
    from quadnav_onboard.policy import Policy
    from sim_harness.cmd_eval import at_flight_scale, shield_from_flags
    from sim_harness.procgen import procedural_worlds
    from sim_harness.rl.evaluate import env_config_for_policy, evaluate, policy_greedy_fn
    from sim_harness.world import load_world, paper_world_path

    if args.trials < 1 or args.max_steps < 1:
        print("quadnav-sim select: --trials and --max-steps must be >= 1", file=sys.stderr)
        return 2
    try:
        policies = [Policy.from_path(m) for m in args.models]
        shields = [shield_from_flags(policy, args) for policy in policies]  # bad flags: before any flight
    except (CheckpointError, ConfigError, ValueError) as exc:
        print(f"quadnav-sim select: {exc}", file=sys.stderr)
        return 2
    sets = [
        ("train", [load_world(paper_world_path(i)) for i in range(1, 8)], (0, 1000)),
        ("dev", procedural_worlds(8, DEV_PROCEDURAL_SEED), (0, 1)),
    ]
    scores = []
    bar = tqdm(total=len(policies) * 4, desc="select", unit="set", disable=args.no_progress, file=sys.stderr)
    for model, policy, shield in zip(args.models, policies, shields, strict=True):
        env_cfg = env_config_for_policy(policy, max_steps=args.max_steps, shield=shield)
        parts = {}
        for name, written, seeds in sets:
            env_cfg_s, worlds = at_flight_scale(env_cfg, written, args)
            for seed in seeds:
                rows = evaluate(policy_greedy_fn(policy), worlds, args.trials, seed, env_cfg_s)
                parts[f"{name}_seed{seed}"] = {
                    "flights": len(rows),
                    "goals": sum(r.outcome == "goal" for r in rows),
                    "crashes": sum(r.outcome == "crash" for r in rows),
                }
                bar.update(1)
        goals = sum(p["goals"] for p in parts.values())
        crashes = sum(p["crashes"] for p in parts.values())
        scores.append({"model": model, "score": goals - crashes, "goals": goals, "crashes": crashes, **parts})
    bar.close()
    best = max(range(len(scores)), key=lambda i: (scores[i]["score"], -i))
    width = max(len(s["model"]) for s in scores)
    print(f"{'checkpoint':<{width}}  score  goals  crashes  (of {sum(p['flights'] for p in parts.values())})")
    for i, s in enumerate(scores):
        mark = "  <- chosen" if i == best else ""
        print(f"{s['model']:<{width}}  {s['score']:5d}  {s['goals']:5d}  {s['crashes']:7d}{mark}")
    if args.json:
        out = {
            "rule": "goals - crashes; train Env 1-7 seeds 0/1000 + dev procgen 777 seeds 0/1",
            "shield": args.shield,
            "shield_set": args.shield_set,
            "primitive_scale_m": args.primitive_scale,
            "trials": args.trials,
            "chosen": scores[best]["model"],
            "scores": scores,
        }
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2), encoding="utf-8")
        print(f"wrote {args.json}")
    return 0
