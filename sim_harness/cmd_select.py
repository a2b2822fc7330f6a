"""``quadnav-sim select``: choose among checkpoints without touching the held-out worlds.

The rule (the one ``docs/results.md`` uses to pick the shipped seed): score = goals − crashes over

- the training worlds Env 1–7, 10 trials each, start-jitter seeds 0 and 1000 (140 flights each), and
- a development set of 8 generated worlds (procedural seed 777), 10 trials each, seeds 0 and 1
  (160 flights),

flown greedily with the depth safety filter (``--shield on``: the checkpoint's settings, the
defaults for a checkpoint trained without it, which is how the shipped model flies).
Checkpoints tied at the top fly the same flights again without their filter, and the tie goes
to the one that scores most so (goals − crashes alone): the filter's margins and the primitives
cap what any planner can score with the filter, so ties at the top are common, and what the
network plans on its own is what tells them apart. A tie that remains goes to the checkpoint
listed first. With ``--shield off`` the rule is already flown alone, and ties go to the first
listed; so do ties where any tied checkpoint flies without a filter (``--shield model`` and a
checkpoint that records none). The held-out Env 8–10 and the test worlds (procedural seed 4242)
are never flown here.

With ``--teacher`` the privileged teacher (``sim_harness.rl.teacher``: a search over the primitives
against the true world, two primitives deep, choosing among those the filter allows) flies the
same flights in the first checkpoint's env, as a reference and never a candidate: what a planner
that sees the whole world scores behind this filter with these primitives. Each checkpoint's
misses are then also counted among the teacher's.

With ``--alone`` every checkpoint, not only those tied at the top, also flies the same flights
without its filter, shown beside the rule's score; outside a tie at the top it does not choose.
"""

from __future__ import annotations

