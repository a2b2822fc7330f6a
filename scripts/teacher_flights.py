#!/usr/bin/env python3
"""The privileged teacher flown in an eval's flights: what a planner that sees the true world
reaches with the same primitives, from the same starts.

The teacher (``sim_harness.rl.teacher``) plans every step against the true geometry: a
cost-to-go field and each primitive flown from the env's exact state, two primitives deep. It is
the reference a DQN that sees one 32x32 depth image per step is measured against, and the labels
of the privileged DAgger recipes. The flights are those of ``quadnav-sim eval`` with the same
flags (worlds, scale, ``--trials``, ``--seed``); the model only sets the env (its primitives and
history lengths), and its filter is off unless asked for. With ``--shield on`` the filter runs
beside the teacher and the script counts the decisions whose primitive it would have vetoed;
``--respect-filter`` makes the teacher choose among what the filter allows (the
``teacher_respect_filter`` training key).

Usage:  python scripts/teacher_flights.py [--world W ... | --procedural N --procedural-seed P]
            [--primitive-scale M] [--trials 10] [--seed 0] [--margin-m 0.15] [--lookahead 2]
            [--shield on --respect-filter] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter


def main() -> int:
    from sim_harness.cmd_eval import add_flights_flags, load_flights
    from sim_harness.rl.evaluate import evaluate, summarize
    from sim_harness.rl.teacher import Teacher, TeacherConfig, TeacherPilot

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_flights_flags(ap, shield_default="off", trials_default=10)
    ap.add_argument("--margin-m", type=float, default=TeacherConfig.margin_m,
                    help="clearance beyond the quad's radius the teacher keeps, in (0, 1] m "
                         "(default: %(default)s)")
    ap.add_argument("--lookahead", type=int, default=TeacherConfig.lookahead, choices=(1, 2),
                    help="primitives flown per decision (default: %(default)s)")
    ap.add_argument("--respect-filter", action="store_true",
                    help="the teacher chooses among the primitives the filter allows (needs --shield on)")
    ap.add_argument("--json", default=None, metavar="OUT")
    args = ap.parse_args()
    if args.respect_filter and args.shield != "on":
        print("teacher_flights: --respect-filter: the filter's verdicts need --shield on", file=sys.stderr)
        return 2
    if not 0.0 < args.margin_m <= 1.0:
        print(f"teacher_flights: --margin-m: bad value {args.margin_m!r}: must be in (0, 1]", file=sys.stderr)
        return 2
    loaded = load_flights("teacher_flights", args.model, args)
    if loaded is None:
        return 2
    _, flights = loaded
    teacher = Teacher(TeacherConfig(margin_m=args.margin_m, lookahead=args.lookahead,
                                    respect_filter=args.respect_filter))
    pilot = TeacherPilot(teacher)
    rows = evaluate(pilot.act, flights.worlds, args.trials, args.seed, flights.env_config,
                    limits=flights.limits, depth_noise=flights.depth_noise,
                    on_world_start=pilot.on_world_start)
    summary = summarize(rows)
    by_world: dict[str, Counter] = {}
    for r in rows:
        by_world.setdefault(r.world, Counter())[r.outcome] += 1
    for world, c in by_world.items():
        print(f"{world:28s} " + ", ".join(f"{k} {v}" for k, v in sorted(c.items())))
    print(f"trials {summary['trials']}: goal {summary['success_rate']:.1%}, "
          f"collision-free {summary['collision_free_rate']:.1%}")
    if pilot.decisions:
        print(f"the filter would veto the teacher's choice in {pilot.vetoed} of "
              f"{pilot.decisions} decisions")
    if args.json:
        out = {"margin_m": args.margin_m, "lookahead": args.lookahead, "seed": args.seed,
               "trials": args.trials, "summary": summary, "respect_filter": args.respect_filter,
               "filter_vetoes": ({"decisions": pilot.decisions, "vetoed": pilot.vetoed}
                                 if pilot.decisions else None),
               "by_world": {w: dict(c) for w, c in by_world.items()},
               "rows": [r.to_dict() for r in rows]}
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