import argparse
import dataclasses
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
    p.add_argument(
        "--teacher",
        action="store_true",
        help="also fly the privileged teacher (it sees the true world, keeps to the filter's "
        "verdicts) in the same flights, as a reference score; never chosen",
    )
    p.add_argument(
        "--alone",
        action="store_true",
        help="also fly every checkpoint without its filter in the same flights (its score alone, "
        "shown beside the rule's; it chooses only among checkpoints tied at the top, which fly "
        "alone without this flag too)",
    )
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
    from sim_harness.rl.teacher import Teacher, TeacherConfig, TeacherPilot
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
    flights_per_model = sum(len(w) * len(seeds) for _, w, seeds in sets) * args.trials
    planners = len(policies) * (1 + args.alone) + args.teacher
    bar = tqdm(total=planners * flights_per_model, desc="select", unit="flight",
               disable=args.no_progress, file=sys.stderr)

    def fly(act, env_cfg, on_world_start=None) -> dict:
        """Goals, crashes and the flights missed (``SET_seedS/WORLD/tTRIAL``) of one planner."""
        parts, missed = {}, []
        for name, written, seeds in sets:
            env_cfg_s, worlds = at_flight_scale(env_cfg, written, args)
            for seed in seeds:
                rows = evaluate(act, worlds, args.trials, seed, env_cfg_s, on_world_start=on_world_start,
                                on_world_done=lambda _w: bar.update(args.trials))
                part = f"{name}_seed{seed}"
                parts[part] = {
                    "flights": len(rows),
                    "goals": sum(r.outcome == "goal" for r in rows),
                    "crashes": sum(r.outcome == "crash" for r in rows),
                }
                missed += [f"{part}/{r.world}/t{r.trial}" for r in rows if r.outcome != "goal"]
        goals = sum(p["goals"] for p in parts.values())
        crashes = sum(p["crashes"] for p in parts.values())
        return {"score": goals - crashes, "goals": goals, "crashes": crashes, **parts, "missed": missed}

    scores = [
        {"model": model, **fly(policy_greedy_fn(policy),
                               env_config_for_policy(policy, max_steps=args.max_steps, shield=shield))}
        for model, policy, shield in zip(args.models, policies, shields, strict=True)
    ]
    def alone_env(policy, shield):
        return env_config_for_policy(policy, max_steps=args.max_steps,
                                     shield=dataclasses.replace(shield, enabled=False))

    if args.alone:
        for s, policy, shield in zip(scores, policies, shields, strict=True):
            s["alone"] = fly(policy_greedy_fn(policy), alone_env(policy, shield))
    teacher = None
    if args.teacher:
        env_cfg = env_config_for_policy(policies[0], max_steps=args.max_steps, shield=shields[0])
        pilot = TeacherPilot(Teacher(TeacherConfig(respect_filter=env_cfg.shield.enabled)))
        teacher = {"respects_filter": env_cfg.shield.enabled, "env_of": args.models[0],
                   **fly(pilot.act, env_cfg, pilot.on_world_start)}
        for s in scores:
            s["missed_by_teacher_too"] = len(set(s["missed"]) & set(teacher["missed"]))
    top = max(s["score"] for s in scores)
    tied = [i for i, s in enumerate(scores) if s["score"] == top]
    tie_break = None
    if len(tied) > 1 and all(shields[i].enabled for i in tied):
        for i in tied:
            if "alone" not in scores[i]:
                bar.total += flights_per_model
                bar.refresh()
                scores[i]["alone"] = fly(policy_greedy_fn(policies[i]), alone_env(policies[i], shields[i]))
        tie_break = {"by": "score alone (goals - crashes without the filter)",
                     "tied": [scores[i]["model"] for i in tied]}
    bar.close()
    best = tied[0] if tie_break is None else max(tied, key=lambda i: (scores[i]["alone"]["score"], -i))
    label = "the privileged teacher (a reference)"
    width = max([len(s["model"]) for s in scores] + ([len(label)] if teacher else []))
    header = f"{'checkpoint':<{width}}  score  goals  crashes"
    header += "  missed  also the teacher's" if teacher else ""
    shown_alone = any("alone" in s for s in scores)
    header += "  alone: score  goals  crashes" if shown_alone else ""
    print(f"{header}  (of {flights_per_model} flights)")
    for i, s in enumerate(scores):
        row = f"{s['model']:<{width}}  {s['score']:5d}  {s['goals']:5d}  {s['crashes']:7d}"
        if teacher:
            row += f"  {len(s['missed']):6d}  {s['missed_by_teacher_too']:18d}"
        if "alone" in s:
            a = s["alone"]
            row += f"  {a['score']:12d}  {a['goals']:5d}  {a['crashes']:7d}"
        elif shown_alone:
            row += f"  {'-':>12}  {'-':>5}  {'-':>7}"
        print(row + ("  <- chosen" if i == best else ""))
    if tie_break:
        print(f"({len(tied)} checkpoints tied at {top}; the tie went to the best score without the filter)")
    if teacher:
        print(f"{label:<{width}}  {teacher['score']:5d}  {teacher['goals']:5d}  {teacher['crashes']:7d}"
              f"  {len(teacher['missed']):6d}")
        kept = "keeping to the filter's verdicts" if teacher["respects_filter"] else "with no filter"
        print(f"(the teacher plans against the true world, {kept}, in the env of {teacher['env_of']}; "
              "it is never chosen)")
    if args.json:
        out = {
            "rule": "goals - crashes; train Env 1-7 seeds 0/1000 + dev procgen 777 seeds 0/1; "
                    "ties at the top by the same alone, then first listed",
            "shield": args.shield,
            "shield_set": args.shield_set,
            "primitive_scale_m": args.primitive_scale,
            "trials": args.trials,
            "chosen": scores[best]["model"],
            "tie_break": tie_break,
            "scores": scores,
        }
        if teacher:
            out["teacher"] = teacher
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2), encoding="utf-8")
        print(f"wrote {args.json}")
    return 0
